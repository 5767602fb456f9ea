"""Packet layer above the SpaceWire codec: frame layout, packetizer, depacketizer.

# Ref: ECSS-E-ST-50-12C §5.4 (packet = destination address, cargo, end of packet marker).

A frame is a SpaceWire packet whose first character is the destination address, so a standard
router could route it by logical address. All fields are bytes sent as data characters::

    char  0      1     2      3     4 .. 3+n       4+n        5+n        6+n
          dest | src | type | seq | payload[n] | crc[15:8] | crc[7:0] | EOP

``n`` is 1..``max_payload``; the paper's 40-byte data package is the payload, so a Comm A/B/C/D
frame is 46 data characters and an EOP. There is no length field: the EOP delimits the frame,
and the receiver counts the characters. The CRC is CRC-16/CCITT-FALSE over dest..payload
(:mod:`hdl.link.crc`); the receiver folds in the CRC bytes too and checks for a zero residue.
The frame, the packet types and the receiver's checks are defined in
:mod:`mrm_cosim.protocol.packet`; this module is their gateware.

On the host side a packet is a stream of :class:`Beat` — one per payload byte, each carrying
the packet's header, the last one flagged — in both directions.
"""

from amaranth import *
from amaranth.lib import data, stream, wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from mrm_cosim.protocol import packet as proto
from mrm_cosim.protocol.packet import (COUNTER_MAX, CRC_BYTES, DEFAULT_MAX_PAYLOAD, HEADER_BYTES,
                                       MIN_PAYLOAD)

from ..helpers import rejecting, shaped_enum
from .chars import Char, CharKind
from .crc import CRC16

__all__ = ["PacketType", "Header", "Beat", "RxStats", "Packetizer", "Depacketizer"]


#: The packet types of :class:`mrm_cosim.protocol.packet.PacketType` as an 8-bit field.
PacketType = shaped_enum(proto.PacketType, 8, __name__)


class Header(data.Struct):
    """Packet header; byte ``i`` on the wire is bits ``[8*i, 8*i+8)`` of this layout."""

    dest: 8
    src:  8
    type: PacketType
    seq:  8


class Beat(data.Struct):
    """One payload byte of a packet on the host interface."""

    header: Header  # constant over a packet
    data:   8
    last:   1       # the packet's final payload byte


class RxStats(data.Struct):
    """Receive counters of a :class:`Depacketizer`; each saturates at 0xFFFF."""

    good:   16  # packets delivered
    crc:    16  # dropped: CRC residue not zero
    length: 16  # dropped: payload shorter than 1 byte or longer than max_payload
    eep:    16  # dropped: ended by EEP


def _saturating_increment(m, counter, event):
    with m.If(event & (counter != COUNTER_MAX)):
        m.d.sync += counter.eq(counter + 1)


