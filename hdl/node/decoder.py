"""Packet decoder of the node core: the byte stream of packets in, what they say out.

Every packet for the node arrives as :class:`~hdl.link.packet.Beat` beats, one payload byte
each (docs/node.md "Packets", :mod:`.regs`). The decoder takes them in order and says:

* **words** — a 24-bit word (three bytes, little-endian) that goes into an engine's register
  file: the 13 words of a Comm B and ``g_C[3]`` of a Comm D into the VDC's, the up to 12 words
  of a PARAM into the bank and address its header names. One word at a time is pending; while
  it is, no byte is taken (``rx.ready`` low), so a word for a busy engine holds the link.
* **config** — a CONFIG record (``id`` u8, ``value`` int32) at its last byte.
* **comm_d** — ``τ_D, q_d0, q̇_d0, q̈_d0`` of the Comm D being received, as they arrive.
* **ends** — the end of every packet, in the cycle its last byte is taken: type, sequence
  number, whether the payload was full (40 bytes), and bit 0 of its last byte (Comm B's
  restart flag).
* **upload_crc**, **upload_count** — the running CRC-16/CCITT-FALSE of every CONFIG and PARAM
  payload byte, in arrival order (the link's, :mod:`hdl.link.crc`, from 0xFFFF at reset), and
  the number of such packets modulo 2^16; nothing but reset clears them (docs/node.md "Upload
  check").
"""

from amaranth import *
from amaranth.lib import data, stream, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.hdl.link.crc import CRC16_INIT, crc16_next
from mrm_cosim.hdl.link.packet import Beat, PacketType
from mrm_cosim.protocol.fixed import WORD
from mrm_cosim.protocol.isa import Microcode
from mrm_cosim.protocol.regs import COMM_B_WORDS, PAYLOAD, Bank

__all__ = ["PacketDecoder", "HostWrite", "ConfigRecord", "PacketEnd", "CommDWords"]


class HostWrite(data.Struct):
    """A word for an engine's register file (the engine's host write port)."""

    bank: 2             # :class:`~protocol.regs.Bank`: 0 VDC, 1 joint, 2 generator
    addr: 9
    data: signed(WORD)


class ConfigRecord(data.Struct):
    """A CONFIG record (:class:`~protocol.regs.Config` id and its value)."""

    id:    8
    value: 32


class PacketEnd(data.Struct):
    """The end of a packet for the node (its last byte taken)."""

    type: PacketType
    seq:  8
    full: 1    # the payload had PAYLOAD (40) bytes
    flag: 1    # bit 0 of the last byte (Comm B: restart the derivative history)


class CommDWords(data.Struct):
    """The joint controller's words of a Comm D (its ``g_C`` goes to the VDC)."""

    tau: signed(WORD)   # τ_D, FORCE
    qd0: signed(WORD)   # q_d0, POS
    vd0: signed(WORD)   # q̇_d0, VEL
    ad0: signed(WORD)   # q̈_d0, ACC


