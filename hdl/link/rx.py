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

The bits arrive packed (:class:`~hdl.link.ds.DSReceiver`: the cycle's bits first, their
count as a thermometer code), up to ``slots`` of them. The decode is not a walk over them,
one bit after another (with six slots that walk was the node's slowest path, 21.5 ns on an
ECP5), but closed forms of what the walk would find, each from the registers and a few of
the cycle's bits:

* which bits are flags: the first follows from the framing state at the start of the cycle
  (or two bits after the end of the NULL pattern), each later one 4 or 10 bits after a flag
  with the control or data flag bit;
* the parity checked at a flag: the XOR of the bits since the last flag;
* the character a flag commits: the one that ended two bits earlier, whose payload bits are the
  newest bits received before the parity bit — of this cycle and of an 8-bit history of the
  last bits received (which also serves the search for the first NULL);
* the escape state at a flag: that of the previous flag in the cycle (at most one per four
  bits), or of the registers.

The registers after the cycle are the same closed forms at the bit count, picked by the
thermometer code; only the framing state (one-hot) is stepped bit by bit.
"""

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.link import (CONTROL_BITS, DATA_BITS, NULL_PATTERN, check_cycles,
                                     check_slots)

from ..helpers import rejecting
from .chars import Char, CharKind, ControlCode

__all__ = ["CharReceiver"]


# The framing state of a bit, one-hot: parity bit, flag bit, then the payload bits of a control
# or a data character (the bit's position within its character, as the walk's `pos` and
# `ctrl`). A character of n bits has its next flag n bits after its own.
_PAR, _FLAG = 0, 1
_CTRL = list(range(2, CONTROL_BITS))                                    # positions 2, 3
_DATA = list(range(CONTROL_BITS, CONTROL_BITS + DATA_BITS - 2))         # positions 2 … 9
_N_STATES = CONTROL_BITS + DATA_BITS - 2


def _to_flag(state: int) -> int:
    """Bits from a bit in ``state`` to the next flag bit (0 for a flag bit)."""
    if state == _FLAG:
        return 0
    if state == _PAR:
        return 1
    if state in _CTRL:
        return CONTROL_BITS - (state - _CTRL[0] + 2) + 1
    return DATA_BITS - (state - _DATA[0] + 2) + 1


def _reversed_bits(value: int, width: int) -> int:
    return int(f"{value:0{width}b}"[::-1], 2)


def _nearest(events, values, default):
    """The value of the latest of ``events`` (a list of 1-bit values, earliest first) that is
    high, else ``default``: an OR of terms, each gated by its event and by no later one (not a
    chain of multiplexers, whose last select would wait for every earlier one)."""
    result = Mux(Cat(*events, Const(0)).any(), 0, default)
    for i, (event, value) in enumerate(zip(events, values, strict=True)):
        later = Cat(*events[i + 1:], Const(0)).any()
        result = result | Mux(event & ~later, value, 0)
    return result


class CharReceiver(wiring.Component):
    """Frame and decode received line bits.

    Parameters
    ----------
    slots : int
        Line slots per clock cycle, so at most that many bits per cycle (1 to 8).
    disconnect_limit : int
        Cycles without a line transition, counted from the first quiet cycle, after which
        ``err_disconnect`` rises.

    Attributes
    ----------
    enable : In(1)
        Low: the receiver is held in reset (every register below cleared).
    bit_valid, bit_data, activity : In
        From :class:`~hdl.link.ds.DSReceiver` (``packed_valid``, ``packed_data``): the cycle's
        bits, the first in bit 0, and a thermometer code of how many there are.
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
        n = self._slots
        c, v = self.bit_data, self.bit_valid

        # Registers: the state before the cycle's first bit.
        got_null   = self.got_null
        frame      = Signal(_N_STATES)   # framing state of the next bit, one-hot (0: searching)
        hist       = Signal(8)           # the last bits received, newest in bit 7
        par        = Signal()            # parity of the bits since the last flag
        pend_valid = Signal()            # a complete character waits for the next parity
        pend_ctrl  = Signal()
        pend_bits  = Signal(8)           # its payload bits (the newest in bit 7)
        esc        = Signal()            # the last committed character was ESC
        registers = [got_null, frame, hist, par, pend_valid, pend_ctrl, pend_bits, esc]

        def newest(k):
            """The last 8 bits received up to (not including) bit ``k`` of this cycle."""
            return Cat(hist, c[:k])[k:k + 8]

        # The first NULL: the newest bits equal the pattern (newest in bit 0 of NULL_PATTERN).
        pattern = _reversed_bits(NULL_PATTERN, 7)
        hit = [newest(j + 1)[1:] == pattern for j in range(n)]
        det = []
        for j in range(n):
            det_j = Signal(name=f"det_{j}")
            m.d.comb += det_j.eq(~got_null & hit[j] & ~Cat(*hit[:j], Const(0)).any())
            det.append(det_j)
        searching_before = [~got_null & Cat(*hit[:j], Const(0)).any() for j in range(n + 1)]

        # Which bits are flag bits (for a bit count beyond j: bits up to j all valid). Two
        # beyond the cycle, for the ends of characters below.
        flag = _flags(m, frame, c, det, n)
        # The last payload bit of a character (two bits before the next flag, not the NULL).
        end = [flag[k + 2] & ~det[k] for k in range(n)]
        ctrl0 = Cat(frame[s] for s in _CTRL).any()
        # The character ending at bit k is a control character.
        end_ctrl = [flag[k - 2] if k >= 2 else ctrl0 for k in range(n)]

        def parity_at(j):
            """Parity before bit j: XOR of the bits since the last flag (or the NULL)."""
            resets = [flag[k] | det[k] for k in range(j)]
            since = [c[k + 1:j].xor() if k + 1 < j else Const(0) for k in range(j)]
            start = Mux(got_null, par ^ c[:j].xor(), par) if j else par
            return _nearest(resets, since, start)

        def pending_at(j):
            """(valid, ctrl, bits) of the pending character before bit j: one that ended at
            j − 1 or j − 2 (a later end is followed by its flag, which takes it), else the
            registers' while no flag or NULL came in between (their bits and ctrl are then
            unused, so they need not be the walk's, only `valid` must)."""
            valid, ctrl, bits = pend_valid, pend_ctrl, pend_bits
            if j:
                valid = pend_valid & ~Cat(flag[k] | det[k] for k in range(j)).any()
            for k in range(max(j - 2, 0), j):
                valid = valid | end[k]
                ctrl = Mux(end[k], end_ctrl[k], ctrl)
                bits = Mux(end[k], newest(k + 1), bits)
            return valid, ctrl, bits

        # At a flag bit j, the character it commits: the one that ended two bits before it
        # (parity and flag bit between). The parity restarted after that character's own flag,
        # j − CONTROL_BITS or j − DATA_BITS, or after the NULL (ending at j − 2), or before the
        # cycle; the escape state is the one after that flag (0 after the NULL, else the
        # register's).
        esc_flag, after, commit = [], [], []   # escape state at / after each flag bit
        for j in range(n):
            prev = [j - length for length in (DATA_BITS, CONTROL_BITS) if j >= length]
            null = [det[j - 2]] if j >= 2 else []
            e_j = Signal(name=f"esc_flag_{j}")
            m.d.comb += e_j.eq(_nearest([flag[k] for k in prev] + null,
                                        [after[k] for k in prev] + [Const(0)] * len(null),
                                        Mux(searching_before[j], 0, esc)))
            esc_flag.append(e_j)
            good = Signal(name=f"good_{j}")
            m.d.comb += good.eq(_nearest([flag[k] for k in prev] + null,
                                         [c[k + 1:j + 1].xor() for k in prev + [j - 2] * len(null)],
                                         par ^ c[:j + 1].xor()))
            if j >= 2:
                p_valid = ~det[j - 2]
                p_ctrl = end_ctrl[j - 2]
                p_bits = newest(j - 1)
            else:
                p_valid, p_ctrl, p_bits = pend_valid, pend_ctrl, pend_bits
            cm = Signal(name=f"commit_{j}")
            m.d.comb += cm.eq(flag[j] & good & p_valid)
            commit.append((cm, p_ctrl, p_bits[6:8], p_bits, good))
            a_j = Signal(name=f"esc_after_{j}")     # ESC sets it, other commits clear it
            m.d.comb += a_j.eq(Mux(cm, p_ctrl & ~e_j & (p_bits[6:8] == ControlCode.ESC),
                                   e_j))
            after.append(a_j)
        esc_at = [_nearest(flag[:k], after[:k], Mux(searching_before[k], 0, esc))
                  for k in range(n + 1)]

        # This cycle's events (bits below the count only).
        (ev_fct, ev_nchar, ev_time, ev_perr, ev_eerr, nchar_values,
         time_values) = _events(v, commit, esc_flag, flag, n)
        nchar_value = _nearest(ev_nchar, nchar_values, self.nchar.as_value())
        time_value = _nearest(ev_time, time_values, self.time)

        # The registers after the cycle: the values before bit `count`.
        exactly = [~v[0]] + [v[k - 1] & ~v[k] for k in range(1, n)] + [v[n - 1]]

        def at_count(values):
            return _or([Mux(exactly[k], values[k], 0) for k in range(n + 1)])

        steps = _frame_steps(m, frame, c, det, n)
        pendings = [pending_at(k) for k in range(n + 1)]
        after_cycle = [
            got_null | Cat(v[j] & det[j] for j in range(n)).any(),
            at_count(steps),
            at_count([newest(k) for k in range(n + 1)]),
            at_count([parity_at(k) for k in range(n + 1)]),
            at_count([p[0] for p in pendings]),
            at_count([p[1] for p in pendings]),
            at_count([p[2] for p in pendings]),
            at_count(esc_at),
        ]

        self._update(m, registers, after_cycle, ev_fct, ev_nchar, ev_time, ev_perr, ev_eerr,
                     nchar_value, time_value)
        return m

    def _update(self, m, registers, after_cycle, ev_fct, ev_nchar, ev_time, ev_perr, ev_eerr,
                nchar_value, time_value):
        """The registers and outputs after the cycle, and the disconnect timer
        (``disconnect_limit`` cycles of silence after the first transition)."""
        armed = Signal()
        quiet = Signal(range(self._limit + 1))
        m.d.comb += self.err_disconnect.eq(armed & (quiet == self._limit))

        with m.If(~self.enable):
            m.d.sync += [reg.eq(0) for reg in registers]
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
            m.d.sync += [reg.eq(value) for reg, value in zip(registers, after_cycle, strict=True)]
            m.d.sync += [
                self.got_fct.eq(Cat(ev_fct).any()),
                self.got_nchar.eq(Cat(ev_nchar).any()),
                self.got_time.eq(Cat(ev_time).any()),
                self.err_parity.eq(self.err_parity | Cat(ev_perr).any()),
                self.err_escape.eq(self.err_escape | Cat(ev_eerr).any()),
                self.nchar.eq(nchar_value),
                self.time.eq(time_value),
                armed.eq(armed | self.activity),
            ]
            with m.If(self.activity):
                m.d.sync += quiet.eq(0)
            with m.Elif(armed & (quiet != self._limit)):
                m.d.sync += quiet.eq(quiet + 1)