class Packetizer(wiring.Component):
    """Turn host beats into a frame: header, payload, CRC, EOP.

    The header is taken from the first beat of a packet, with ``src`` replaced by ``address``.
    The host should give a packet 1..``max_payload`` bytes of its receivers; others go out but are
    rejected at the far end. It may pause inside a packet (the link then idles), but a packet
    holds the node's upstream port until its last beat, so it must not wait on its own receiver.

    Attributes
    ----------
    address : In(8)
        This node's address, written into ``src``.
    beats : In(stream.Signature(Beat))
        Payload bytes from the host.
    chars : Out(stream.Signature(Char))
        Frame characters.
    """

    address: In(8)
    beats:   In(stream.Signature(Beat))
    chars:   Out(stream.Signature(Char))

    def elaborate(self, platform):
        m = Module()
        m.submodules.crc = crc = CRC16()

        header = Signal(Header)
        index  = Signal(range(HEADER_BYTES))
        sent   = Signal()
        m.d.comb += sent.eq(self.chars.valid & self.chars.ready)

        with m.FSM():
            with m.State("Idle"):
                with m.If(self.beats.valid):
                    m.d.sync += [
                        header.eq(self.beats.p.header),
                        header.src.eq(self.address),
                        index.eq(0),
                    ]
                    m.next = "Header"

            with m.State("Header"):
                m.d.comb += [
                    self.chars.valid.eq(1),
                    self.chars.p.kind.eq(CharKind.DATA),
                    self.chars.p.data.eq(header.as_value().word_select(index, 8)),
                    crc.start.eq(index == 0),
                    crc.valid.eq(sent),
                    crc.data.eq(self.chars.p.data),
                ]
                with m.If(sent):
                    m.d.sync += index.eq(index + 1)
                    with m.If(index == HEADER_BYTES - 1):
                        m.next = "Payload"

            with m.State("Payload"):
                m.d.comb += [
                    self.chars.valid.eq(self.beats.valid),
                    self.chars.p.kind.eq(CharKind.DATA),
                    self.chars.p.data.eq(self.beats.p.data),
                    self.beats.ready.eq(self.chars.ready),
                    crc.valid.eq(sent),
                    crc.data.eq(self.chars.p.data),
                ]
                with m.If(sent & self.beats.p.last):
                    m.next = "CRC-High"

            with m.State("CRC-High"):
                m.d.comb += [
                    self.chars.valid.eq(1),
                    self.chars.p.kind.eq(CharKind.DATA),
                    self.chars.p.data.eq(crc.crc[8:16]),
                ]
                with m.If(sent):
                    m.next = "CRC-Low"

            with m.State("CRC-Low"):
                m.d.comb += [
                    self.chars.valid.eq(1),
                    self.chars.p.kind.eq(CharKind.DATA),
                    self.chars.p.data.eq(crc.crc[0:8]),
                ]
                with m.If(sent):
                    m.next = "EOP"

            with m.State("EOP"):
                m.d.comb += [
                    self.chars.valid.eq(1),
                    self.chars.p.kind.eq(CharKind.EOP),
                ]
                with m.If(sent):
                    m.next = "Idle"

        return m


