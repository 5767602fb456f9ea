"""Bit-exact Python reference of the packet layer and of daisy-chain forwarding.

Pure Python (no Amaranth), fast enough for the ``model`` backend. It mirrors, at transaction
level, what the gateware in :mod:`hdl.link.packet` and :mod:`hdl.link.router` does:

* frame encoding (:func:`encode`) — the exact character sequence the
  :class:`~hdl.link.packet.Packetizer` emits;
* frame checking (:func:`check_frame`, :class:`DepacketizerModel`) — which packets the
  :class:`~hdl.link.packet.Depacketizer` delivers and which counter each rejected one bumps;
* routing (:func:`route`, :class:`RouterModel`, :class:`ChainModel`) — where the
  :class:`~hdl.link.router.Router` sends a packet and what it discards.

Characters are plain integers here: ``0..255`` is a data character, :data:`EOP` and :data:`EEP`
(values 0x100 and 0x101, the flag bit set as in a 9-bit N-char) end a packet.

Frame (all data characters, then one EOP)::

    dest | src | type | seq | payload (1..max_payload bytes) | crc[15:8] | crc[7:0] | EOP

The CRC is CRC-16/CCITT-FALSE over dest..payload (see :mod:`hdl.link.crc`).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

__all__ = [
    "EOP", "EEP", "MASTER_ADDRESS", "BROADCAST", "HEADER_BYTES", "CRC_BYTES", "DATA_PAYLOAD",
    "DEFAULT_MAX_PAYLOAD", "MIN_PAYLOAD", "COUNTER_MAX", "PacketType", "Verdict", "Header",
    "crc16", "encode", "split_packets", "check_frame", "DepacketizerModel", "route",
    "RouterModel", "ChainModel", "is_packet_merge",
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

CRC16_POLY = 0x1021
CRC16_INIT = 0xFFFF


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


def _make_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ CRC16_POLY if crc & 0x8000 else crc << 1) & 0xFFFF
        table.append(crc)
    return tuple(table)


_CRC_TABLE = _make_table()


def crc16(data: Iterable[int], crc: int = CRC16_INIT) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (bytes or ints 0..255), continuing from ``crc``."""
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ _CRC_TABLE[(crc >> 8) ^ byte]
    return crc


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


class DepacketizerModel:
    """Transaction-level model of :class:`~hdl.link.packet.Depacketizer`.

    Parameters
    ----------
    max_payload : int

    Attributes
    ----------
    counts : dict of str -> int
        Saturating counters ``good``, ``crc``, ``length``, ``eep`` (as the gateware's ``stats``).
    """

    def __init__(self, *, max_payload: int = DEFAULT_MAX_PAYLOAD):
        self.max_payload = max_payload
        self.counts = {verdict.value: 0 for verdict in Verdict}
        self._partial: list[int] = []

    def feed(self, chars: Iterable[int]) -> list[tuple[Header, bytes]]:
        """Consume characters; return the packets delivered to the host, in order."""
        delivered = []
        for char in chars:
            self._partial.append(char)
            if char in (EOP, EEP):
                verdict, header, payload = check_frame(self._partial,
                                                       max_payload=self.max_payload)
                self._partial = []
                key = verdict.value
                self.counts[key] = min(self.counts[key] + 1, COUNTER_MAX)
                if verdict is Verdict.GOOD:
                    delivered.append((header, payload))
        return delivered


def route(address: int, packet: Sequence[int], *, down_running: bool = True
          ) -> tuple[bool, bool]:
    """Where a node's router sends a packet arriving on its upstream port.

    Parameters
    ----------
    address : int
        The node's address.
    packet : sequence of int
        The packet's characters; the first is the destination address.
    down_running : bool
        Whether the downstream link is in the Run state when the packet starts.

    Returns
    -------
    to_local, to_down : bool
        Both False means the packet is discarded (and counted in the router's ``dropped``).
    """
    if not packet or packet[0] > 0xFF:          # empty packet: a bare EOP/EEP
        return False, False
    dest = packet[0]
    to_local = dest == address or dest == BROADCAST
    to_down = (dest != address) and down_running
    return to_local, to_down


class RouterModel:
    """Transaction-level model of :class:`~hdl.link.router.Router` for one node.

    Packets from upstream go to the host (own address or broadcast) and/or downstream (any other
    address, broadcast included). Packets from downstream and from the host go upstream. A
    packet whose output link is not running is discarded whole and counted.
    """

    def __init__(self, address: int):
        self.address = address
        self.dropped = 0

    def _count_drop(self):
        self.dropped = min(self.dropped + 1, COUNTER_MAX)

    def from_upstream(self, packet: Sequence[int], *, down_running: bool = True
                      ) -> tuple[list[int] | None, list[int] | None]:
        """Return ``(to_local, to_down)`` copies of ``packet`` (None where it does not go)."""
        to_local, to_down = route(self.address, packet, down_running=down_running)
        if not (to_local or to_down):
            self._count_drop()
        return (list(packet) if to_local else None), (list(packet) if to_down else None)

    def to_upstream(self, packet: Sequence[int], *, up_running: bool = True
                    ) -> list[int] | None:
        """A packet from downstream or from the host, as it leaves on the upstream port."""
        if not packet or packet[0] > 0xFF or not up_running:
            self._count_drop()
            return None
        return list(packet)


class ChainModel:
    """Where packets go in a chain ``master - node 1 - ... - node n_nodes`` (all links up).

    Node ``k`` has address ``k``. Replies always travel to the master unchanged.
    """

    def __init__(self, n_nodes: int, *, max_payload: int = DEFAULT_MAX_PAYLOAD):
        if not isinstance(n_nodes, int) or not 1 <= n_nodes <= 254:
            raise ValueError(f"Node count must be an integer in 1..254, not {n_nodes!r}")
        self.routers = [RouterModel(k) for k in range(1, n_nodes + 1)]
        self.nodes = [DepacketizerModel(max_payload=max_payload) for _ in self.routers]

    def send_down(self, packet: Sequence[int]) -> dict[int, list[tuple[Header, bytes]]]:
        """Send one packet from the master; return what each node's host receives."""
        received = {}
        for index, (router, node) in enumerate(zip(self.routers, self.nodes, strict=True)):
            last = index == len(self.routers) - 1
            to_local, to_down = router.from_upstream(packet, down_running=not last)
            if to_local is not None:
                delivered = node.feed(to_local)
                if delivered:
                    received[router.address] = delivered
            if to_down is None:
                break
            packet = to_down
        return received


def is_packet_merge(output: Sequence[Sequence[int]], *sources: Sequence[Sequence[int]]) -> bool:
    """Whether ``output`` interleaves whole packets of ``sources``, each in its own order.

    That is what an arbiter that never splits a packet produces. Packets are compared by value;
    equal packets from different sources make the answer ambiguous, so give them unique contents.
    """
    heads = [0] * len(sources)
    for packet in output:
        for index, source in enumerate(sources):
            if heads[index] < len(source) and list(source[heads[index]]) == list(packet):
                heads[index] += 1
                break
        else:
            return False
    return all(head == len(source) for head, source in zip(heads, sources, strict=True))
