"""SpaceWire characters: host-side N-chars, on-wire encodings, link states, error counters.

# Ref: ECSS-E-ST-50-12C §7.2 (data characters), §7.3 (control characters, NULL, time-codes),
#      §7.4 (parity), §8.5 (link state machine).

Bits are numbered in transmission order: bit 0 of every on-wire layout below is the first bit
on the line. A data character is ``P 0 D0..D7`` (10 bits, data LSB first); a control character
is ``P 1 C0 C1`` (4 bits). The standard writes the four control characters as ``P100`` (FCT),
``P101`` (EOP), ``P110`` (EEP) and ``P111`` (ESC), left to right in transmission order, so with
``C0`` as the least significant bit of :class:`ControlCode` their values are FCT = 0b00,
EOP = 0b10, EEP = 0b01, ESC = 0b11.

The parity bit ``P`` of a character covers the data or control bits of the *previous*
character and the ``P`` and flag bits of the current one; their sum is odd (§7.4).
"""

from amaranth import Mux, Value
from amaranth.lib import data, enum

__all__ = [
    "CharKind", "Char", "ControlCode", "DataChar", "ControlChar", "LinkState", "ErrorCounts",
    "ERROR_CLASSES", "saturating_sum", "saturating_sum_ref",
    "NULL_BITS", "TIME_BITS", "DATA_BITS", "CONTROL_BITS",
]


class CharKind(enum.Enum, shape=2):
    """Kind of an N-char on host streams."""

    DATA = 0  # data character, 8 bits in ``Char.data``
    EOP  = 1  # normal end of packet
    EEP  = 2  # error end of packet


class Char(data.Struct):
    """An N-char as carried on host streams (``data`` is zero for EOP/EEP)."""

    kind: CharKind
    data: 8


class ControlCode(enum.Enum, shape=2):
    """The two control bits of a control character, ``C0`` in bit 0 (sent first)."""

    FCT = 0b00  # P100: flow control token
    EOP = 0b10  # P101: normal end of packet (EOP_1)
    EEP = 0b01  # P110: error end of packet (EOP_2)
    ESC = 0b11  # P111: escape (ESC+FCT = NULL, ESC+data = time-code)


class DataChar(data.Struct):
    """A data character as it appears on the line (bit 0 first)."""

    parity: 1
    flag:   1  # 0 for data characters
    data:   8


class ControlChar(data.Struct):
    """A control character as it appears on the line (bit 0 first)."""

    parity: 1
    flag:   1  # 1 for control characters
    code:   ControlCode


class LinkState(enum.Enum, shape=3):
    """State of the link state machine (§8.5), in the order a link passes through them."""

    ERROR_RESET = 0
    ERROR_WAIT  = 1
    READY       = 2
    STARTED     = 3
    CONNECTING  = 4
    RUN         = 5


class ErrorCounts(data.Struct):
    """Saturating per-class error counters: errors that took the link to Error-Reset."""

    disconnect: 16  # no transition for the disconnect timeout (§8.5.3, 850 ns nominal)
    parity:     16  # parity check failed (§7.4)
    escape:     16  # ESC followed by ESC, EOP or EEP
    credit:     16  # FCT beyond 56 outstanding, or an N-char beyond the credit given
    sequence:   16  # FCT, N-char or time-code in a state where the standard forbids it


#: The fields of :class:`ErrorCounts`, in layout order.
ERROR_CLASSES = tuple(data.Layout.cast(ErrorCounts).members)

def saturating_sum(values, width: int = 16) -> Value:
    """Sum of unsigned ``values`` saturated at ``2**width - 1`` (combinational).

    How a node reports several saturating counters as one (its link's error classes in Comm A);
    the reference is :func:`saturating_sum_ref`.
    """
    total = sum(Value.cast(v).as_unsigned() for v in values)
    top = (1 << width) - 1
    return Mux(total >= top, top, total)[:width]


def saturating_sum_ref(values, width: int = 16) -> int:
    """Reference of :func:`saturating_sum`."""
    return min(sum(int(v) for v in values), (1 << width) - 1)


#: Line bits of a data character, a control character, a NULL and a time-code.
DATA_BITS    = 10
CONTROL_BITS = 4
NULL_BITS    = 8
TIME_BITS    = 14