class Depacketizer(wiring.Component):
    """Check frames and hand good packets to the host; count and drop bad ones.

    Store and forward: a packet's payload is written into one of ``slots`` buffers while it
    arrives and is offered on ``beats`` only after its EOP, once the checks passed (EEP, then
    length, then CRC; the first that fails names the counter). So the host never sees a byte of
    a bad packet. While every slot holds a packet the host has not taken, ``chars`` is not
    ready at the start of the next packet, which back-pressures the link (credit flow control).

    Parameters
    ----------
    max_payload : int
        Largest payload accepted, 1..255 bytes.
    slots : int
        Packet buffers, a power of two (1, 2, 4, ...). Two let one packet arrive while the host
        reads the previous one.

    Attributes
    ----------
    chars : In(stream.Signature(Char))
        Characters of packets addressed to this node.
    beats : Out(stream.Signature(Beat))
        Payload bytes of good packets.
    stats : Out(RxStats)
        Counters, updated at the clock edge after each EOP/EEP.
    """

    chars: In(stream.Signature(Char))
    beats: Out(stream.Signature(Beat))
    stats: Out(RxStats)

    def __init__(self, *, max_payload: int = DEFAULT_MAX_PAYLOAD, slots: int = 2):
        with rejecting(self):
            if (not isinstance(max_payload, int) or isinstance(max_payload, bool) or
                    not MIN_PAYLOAD <= max_payload <= 255):
                raise ValueError(f"Maximum payload must be an integer in {MIN_PAYLOAD}..255, "
                                 f"not {max_payload!r}")
            if (not isinstance(slots, int) or isinstance(slots, bool) or slots < 1 or
                    slots & (slots - 1)):
                raise ValueError(f"Slot count must be a power of two, not {slots!r}")
        self._max_payload = max_payload
        self._slots = slots
        super().__init__()

    @property
    def max_payload(self) -> int:
        return self._max_payload

    @property
    def slots(self) -> int:
        return self._slots

    def elaborate(self, platform):
        m = Module()
        m.submodules.crc = crc = CRC16()

        slot_bits = ceil_log2(self._slots)
        index_bits = ceil_log2(self._max_payload)
        m.submodules.buffer = buffer = Memory(shape=8, depth=self._slots << index_bits, init=[])
        wr = buffer.write_port()
        rd = buffer.read_port()

        full    = Signal(self._slots)
        headers = Array(Signal(Header, name=f"header_{n}") for n in range(self._slots))
        lengths = Array(Signal(range(self._max_payload + 1), name=f"length_{n}")
                        for n in range(self._slots))

        # Write side: count characters, shift the header in, store the payload.
        too_long = HEADER_BYTES + self._max_payload + CRC_BYTES + 1
        count    = Signal(range(too_long + 1))
        incoming = Signal(Header)
        w_slot   = Signal(slot_bits)
        taken    = Signal()
        is_data  = Signal()
        m.d.comb += [
            self.chars.ready.eq(~full.bit_select(w_slot, 1)),
            taken.eq(self.chars.valid & self.chars.ready),
            is_data.eq(self.chars.p.kind == CharKind.DATA),
            crc.start.eq(count == 0),
            crc.valid.eq(taken & is_data),
            crc.data.eq(self.chars.p.data),
            wr.addr.eq(Cat((count - HEADER_BYTES)[:index_bits], w_slot)),
            wr.data.eq(self.chars.p.data),
            wr.en.eq(taken & is_data & (count >= HEADER_BYTES) &
                     (count < HEADER_BYTES + self._max_payload)),
        ]

        n_payload = Signal(range(too_long + 1))
        length_ok = Signal()
        m.d.comb += [
            n_payload.eq(count - HEADER_BYTES - CRC_BYTES),
            length_ok.eq((count >= HEADER_BYTES + MIN_PAYLOAD + CRC_BYTES) &
                         (count <= HEADER_BYTES + self._max_payload + CRC_BYTES)),
        ]
        end_eep    = Signal()
        end_length = Signal()
        end_crc    = Signal()
        end_good   = Signal()
        with m.If(taken & ~is_data):
            m.d.sync += count.eq(0)
            with m.If(self.chars.p.kind == CharKind.EEP):
                m.d.comb += end_eep.eq(1)
            with m.Elif(~length_ok):
                m.d.comb += end_length.eq(1)
            with m.Elif(crc.crc != 0):
                m.d.comb += end_crc.eq(1)
            with m.Else():
                m.d.comb += end_good.eq(1)
        with m.Elif(taken):
            with m.If(count != too_long):
                m.d.sync += count.eq(count + 1)
            with m.If(count < HEADER_BYTES):
                m.d.sync += incoming.eq(Cat(incoming.as_value()[8:], self.chars.p.data))

        with m.If(end_good):
            m.d.sync += [
                headers[w_slot].eq(incoming),
                lengths[w_slot].eq(n_payload),
                w_slot.eq(w_slot + 1),
            ]

        _saturating_increment(m, self.stats.good,   end_good)
        _saturating_increment(m, self.stats.crc,    end_crc)
        _saturating_increment(m, self.stats.length, end_length)
        _saturating_increment(m, self.stats.eep,    end_eep)

        # Read side: offer the oldest full slot, one byte per beat (the read port has one
        # cycle of latency, so `valid` and `last` are registered alongside its data).
        r_slot  = Signal(slot_bits)
        r_index = Signal(range(self._max_payload + 1))
        last    = Signal()
        more    = Signal()
        advance = Signal()
        done    = Signal()
        m.d.comb += [
            more.eq(full.bit_select(r_slot, 1) & (r_index < lengths[r_slot])),
            advance.eq(~self.beats.valid | self.beats.ready),
            done.eq(self.beats.valid & self.beats.ready & last),
            rd.addr.eq(Cat(r_index[:index_bits], r_slot)),
            rd.en.eq(advance),
            self.beats.p.data.eq(rd.data),
            self.beats.p.header.eq(headers[r_slot]),
            self.beats.p.last.eq(last),
        ]
        with m.If(advance):
            m.d.sync += self.beats.valid.eq(more)
            with m.If(more):
                m.d.sync += [
                    r_index.eq(r_index + 1),
                    last.eq(r_index == lengths[r_slot] - 1),
                ]
        with m.If(done):
            m.d.sync += [
                r_slot.eq(r_slot + 1),
                r_index.eq(0),
            ]

        for n in range(self._slots):
            with m.If(end_good & (w_slot == n)):
                m.d.sync += full[n].eq(1)
            with m.Elif(done & (r_slot == n)):
                m.d.sync += full[n].eq(0)

        return m
