"""Character transmitter: chooses what to send next and encodes it with its parity.

# Ref: ECSS-E-ST-50-12C §7.2-§7.4 (characters, NULL, time-codes, parity), §8.5.2 (what the
#      transmitter may send in Started, Connecting and Run), transmit priority time-code > FCT
#      > N-char > NULL.

Whenever the data-strobe transmitter can take the next group of line bits, exactly one of
these is encoded, in priority order: a time-code (ESC + data character, 14 bits) if
``send_time``, an FCT (4 bits) if ``send_fct``, the N-char offered on ``nchar`` (10 or 4 bits),
else a NULL (ESC + FCT, 8 bits). NULL and time-code go out as one group, so nothing can come
between their two characters. The parity state (the XOR of the previous character's data or
control bits) starts at zero whenever the transmitter is enabled.
"""

from amaranth import *
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.link import (CONTROL_BITS, DATA_BITS, NULL_BITS, TIME_BITS, check_div,
                                     check_slots)

from ..helpers import rejecting
from .chars import Char, CharKind, ControlChar, ControlCode, DataChar
from .ds import DSTransmitter

__all__ = ["CharTransmitter"]


def _fields(view, **values):
    """Assignments of ``values`` to the fields of the struct view ``view``."""
    return [getattr(view, name).eq(value) for name, value in values.items()]


class CharTransmitter(wiring.Component):
    """Encode FCTs, N-chars, time-codes and NULLs onto a data-strobe line.

    Parameters
    ----------
    slots, start_div, max_run_div : int
        See :class:`~hdl.link.ds.DSTransmitter`.

    Attributes
    ----------
    enable, fast, run_div : In
        See :class:`~hdl.link.ds.DSTransmitter`; ``enable`` low also clears the parity state.
    send_time : In(1)
        A time-code with value ``time`` is waiting; it goes out at the next opportunity.
    time : In(8)
    send_fct : In(1)
        An FCT may be sent.
    nchar : In(stream.Signature(Char))
        N-chars to send. ``ready`` is high in the cycles where an N-char would be encoded.
    time_sent, fct_sent : Out(1)
        Strobes: the time-code or an FCT was encoded this cycle.
    d_out, s_out : Out(slots)
        Line samples.
    """

    def __init__(self, *, slots: int, start_div: int, max_run_div: int):
        with rejecting(self):
            check_slots(slots)
            check_div(start_div, "Start bit period", slots)
            check_div(max_run_div, "Slowest run bit period", slots)
        self._params = dict(slots=slots, start_div=start_div, max_run_div=max_run_div)
        super().__init__({
            "enable":    In(1),
            "fast":      In(1),
            "run_div":   In(range(max_run_div + 1)),
            "send_time": In(1),
            "time":      In(8),
            "send_fct":  In(1),
            "nchar":     In(stream.Signature(Char)),
            "time_sent": Out(1),
            "fct_sent":  Out(1),
            "d_out":     Out(slots),
            "s_out":     Out(slots),
        })

    def elaborate(self, platform):
        m = Module()
        m.submodules.ds = ds = DSTransmitter(**self._params)

        par = Signal()      # XOR of the data/control bits of the previous character
        m.d.comb += [
            ds.enable.eq(self.enable),
            ds.fast.eq(self.fast),
            ds.run_div.eq(self.run_div),
            ds.groups.valid.eq(1),
            self.d_out.eq(ds.d_out),
            self.s_out.eq(ds.s_out),
        ]

        # ESC (parity = par: the flag and two control bits are all 1) as the first character of
        # NULL and time-code; the second character's parity then covers ESC's bits 1 1.
        esc = Signal(ControlChar)
        m.d.comb += _fields(esc, parity=par, flag=1, code=ControlCode.ESC)
        null_fct = Signal(ControlChar)
        m.d.comb += _fields(null_fct, parity=0, flag=1, code=ControlCode.FCT)
        time_char = Signal(DataChar)
        m.d.comb += _fields(time_char, parity=1, flag=0, data=self.time)

        # Single characters: odd parity over the previous bits, P and the flag.
        fct = Signal(ControlChar)
        m.d.comb += _fields(fct, parity=par, flag=1, code=ControlCode.FCT)
        nchar_data = Signal(DataChar)
        m.d.comb += _fields(nchar_data, parity=~par, flag=0, data=self.nchar.p.data)
        nchar_ctrl = Signal(ControlChar)
        m.d.comb += _fields(nchar_ctrl, parity=par, flag=1,
                            code=Mux(self.nchar.p.kind == CharKind.EOP,
                                     ControlCode.EOP, ControlCode.EEP))

        # `nchar.ready` does not look at `nchar.valid`: the host sees a Moore-style ready.
        m.d.comb += self.nchar.ready.eq(ds.groups.ready & ~self.send_time & ~self.send_fct)

        bits    = ds.groups.p.bits
        length  = ds.groups.p.length
        par_new = Signal()
        with m.If(self.send_time):
            m.d.comb += [
                bits.eq(Cat(esc, time_char)),
                length.eq(TIME_BITS),
                par_new.eq(self.time.xor()),
                self.time_sent.eq(ds.groups.ready),
            ]
        with m.Elif(self.send_fct):
            m.d.comb += [
                bits.eq(fct),
                length.eq(CONTROL_BITS),
                par_new.eq(0),
                self.fct_sent.eq(ds.groups.ready),
            ]
        with m.Elif(self.nchar.valid):
            with m.If(self.nchar.p.kind == CharKind.DATA):
                m.d.comb += [
                    bits.eq(nchar_data),
                    length.eq(DATA_BITS),
                    par_new.eq(self.nchar.p.data.xor()),
                ]
            with m.Else():
                m.d.comb += [
                    bits.eq(nchar_ctrl),
                    length.eq(CONTROL_BITS),
                    par_new.eq(1),          # EOP and EEP have one control bit set
                ]
        with m.Else():
            m.d.comb += [
                bits.eq(Cat(esc, null_fct)),
                length.eq(NULL_BITS),
                par_new.eq(0),
            ]

        with m.If(~self.enable):
            m.d.sync += par.eq(0)
        with m.Elif(ds.groups.ready):
            m.d.sync += par.eq(par_new)
        return m
