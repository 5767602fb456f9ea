"""The link: SpaceWire characters, link states, error classes, credits, codec parameters.

# Ref: ECSS-E-ST-50-12C §7.2 (data characters), §7.3 (control characters, NULL, time-codes),
#      §7.4 (parity), §8.5 (link state machine, flow control), §6.6 (signalling rate).

The values the link's gateware (:mod:`mrm_cosim.hdl.link`, whose :mod:`~mrm_cosim.hdl.link.chars`
gives them Amaranth shapes) and its cycle-level reference
(:class:`~mrm_cosim.hdl.link.codec_ref.CodecRef`) share, so that both encode the same characters
and accept and refuse exactly the same parameters.

Bits are numbered in transmission order: bit 0 of every on-wire layout is the first bit on the
line. A data character is ``P 0 D0..D7`` (10 bits, data LSB first); a control character is
``P 1 C0 C1`` (4 bits). The standard writes the four control characters as ``P100`` (FCT),
``P101`` (EOP), ``P110`` (EEP) and ``P111`` (ESC), left to right in transmission order, so with
``C0`` as the least significant bit of :class:`ControlCode` their values are FCT = 0b00,
EOP = 0b10, EEP = 0b01, ESC = 0b11.

The parity bit ``P`` of a character covers the data or control bits of the *previous*
character and the ``P`` and flag bits of the current one; their sum is odd (§7.4).
"""

import enum

__all__ = ["CharKind", "ControlCode", "LinkState", "ERROR_CLASSES",
           "DATA_BITS", "CONTROL_BITS", "NULL_BITS", "TIME_BITS", "GROUP_BITS", "NULL_PATTERN",
           "FCT_CREDIT", "MAX_CREDIT", "CREDIT_TIMEOUT", "CREDIT_AUDIT",
           "DEFAULT_SLOTS", "DEFAULT_RUN_DIV",
           "MAX_SLOTS", "MAX_BITS_PER_CYCLE", "min_div", "check_slots", "check_div",
           "check_cycles", "rest_credit",
           "codec_params", "slot_at"]


class CharKind(enum.IntEnum):
    """Kind of an N-char on host streams (2 bits)."""

    DATA = 0  # data character, 8 bits of data
    EOP  = 1  # normal end of packet
    EEP  = 2  # error end of packet


class ControlCode(enum.IntEnum):
    """The two control bits of a control character, ``C0`` in bit 0 (sent first)."""

    FCT = 0b00  # P100: flow control token
    EOP = 0b10  # P101: normal end of packet (EOP_1)
    EEP = 0b01  # P110: error end of packet (EOP_2)
    ESC = 0b11  # P111: escape (ESC+FCT = NULL, ESC+data = time-code)


class LinkState(enum.IntEnum):
    """State of the link state machine (§8.5), in the order a link passes through them."""

    ERROR_RESET = 0
    ERROR_WAIT  = 1
    READY       = 2
    STARTED     = 3
    CONNECTING  = 4
    RUN         = 5


#: Classes of the saturating 16-bit error counters, errors that took the link to Error-Reset,
#: in the order of the gateware's ``ErrorCounts`` fields:
#: ``disconnect`` — no transition for the disconnect timeout (§8.5.3, 850 ns nominal);
#: ``parity`` — parity check failed (§7.4); ``escape`` — ESC followed by ESC, EOP or EEP;
#: ``credit`` — FCT beyond 56 outstanding, or an N-char beyond the credit given;
#: ``sequence`` — FCT, N-char or time-code in a state where the standard forbids it;
#: ``credit_timeout`` — credit went astray, by one of two rules of ours: inside a packet, credit
#: we announced (FCTs sent) went unused for the credit timeout (the peer is starved of credit
#: we believe it holds: an FCT of ours was lost on the line); or the credit audit: we sent no
#: N-char for the audit time and still do not hold the credit a drained peer grants (an FCT of
#: the peer's was lost, or one appeared that it never sent) (docs/link.md "Lost FCTs"). The
#: first five are the standard's; the last is ours, and recovers the credit the standard's way
#: (Error-Reset, a new handshake).
ERROR_CLASSES = ("disconnect", "parity", "escape", "credit", "sequence", "credit_timeout")

