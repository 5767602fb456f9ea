"""VDC sequencing: what the VDC engine is given, and when it runs.

The VDC engine's host port takes, in priority order:

1. the period's snapshot, once the CORDIC is done: ``q̇`` (the boundary's velocity),
   ``cos q`` and ``sin q`` into the VDC program's ``qd``, ``cq``, ``sq``;
2. the decoder's words for the VDC bank: Comm B's 13 words, Comm D's ``g_C``, PARAM words.

A full Comm B requests a run; it starts once the engine is idle, the snapshot is in and no
word is pending (so its last word is in), from the program's ``"first"`` entry if the
derivative history must restart (``primed``: after reset, CONFIG PRIME, a watchdog trip or an
ARM taking effect, up to the next Comm B; or bit 0 of the Comm B's flag byte), else from
``"main"``. The forces are ready at the program's MARK: from then up to the next boundary or
run they are FRESH (this period's Comm B), and a waiting Comm C reply may go.
"""

from amaranth import *
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.hdl.link.packet import PacketType
from mrm_cosim.protocol.fixed import WORD
from mrm_cosim.protocol.isa import ADDR_BITS, Microcode

from .decoder import HostWrite, PacketEnd

__all__ = ["VdcSequencer"]


class VdcSequencer(wiring.Component):
    """The VDC engine's host port, start and the FRESH / PRIME status (see the module
    docstring).

    Parameters
    ----------
    vdc : Microcode
        The VDC program (its entries and the registers of the snapshot).

    Attributes
    ----------
    boundary : In(1)
        The period boundary (the forces are no longer fresh).
    velocity : In(signed(24))
        The boundary's velocity (:class:`~hdl.node.timer.Snapshot`).
    trig_done : In(1)
    cos, sin : In(signed(24))
        The CORDIC's result of the boundary's count (:class:`~hdl.node.trig.SinCos`).
    words : In(stream.Signature(HostWrite))
        Words for the VDC bank (the bank field is not looked at).
    hold : In(1)
        A word for either engine is pending: a run waits.
    ends : In(stream.Signature(PacketEnd, always_ready=True))
        Packet ends (from :class:`~hdl.node.decoder.PacketDecoder`); a full Comm B's count.
    prime, arm : In(1)
        Strobes: CONFIG PRIME; an ARM taking effect.
    tripped : In(1)
        The watchdog's trip (its rising edge primes).
    busy, mark : In(1)
        The VDC engine runs; its MARK (forces written).
    start : Out(1)
    entry : Out(ROM address)
        The VDC engine's start strobe and entry.
    host_addr, host_wdata, host_we : Out(9), Out(signed(24)), Out(1)
        The VDC engine's host write port.
    fresh : Out(1)
        The forces are from this period's Comm B (``Status.FRESH``).
    primed : Out(1)
        The next run restarts the derivative history (``Status.PRIME``).
    pending : Out(1)
        A run is requested or under way and has not reached its MARK.
    """

    def __init__(self, vdc: Microcode):
        if not isinstance(vdc, Microcode):
            raise TypeError(f"vdc must be a Microcode, not {vdc!r}")
        self._mc = vdc
        super().__init__({
            "boundary":   In(1),
            "velocity":   In(signed(WORD)),
            "trig_done":  In(1),
            "cos":        In(signed(WORD)),
            "sin":        In(signed(WORD)),
            "words":      In(stream.Signature(HostWrite)),
            "hold":       In(1),
            "ends":       In(stream.Signature(PacketEnd, always_ready=True)),
            "prime":      In(1),
            "arm":        In(1),
            "tripped":    In(1),
            "busy":       In(1),
            "mark":       In(1),
            "start":      Out(1),
            "entry":      Out(range(len(vdc.instrs))),
            "host_addr":  Out(ADDR_BITS),
            "host_wdata": Out(signed(WORD)),
            "host_we":    Out(1),
            "fresh":      Out(1),
            "primed":     Out(1, init=1),
            "pending":    Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        vmc = self._mc

        # Snapshot writer: q̇, cos q, sin q, one a cycle while the engine is idle.
        sw_pending = Signal()
        sw_idx     = Signal(2)
        sw_cos     = Signal(signed(WORD))
        sw_sin     = Signal(signed(WORD))
        with m.If(self.trig_done):
            m.d.sync += [
                sw_pending.eq(1),
                sw_idx.eq(0),
                sw_cos.eq(self.cos),
                sw_sin.eq(self.sin),
            ]
        sw_addr = Array([C(vmc.addr("qd"), 9), C(vmc.addr("cq"), 9), C(vmc.addr("sq"), 9),
                         C(0, 9)])
        sw_data = Array([self.velocity, sw_cos, sw_sin, C(0, WORD)])
        m.d.comb += self.words.ready.eq(~sw_pending & ~self.busy)
        with m.If(sw_pending & ~self.busy):
            m.d.comb += [
                self.host_addr.eq(sw_addr[sw_idx]),
                self.host_wdata.eq(sw_data[sw_idx]),
                self.host_we.eq(1),
            ]
            m.d.sync += sw_idx.eq(sw_idx + 1)
            with m.If(sw_idx == 2):
                m.d.sync += sw_pending.eq(0)
        with m.Elif(self.words.valid & self.words.ready):
            m.d.comb += [
                self.host_addr.eq(self.words.p.addr),
                self.host_wdata.eq(self.words.p.data),
                self.host_we.eq(1),
            ]

        # Runs: requested at a full Comm B's end, started when everything is in.
        go    = Signal()                # a run is requested
        wait  = Signal()                # a run is under way, before its MARK
        first = Signal()                # ... from "first"
        with m.If(self.boundary):
            m.d.sync += self.fresh.eq(0)
        with m.If(go & ~self.busy & ~sw_pending & ~self.hold):
            m.d.comb += [
                self.start.eq(1),
                self.entry.eq(Mux(first, vmc.entries["first"], vmc.entries["main"])),
            ]
            m.d.sync += [
                go.eq(0),
                wait.eq(1),
                self.fresh.eq(0),
            ]
        with m.If(self.mark):
            m.d.sync += [
                wait.eq(0),
                self.fresh.eq(1),
            ]
        m.d.comb += self.pending.eq(go | wait)

        # PRIME: set by CONFIG, a trip or an ARM taking effect; taken by the next Comm B.
        tripped_prev = Signal()
        m.d.sync += tripped_prev.eq(self.tripped)
        with m.If(self.prime | (self.tripped & ~tripped_prev) | self.arm):
            m.d.sync += self.primed.eq(1)
        with m.If(self.ends.valid & (self.ends.p.type == PacketType.COMM_B) & self.ends.p.full):
            m.d.sync += [
                go.eq(1),
                first.eq(self.primed | self.ends.p.flag),
                self.primed.eq(0),
            ]
        return m
