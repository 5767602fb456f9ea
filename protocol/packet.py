"""Packets on the link: types, header, framing and the receiver's checks.

# Ref: ECSS-E-ST-50-12C §5.4 (packet = destination address, cargo, end of packet marker).

The single definition of a frame, used by the master, by the gateware
(:mod:`~mrm_cosim.hdl.link.packet`, :mod:`~mrm_cosim.hdl.link.router`) and by the bit-exact
references (:mod:`~mrm_cosim.hdl.link.packet_ref`):

* frame encoding (:func:`encode`) — the exact character sequence the packetizer emits;
* frame checking (:func:`check_frame`) — which packets a receiver delivers, and why it drops
  the others (:class:`Verdict`).

Characters are plain integers here: ``0..255`` is a data character, :data:`EOP` and :data:`EEP`
(values 0x100 and 0x101, the flag bit set as in a 9-bit N-char) end a packet.

Frame (all data characters, then one EOP)::

    dest | src | type | seq | payload (1..max_payload bytes) | crc[15:8] | crc[7:0] | EOP

The CRC is CRC-16/CCITT-FALSE over dest..payload (:mod:`.crc`).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from .crc import crc16

__all__ = [
    "EOP", "EEP", "MASTER_ADDRESS", "BROADCAST", "HEADER_BYTES", "CRC_BYTES", "DATA_PAYLOAD",
    "DEFAULT_MAX_PAYLOAD", "MIN_PAYLOAD", "COUNTER_MAX", "PacketType", "Verdict", "Header",
    "encode", "split_packets", "check_frame",
]

EOP = 0x100
EEP = 0x101

MASTER_ADDRESS      = 0x00
BROADCAST           = 0xFF
HEADER_BYTES        = 4
CRC_BYTES           = 2
MIN_PAYLOAD         = 1
DATA_PAYLOAD        = 40   # the paper's "data package of 40 bytes" (Comm A/B/C/D)
DEFAULT_MAX_PAYLOAD = 64
COUNTER_MAX         = 0xFFFF  # statistics counters saturate here


class PacketType(enum.IntEnum):
    """Packet types (the ``type`` byte). Other values pass the link layer unchanged."""

    COMM_A = 0x0A  # slave -> master: joint position, velocity, status
    COMM_B = 0x0B  # master -> slave: required joint velocity, V, V_r
    COMM_C = 0x0C  # slave -> master: required net force/moment of Link a and Link b
    COMM_D = 0x0D  # master -> slave: required joint load torque (projection on the axis)
    CONFIG = 0x10  # configuration register write / read-back
    PARAM  = 0x20  # parameter upload (VDC estimates, bounds, gains)
    DMP    = 0x30  # motion-primitive deployment (weights, centres, widths)
    STATUS = 0x40  # status / error counters report


class Verdict(enum.Enum):
    """What the receiver does with one packet."""

    GOOD   = "good"    # delivered to the host
    CRC    = "crc"     # dropped: CRC residue is not zero
    LENGTH = "length"  # dropped: fewer than 7 or more than 6 + max_payload data characters
    EEP    = "eep"     # dropped: ended by an error end of packet


@dataclass(frozen=True)
class Header:
    """Packet header, the first four data characters of a frame, in wire order.

    Attributes
    ----------
    dest : int
        Destination address: 0 the master, 1..254 a node, 255 every node (broadcast).
    src : int
        Source address (the packetizer fills in the node's own address).
    type : int
        A :class:`PacketType` value (any byte is carried).
    seq : int
        Sequence number, modulo 256; a reply carries the sequence of its request.
    """

    dest: int
    src:  int
    type: int
    seq:  int

    def __post_init__(self):
        for name in ("dest", "src", "type", "seq"):
            value = getattr(self, name)
            if not isinstance(value, int) or not 0 <= value <= 255:
                raise ValueError(f"Header.{name} must be an integer in 0..255, not {value!r}")

    def to_bytes(self) -> bytes:
        return bytes((self.dest, self.src, self.type, self.seq))

    @classmethod
    def from_bytes(cls, raw: Sequence[int]) -> Header:
        return cls(raw[0], raw[1], raw[2], raw[3])


def encode(header: Header, payload: Sequence[int], *,
           max_payload: int = DEFAULT_MAX_PAYLOAD) -> list[int]:
    """Characters of one frame: header, payload, CRC (high byte first), EOP.

    Parameters
    ----------
    header : Header
    payload : sequence of int, length 1..max_payload
        Payload bytes.
    max_payload : int
        Largest payload the receivers accept.

    Returns
    -------
    list of int
        ``4 + len(payload) + 2`` data characters, then :data:`EOP`.
    """
    payload = bytes(payload)
    if not MIN_PAYLOAD <= len(payload) <= max_payload:
        raise ValueError(f"Payload must hold {MIN_PAYLOAD}..{max_payload} bytes, "
                         f"not {len(payload)}")
    body = header.to_bytes() + payload
    crc = crc16(body)
    return [*body, crc >> 8, crc & 0xFF, EOP]


def split_packets(chars: Iterable[int]) -> list[list[int]]:
    """Cut a character stream after each EOP/EEP; a trailing unterminated part is dropped."""
    packets, current = [], []
    for char in chars:
        current.append(char)
        if char in (EOP, EEP):
            packets.append(current)
            current = []
    return packets


def check_frame(packet: Sequence[int], *, max_payload: int = DEFAULT_MAX_PAYLOAD
                ) -> tuple[Verdict, Header | None, bytes | None]:
    """Classify one packet (its characters up to and including the EOP/EEP).

    The checks run in this order, as in the gateware: EEP, then length, then CRC.

    Returns
    -------
    verdict : Verdict
    header : Header or None
        Only for :attr:`Verdict.GOOD`.
    payload : bytes or None
        Only for :attr:`Verdict.GOOD`.
    """
    if not packet or packet[-1] not in (EOP, EEP):
        raise ValueError("A packet must end with EOP or EEP")
    body = packet[:-1]
    if any(char > 0xFF for char in body):
        raise ValueError("EOP/EEP may only end a packet")
    if packet[-1] == EEP:
        return Verdict.EEP, None, None
    n_payload = len(body) - HEADER_BYTES - CRC_BYTES
    if not MIN_PAYLOAD <= n_payload <= max_payload:
        return Verdict.LENGTH, None, None
    if crc16(body) != 0:
        return Verdict.CRC, None, None
    return Verdict.GOOD, Header.from_bytes(body), bytes(body[HEADER_BYTES:-CRC_BYTES])