class PacketDecoder(wiring.Component):
    """Decode the node's packets into register writes, CONFIG records and packet ends.

    Parameters
    ----------
    vdc : Microcode
        The VDC program: where Comm B's words and Comm D's ``g_C`` go in its register file.

    Attributes
    ----------
    rx : In(stream.Signature(Beat))
        Packets for this node (the core's ``rx``). ``ready`` is low while a word is pending.
    words : Out(stream.Signature(HostWrite))
        The pending register-file word; the engine of its bank takes it (``ready``).
    config : Out(stream.Signature(ConfigRecord, always_ready=True))
        A CONFIG record, in the cycle its last byte is taken.
    comm_d : Out(CommDWords)
        The Comm D words received so far (each as its third byte is taken).
    ends : Out(stream.Signature(PacketEnd, always_ready=True))
        A packet's end, in the cycle its last byte is taken.
    upload_crc, upload_count : Out(16)
        CRC of every CONFIG / PARAM payload byte since reset, and the number of such packets.
    """

    rx:           In(stream.Signature(Beat))
    words:        Out(stream.Signature(HostWrite))
    config:       Out(stream.Signature(ConfigRecord, always_ready=True))
    comm_d:       Out(CommDWords)
    ends:         Out(stream.Signature(PacketEnd, always_ready=True))
    upload_crc:   Out(16, init=CRC16_INIT)
    upload_count: Out(16)

    def __init__(self, vdc: Microcode):
        if not isinstance(vdc, Microcode):
            raise TypeError(f"vdc must be a Microcode, not {vdc!r}")
        self._vdc = vdc
        super().__init__()

    def elaborate(self, platform):
        m = Module()
        vmc = self._vdc
        beat  = self.rx.p
        ptype = beat.header.type
        taken = Signal()
        pos   = Signal(range(256))      # byte of the payload
        wacc  = Signal(WORD)            # the last three bytes
        wj    = Signal(range(3))        # byte of the word
        wk    = Signal(range(256))      # word of the packet
        word  = Signal(signed(WORD))
        wdone = Signal()
        par_bank = Signal(2)
        par_addr = Signal(16)
        pend = self.words
        b_addr = Array(C(vmc.addr(n), 9) for n in COMM_B_WORDS)
        g_addr = Array(C(vmc.addr(f"gC{k}"), 9) for k in range(3))

        m.d.comb += [
            self.rx.ready.eq(~pend.valid),
            taken.eq(self.rx.valid & self.rx.ready),
            word.eq(Cat(wacc[8:], beat.data)),
        ]
        is_b = ptype == PacketType.COMM_B
        is_d = ptype == PacketType.COMM_D
        is_p = ptype == PacketType.PARAM
        is_c = ptype == PacketType.CONFIG
        in_words = (is_b | is_d | (is_p & (pos >= 3)))
        m.d.comb += wdone.eq(taken & in_words & (wj == 2))
        with m.If(taken):
            m.d.sync += [
                pos.eq(Mux(beat.last, 0, pos + 1)),
                wacc.eq(Cat(wacc[8:], beat.data)),
            ]
            with m.If(beat.last):
                m.d.sync += [
                    wj.eq(0),
                    wk.eq(0),
                ]
            with m.Elif(in_words):
                m.d.sync += wj.eq(Mux(wj == 2, 0, wj + 1))
                with m.If(wj == 2):
                    m.d.sync += wk.eq(wk + 1)
            with m.If(is_p):
                with m.Switch(pos):
                    with m.Case(0):
                        m.d.sync += par_bank.eq(beat.data[:2])
                    with m.Case(1):
                        m.d.sync += par_addr[:8].eq(beat.data)
                    with m.Case(2):
                        m.d.sync += par_addr[8:].eq(beat.data)

        # Upload check: CRC of every CONFIG / PARAM payload byte in arrival order, and the
        # number of such packets, from reset (16 flip-flops and an XOR network, 16 + a counter).
        with m.If(taken & (is_c | is_p)):
            m.d.sync += self.upload_crc.eq(crc16_next(self.upload_crc, beat.data))
            with m.If(beat.last):
                m.d.sync += self.upload_count.eq(self.upload_count + 1)

        # Words: to a register file (through the pending write) or a D word. The pending write
        # and a new word never meet: no byte is taken while one is pending.
        with m.If(pend.valid & pend.ready):
            m.d.sync += pend.valid.eq(0)

        def pending(bank, addr):
            return [pend.valid.eq(1), pend.p.bank.eq(bank), pend.p.addr.eq(addr),
                    pend.p.data.eq(word)]

        with m.If(wdone):
            with m.If(is_b & (wk < len(COMM_B_WORDS))):
                m.d.sync += pending(Bank.VDC, b_addr[wk])
            with m.If(is_d):
                with m.Switch(wk):
                    with m.Case(0):
                        m.d.sync += self.comm_d.tau.eq(word)
                    with m.Case(1, 2, 3):
                        m.d.sync += pending(Bank.VDC, g_addr[(wk - 1)[:2]])
                    with m.Case(4):
                        m.d.sync += self.comm_d.qd0.eq(word)
                    with m.Case(5):
                        m.d.sync += self.comm_d.vd0.eq(word)
                    with m.Case(6):
                        m.d.sync += self.comm_d.ad0.eq(word)
            with m.If(is_p & (wk < 12)):
                m.d.sync += pending(par_bank, (par_addr + wk)[:9])

        # CONFIG records: id, then a 32-bit value (the low 24 bits and the sign are used).
        cfg_j  = Signal(range(5))
        cfg_id = Signal(8)
        cfg_v  = Signal(24)
        m.d.comb += [
            self.config.p.id.eq(cfg_id),
            self.config.p.value.eq(Cat(cfg_v, beat.data)),
        ]
        with m.If(taken & is_c):
            with m.If(cfg_j == 0):
                m.d.sync += cfg_id.eq(beat.data)
            with m.Else():
                m.d.sync += cfg_v.eq(Cat(cfg_v[8:], beat.data))
            m.d.sync += cfg_j.eq(Mux((cfg_j == 4) | beat.last, 0, cfg_j + 1))
            m.d.comb += self.config.valid.eq(cfg_j == 4)

        m.d.comb += [
            self.ends.valid.eq(taken & beat.last),
            self.ends.p.type.eq(ptype),
            self.ends.p.seq.eq(beat.header.seq),
            self.ends.p.full.eq(pos == PAYLOAD - 1),
            self.ends.p.flag.eq(beat.data[0]),
        ]
        return m
