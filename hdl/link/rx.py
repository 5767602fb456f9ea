"""Character receiver: line bits to FCT, N-chars and time-codes, with the receive errors.

# Ref: ECSS-E-ST-50-12C §7.2-§7.4 (characters, parity), §8.5.3 (gotNULL, gotFCT, gotN-Char,
#      gotTime-Code; disconnect, parity and escape errors).

Until the first NULL the receiver only looks for the bit sequence ``1 1 1 0 1 0 0`` (an ESC
without its parity bit, then the FCT ``0 1 0 0``: the parity of the first ESC covers bits the
receiver never saw, so it is not checked). From then on it frames characters and checks parity
at each flag bit: the parity of a character covers the previous one, so a character is
*committed* (decoded and reported) only when the next character's parity and flag bits have
arrived and checked good. A character hit by a bit error is therefore never reported.

A disconnect error is flagged once the line has shown no transition on D or S for
``disconnect_limit`` cycles after the first transition since the receiver was enabled.
"""

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.link import NULL_PATTERN, check_cycles, check_slots

from ..helpers import rejecting
from .chars import Char, CharKind, ControlCode

__all__ = ["CharReceiver"]


class CharReceiver(wiring.Component):
    """Frame and decode received line bits.

    Parameters
    ----------
    slots : int
        Line slots per clock cycle (1 to 4).
    disconnect_limit : int
        Cycles without a line transition, counted from the first quiet cycle, after which
        ``err_disconnect`` rises.

    Attributes
    ----------
    enable : In(1)
        Low: the receiver is held in reset (every register below cleared).
    bit_valid, bit_data, activity : In
        From :class:`~hdl.link.ds.DSReceiver`.
    got_null : Out(1)
        A NULL has been received since the receiver was enabled (level).
    got_fct, got_nchar, got_time : Out(1)
        One-cycle strobes: an FCT, an N-char (``nchar``) or a time-code (``time``) arrived.
    nchar : Out(Char)
        The N-char of ``got_nchar``.
    time : Out(8)
        Value of the last time-code received (control flags in bits 7:6).
    err_parity, err_escape : Out(1)
        Parity or escape error seen (sticky until the receiver is reset).
    err_disconnect : Out(1)
        Disconnect timeout (level).
    """

    def __init__(self, *, slots: int, disconnect_limit: int):
        with rejecting(self):
            check_slots(slots)
            check_cycles(disconnect_limit, "Disconnect limit")
        self._slots = slots
        self._limit = disconnect_limit
        super().__init__({
            "enable":         In(1),
            "bit_valid":      In(slots),
            "bit_data":       In(slots),
            "activity":       In(1),
            "got_null":       Out(1),
            "got_fct":        Out(1),
            "got_nchar":      Out(1),
            "nchar":          Out(Char),
            "got_time":       Out(1),
            "time":           Out(8),
            "err_parity":     Out(1),
            "err_escape":     Out(1),
            "err_disconnect": Out(1),
        })

    def elaborate(self, platform):
        m = Module()

        # Framing state, carried from slot to slot within a cycle.
        state = {
            "got_null":   self.got_null,
            "search":     Signal(7),        # last bits before the first NULL, newest in bit 0
            "pos":        Signal(range(10)),  # bit position within the character (0 = parity)
            "ctrl":       Signal(),         # the character being received is a control char
            "par":        Signal(),         # running parity over the bits since the last flag
            "shift":      Signal(8),        # payload bits, shifted in at bit 7
            "pend_valid": Signal(),         # a complete character waits for the next parity
            "pend_ctrl":  Signal(),
            "pend_bits":  Signal(8),
            "esc":        Signal(),         # the last committed character was ESC
        }
        registers = dict(state)

        ev_fct, ev_nchar, ev_time, ev_perr, ev_eerr = [], [], [], [], []
        ev_kind, ev_bits = [], []
        for i in range(self._slots):
            cur = state
            nxt = {k: Signal.like(v, name=f"{k}_{i}") for k, v in cur.items()}
            m.d.comb += [nxt[k].eq(cur[k]) for k in cur]

            b      = self.bit_data[i]
            fct    = Signal(name=f"ev_fct_{i}")
            nchar  = Signal(name=f"ev_nchar_{i}")
            kind   = Signal(CharKind, name=f"ev_kind_{i}")
            tcode  = Signal(name=f"ev_time_{i}")
            perr   = Signal(name=f"ev_perr_{i}")
            eerr   = Signal(name=f"ev_eerr_{i}")
            code   = cur["pend_bits"][6:8]

            with m.If(self.bit_valid[i]):
                with m.If(~cur["got_null"]):
                    search = Cat(b, cur["search"][:6])
                    m.d.comb += nxt["search"].eq(search)
                    with m.If(search == NULL_PATTERN):
                        m.d.comb += [
                            nxt["got_null"].eq(1),
                            nxt["pos"].eq(0),
                            nxt["par"].eq(0),       # the FCT's control bits are 0 0
                            nxt["pend_valid"].eq(0),
                            nxt["esc"].eq(0),
                        ]
                with m.Elif(cur["pos"] == 0):           # parity bit
                    m.d.comb += [
                        nxt["par"].eq(cur["par"] ^ b),
                        nxt["pos"].eq(1),
                    ]
                with m.Elif(cur["pos"] == 1):           # flag bit: check parity, commit
                    with m.If(~(cur["par"] ^ b)):
                        m.d.comb += perr.eq(1)
                    with m.Elif(cur["pend_valid"]):
                        with m.If(cur["pend_ctrl"]):
                            with m.If(cur["esc"]):
                                m.d.comb += nxt["esc"].eq(0)
                                with m.If(code != ControlCode.FCT):  # ESC ESC/EOP/EEP
                                    m.d.comb += eerr.eq(1)
                            with m.Else():
                                with m.Switch(code):
                                    with m.Case(ControlCode.FCT):
                                        m.d.comb += fct.eq(1)
                                    with m.Case(ControlCode.EOP):
                                        m.d.comb += [nchar.eq(1), kind.eq(CharKind.EOP)]
                                    with m.Case(ControlCode.EEP):
                                        m.d.comb += [nchar.eq(1), kind.eq(CharKind.EEP)]
                                    with m.Case(ControlCode.ESC):
                                        m.d.comb += nxt["esc"].eq(1)
                        with m.Else():
                            with m.If(cur["esc"]):
                                m.d.comb += [tcode.eq(1), nxt["esc"].eq(0)]
                            with m.Else():
                                m.d.comb += [nchar.eq(1), kind.eq(CharKind.DATA)]
                    m.d.comb += [
                        nxt["ctrl"].eq(b),
                        nxt["par"].eq(0),
                        nxt["pos"].eq(2),
                        nxt["pend_valid"].eq(0),
                    ]
                with m.Else():                          # payload bits
                    shift = Cat(cur["shift"][1:], b)
                    last = Mux(cur["ctrl"], cur["pos"] == 3, cur["pos"] == 9)
                    m.d.comb += [
                        nxt["shift"].eq(shift),
                        nxt["par"].eq(cur["par"] ^ b),
                        nxt["pos"].eq(Mux(last, 0, cur["pos"] + 1)),
                    ]
                    with m.If(last):
                        m.d.comb += [
                            nxt["pend_valid"].eq(1),
                            nxt["pend_ctrl"].eq(cur["ctrl"]),
                            nxt["pend_bits"].eq(shift),
                        ]

            ev_fct.append(fct)
            ev_nchar.append(nchar)
            ev_kind.append(kind)
            ev_bits.append(cur["pend_bits"])
            ev_time.append(tcode)
            ev_perr.append(perr)
            ev_eerr.append(eerr)
            state = nxt

        # At most one character is committed per cycle (slots <= 4 < the shortest character),
        # so the slot events can simply be merged.
        armed = Signal()
        quiet = Signal(range(self._limit + 1))
        m.d.comb += self.err_disconnect.eq(armed & (quiet == self._limit))

        with m.If(~self.enable):
            m.d.sync += [reg.eq(0) for reg in registers.values()]
            m.d.sync += [
                self.got_fct.eq(0),
                self.got_nchar.eq(0),
                self.nchar.eq(0),
                self.got_time.eq(0),
                self.time.eq(0),
                self.err_parity.eq(0),
                self.err_escape.eq(0),
                armed.eq(0),
                quiet.eq(0),
            ]
        with m.Else():
            m.d.sync += [reg.eq(state[name]) for name, reg in registers.items()]
            m.d.sync += [
                self.got_fct.eq(Cat(ev_fct).any()),
                self.got_nchar.eq(Cat(ev_nchar).any()),
                self.got_time.eq(Cat(ev_time).any()),
                self.err_parity.eq(self.err_parity | Cat(ev_perr).any()),
                self.err_escape.eq(self.err_escape | Cat(ev_eerr).any()),
                armed.eq(armed | self.activity),
            ]
            for nchar, kind, bits in zip(ev_nchar, ev_kind, ev_bits, strict=True):
                with m.If(nchar):
                    m.d.sync += [
                        self.nchar.kind.eq(kind),
                        self.nchar.data.eq(Mux(kind == CharKind.DATA, bits, 0)),
                    ]
            for tcode, bits in zip(ev_time, ev_bits, strict=True):
                with m.If(tcode):
                    m.d.sync += self.time.eq(bits)
            with m.If(self.activity):
                m.d.sync += quiet.eq(0)
            with m.Elif(armed & (quiet != self._limit)):
                m.d.sync += quiet.eq(quiet + 1)
        return m