#: Line bits of a data character, a control character, a NULL and a time-code.
DATA_BITS    = 10
CONTROL_BITS = 4
NULL_BITS    = 8
TIME_BITS    = 14

#: Longest group of line bits the transmitter takes at once: a time-code (ESC + data).
GROUP_BITS = TIME_BITS

#: The last seven bits of the first NULL, oldest in bit 6: ``1 1 1`` (ESC after its parity)
#: then ``0 1 0 0`` (FCT with parity 0). The receiver looks for it before it frames characters.
NULL_PATTERN = 0b1110100

#: Flow control: one FCT grants 8 N-chars; at most 56 may be outstanding (§8.5 / flow control).
FCT_CREDIT = 8
MAX_CREDIT = 56

#: Widest SERDES supported (line samples per cycle and line).
MAX_SLOTS = 8

#: Most line bits a cycle may carry: with at most 4 a cycle holds at most one character
#: boundary, which the character receiver (one commit per cycle) and the transmitter's refill
#: rule (a group of at least 4 bits per cycle keeps the line busy) rely on. A bit period is
#: therefore at least ``min_div(slots)`` slots.
MAX_BITS_PER_CYCLE = 4


def slot_at(t: int, phase: int, period: int, slots: int) -> tuple[int, int] | None:
    """Where a sender's line level at time ``t`` lies (clocks of their own, docs/clocks.md):
    ``(cycle, slot)`` — bit ``slot`` of its line word of cycle ``cycle``, the cycle
    ``[phase + cycle·period, phase + (cycle+1)·period)`` cut into ``slots`` equal slots — or
    None before its cycle 0. Exact integers in any time unit; the one resampler of
    :class:`cosim.clocks.ClockedEngine` and :mod:`testbench.clocks`."""
    rel = t - phase
    if rel < 0:
        return None
    c, r = divmod(rel, period)
    return c, r * slots // period


