"""SpaceWire characters as Amaranth shapes: host-side N-chars, on-wire encodings, link states,
error counters.

# Ref: ECSS-E-ST-50-12C §7.2 (data characters), §7.3 (control characters, NULL, time-codes),
#      §7.4 (parity), §8.5 (link state machine).

The values (character kinds, control codes, link states, error classes, bit counts) are
defined once in :mod:`mrm_cosim.protocol.link`, with the bit numbering: bit 0 of every
on-wire layout below is the first bit on the line.
"""

from amaranth import Mux, Value
from amaranth.lib import data

from mrm_cosim.protocol import link

from ..helpers import shaped_enum

__all__ = ["CharKind", "Char", "ControlCode", "DataChar", "ControlChar", "LinkState",
           "ErrorCounts", "saturating_sum"]


#: Kind of an N-char on host streams (:class:`mrm_cosim.protocol.link.CharKind`).
CharKind = shaped_enum(link.CharKind, 2, __name__)

#: The two control bits of a control character, ``C0`` in bit 0 (sent first)
#: (:class:`mrm_cosim.protocol.link.ControlCode`).
ControlCode = shaped_enum(link.ControlCode, 2, __name__)

#: State of the link state machine (:class:`mrm_cosim.protocol.link.LinkState`).
LinkState = shaped_enum(link.LinkState, 3, __name__)


class Char(data.Struct):
    """An N-char as carried on host streams (``data`` is zero for EOP/EEP)."""

    kind: CharKind
    data: 8


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


class ErrorCounts(data.Struct):
    """Saturating per-class error counters, errors that took the link to Error-Reset: one
    16-bit field per class of :data:`mrm_cosim.protocol.link.ERROR_CLASSES`, in that order."""

    __annotations__ = {name: 16 for name in link.ERROR_CLASSES}


def saturating_sum(values, width: int = 16) -> Value:
    """Sum of unsigned ``values`` saturated at ``2**width - 1`` (combinational).

    How a node reports several saturating counters as one (its link's error classes in Comm A);
    the reference is :func:`~mrm_cosim.hdl.link.codec_ref.saturating_sum_ref`.
    """
    total = sum(Value.cast(v).as_unsigned() for v in values)
    top = (1 << width) - 1
    return Mux(total >= top, top, total)[:width]