def _flags(m, frame, c, det, n):
    """Which bits are flag bits (for a bit count beyond j: bits up to j all valid), two beyond
    the cycle for the ends of characters."""
    flag = []
    for j in range(n + 2):
        terms = [frame[s] for s in range(_N_STATES) if _to_flag(s) == j]
        if j >= 2:
            terms.append(det[j - 2])            # the NULL's FCT ends at j - 2
        if j >= CONTROL_BITS:
            terms.append(flag[j - CONTROL_BITS] & c[j - CONTROL_BITS])
        if j >= DATA_BITS:
            terms.append(flag[j - DATA_BITS] & ~c[j - DATA_BITS])
        f_j = Signal(name=f"flag_{j}")
        m.d.comb += f_j.eq(Cat(*terms, Const(0)).any())
        flag.append(f_j)
    return flag


def _events(v, commit, esc_flag, flag, n):
    """The cycle's events per bit (bits below the count only): FCT, N-char, time-code, parity
    and escape errors, and the N-char and time-code values."""
    ev_fct, ev_nchar, ev_time, ev_perr, ev_eerr = [], [], [], [], []
    nchar_values, time_values = [], []
    for j in range(n):
        cm, pc, code, bits, good = commit[j]
        cm_j = v[j] & cm
        e = esc_flag[j]
        ev_perr.append(v[j] & flag[j] & ~good)
        ev_eerr.append(cm_j & pc & e & (code != ControlCode.FCT))
        ev_fct.append(cm_j & pc & ~e & (code == ControlCode.FCT))
        eop = cm_j & pc & ~e & (code == ControlCode.EOP)
        eep = cm_j & pc & ~e & (code == ControlCode.EEP)
        data = cm_j & ~pc & ~e
        tcode = cm_j & ~pc & e
        ev_nchar.append(eop | eep | data)
        ev_time.append(tcode)
        kind = Mux(data, CharKind.DATA, Mux(eop, CharKind.EOP, CharKind.EEP))
        nchar_values.append(Cat(kind, Mux(data, bits, 0)))
        time_values.append(bits)
    return ev_fct, ev_nchar, ev_time, ev_perr, ev_eerr, nchar_values, time_values


def _frame_steps(m, frame, c, det, n):
    """The one-hot framing state before each bit of the cycle (``frame`` before the first)."""
    steps = [frame]
    for j in range(n):
        s, nxt = steps[-1], Signal(_N_STATES, name=f"frame_{j + 1}")
        m.d.comb += [
            nxt[_FLAG].eq(s[_PAR]),
            nxt[_CTRL[0]].eq(s[_FLAG] & c[j]),
            nxt[_DATA[0]].eq(s[_FLAG] & ~c[j]),
            nxt[_PAR].eq(s[_CTRL[-1]] | s[_DATA[-1]] | det[j]),
        ]
        for states in (_CTRL, _DATA):
            for a, b in zip(states[:-1], states[1:], strict=True):
                m.d.comb += nxt[b].eq(s[a])
        steps.append(nxt)
    return steps


def _or(values):
    result = values[0]
    for value in values[1:]:
        result = result | value
    return result