def min_div(slots: int) -> int:
    """Shortest bit period, in slots, a transmitter of ``slots`` slots per cycle may use."""
    return -(-slots // MAX_BITS_PER_CYCLE)


def _is_int(value):
    return isinstance(value, int) and not isinstance(value, bool)


def check_slots(slots):
    if not _is_int(slots) or not 1 <= slots <= MAX_SLOTS:
        raise ValueError(f"Slots per cycle must be an integer from 1 to {MAX_SLOTS}, "
                         f"not {slots!r}")


def check_div(div, name, slots=1):
    if not _is_int(div) or div < min_div(slots):
        raise ValueError(f"{name} must be an integer number of slots of at least "
                         f"{min_div(slots)} (at most {MAX_BITS_PER_CYCLE} bits per cycle), "
                         f"not {div!r}")


def check_cycles(cycles, name, minimum=1):
    if not _is_int(cycles) or cycles < minimum:
        raise ValueError(f"{name} must be an integer number of cycles of at least {minimum}, "
                         f"not {cycles!r}")


#: Default credit timeout, cycles (12.8 µs): far beyond any pause inside a packet of the
#: project's hosts (they stream a packet from a buffer; a time-code or an FCT between two of
#: its characters costs at most 5 cycles), far below anything a control period notices.
CREDIT_TIMEOUT = 640

#: Default credit audit, cycles (25.6 µs): after this long without sending an N-char, a
#: transmitter must hold exactly the credit its peer grants once its receive FIFO is drained
#: (:func:`rest_credit`). Far beyond the time a peer of the project needs to drain its FIFO and
#: send its FCTs (≈ 100 cycles at the run rate) or to unblock a forwarding path held by a
#: starved link further down (the credit timeout, then the restart's spill), far below anything
#: a control period notices: the 1 ms cycle's links are silent for most of every period, so a
#: lost FCT is found in the period it was lost in.
CREDIT_AUDIT = 2 * CREDIT_TIMEOUT


def rest_credit(rx_fifo_depth: int) -> tuple[int, int]:
    """Credit a drained receiver of ``rx_fifo_depth`` entries has granted, as ``(low, high)``:
    more than ``low``, at most ``high``.

    The receiver sends an FCT while ``rx_credit ≤ 48`` and its FIFO has room for 8 more beyond
    the credit and one entry in reserve (``level + rx_credit ≤ depth − 9``): with the FIFO empty
    it stops at the first value above ``low = min(48, depth − 9)``, which is at most 8 above it
    (the residue of ``rx_credit`` mod 8 depends on where the last packet ended). A peer built
    with the same depth (the links of one chain are) holds that much once nothing is in flight.
    """
    low = min(MAX_CREDIT - FCT_CREDIT, rx_fifo_depth - FCT_CREDIT - 1)
    return low, low + FCT_CREDIT


#: Default SERDES: 6 line samples per 20 ns cycle (300 MS/s), and the default run rate: 2 slots
#: per bit = 150 Mbit/s, two samples per bit (docs/link.md "Receiver margin").
DEFAULT_SLOTS = 6
DEFAULT_RUN_DIV = 2


def codec_params(*, slots=DEFAULT_SLOTS, start_div=None, run_div=DEFAULT_RUN_DIV,
                 max_run_div=None, reset_cycles=320, wait_cycles=640,
                 disconnect_cycles=43, rx_fifo_depth=64, credit_timeout=CREDIT_TIMEOUT,
                 credit_audit=CREDIT_AUDIT):
    """Check the codec's parameters; return them with ``start_div`` (10 Mbit/s) and
    ``max_run_div`` (the slowest run rate the ``run_div`` port selects: ``start_div``, or
    ``run_div`` if that is slower) resolved.

    ``run_div`` is the reset value of the codec's run-rate port. ``credit_timeout`` 0 turns the
    lost-FCT check off (for hosts that pause inside packets). ``credit_audit`` 0 turns the
    credit audit off (for a peer whose receive FIFO is not ``rx_fifo_depth`` deep, or whose host
    may leave characters in it for longer than the audit time).
    """
    check_slots(slots)
    if start_div is None:
        start_div = 5 * slots
    check_div(start_div, "Start bit period", slots)
    check_div(run_div, "Run bit period", slots)
    if max_run_div is None:
        max_run_div = max(start_div, run_div)
    check_div(max_run_div, "Slowest run bit period", slots)
    if max_run_div < run_div:
        raise ValueError(f"Slowest run bit period must be at least the run bit period "
                         f"{run_div}, not {max_run_div!r}")
    check_cycles(disconnect_cycles, "Disconnect time", 3)
    check_cycles(wait_cycles, "Wait time")
    # Exchange of silence: the peer must have detected our silence and fallen silent itself
    # before our receiver comes out of Error-Reset (+ 6: D falls one cycle after S, at both
    # ends).
    check_cycles(reset_cycles, "Reset time (disconnect time + 6)", disconnect_cycles + 6)
    if not _is_int(rx_fifo_depth) or rx_fifo_depth < FCT_CREDIT + 1:
        raise ValueError(f"Receive FIFO depth must be an integer of at least "
                         f"{FCT_CREDIT + 1}, not {rx_fifo_depth!r}")
    if not _is_int(credit_timeout) or credit_timeout < 0:
        raise ValueError(f"Credit timeout must be an integer number of cycles, 0 (off) or "
                         f"more, not {credit_timeout!r}")
    if not _is_int(credit_audit) or credit_audit < 0 or credit_audit == 1:
        raise ValueError(f"Credit audit must be an integer number of cycles, 0 (off) or 2 or "
                         f"more, not {credit_audit!r}")
    return dict(slots=slots, start_div=start_div, run_div=run_div, max_run_div=max_run_div,
                reset_cycles=reset_cycles,
                wait_cycles=wait_cycles, disconnect_cycles=disconnect_cycles,
                rx_fifo_depth=rx_fifo_depth, credit_timeout=credit_timeout,
                credit_audit=credit_audit)
