"""Chain endpoint of a slave node: two codecs, the router, the packet layer, time-code capture.

# Ref: ECSS-E-ST-50-12C §8.12 (time-codes); the daisy chain of the MRM paper (master ─ node 1
# ─ … ─ node N, the modules carrying the bus through their connectors).

::

    up line ── Codec ──┬── Router ──┬── Codec ── down line
    (to master)        │            │            (to node k+1)
                       │   Depacketizer ──► rx (host)
                       │   Packetizer   ◄── tx (host)
                       └─ tick_out ──► time-code capture, and on to the down codec's tick_in

The upstream codec waits for the peer (``auto_start``); the downstream codec starts the link
itself (``link_start``), so every link of the chain comes up from the master's side and from
each node at once. A time-code received upstream is passed to the downstream codec in the same
cycle and stamped with the free-running ``cycle`` counter: ``tc_strobe`` pulses one cycle after
the upstream codec's ``tick_out``, with ``tc_stamp`` the counter value of the ``tick_out``
cycle and ``tc_time`` the time-code. Every time-code is forwarded and strobed: the chain has
no loops for time-codes to circulate in, which is what the standard's "one more than the last
value" propagation rule (§8.12) guards against, and absorbing an out-of-sequence code would cost
every node below a period start. ``tc_in_sequence`` tells the node logic whether the code was
the last one plus 1 (mod 64), so it can apply the rule itself.

The node address is the ``address`` input, not a parameter: modules are interchangeable, so
it comes from outside the link layer (strap pins, or a configuration register of the node).
"""

from amaranth import *
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.link import DEFAULT_RUN_DIV, DEFAULT_SLOTS
from mrm_cosim.protocol.packet import DEFAULT_MAX_PAYLOAD

from ..helpers import rejecting
from .chars import ErrorCounts
from .codec import Codec
from .packet import Beat, Depacketizer, Packetizer, RxStats
from .router import Router


__all__ = ["line_signature", "LinkNode", "link_node_top"]


def line_signature(slots: int) -> wiring.Signature:
    """One data-strobe port, from the node's side: ``slots`` line samples per cycle each way."""
    return wiring.Signature({
        "d_out": Out(slots),
        "s_out": Out(slots),
        "d_in":  In(slots),
        "s_in":  In(slots),
    })


class LinkNode(wiring.Component):
    """One node of the daisy chain: the link endpoint the node logic talks to.

    Parameters
    ----------
    codec : dict
        Keyword arguments for both :class:`~hdl.link.codec.Codec` s (``slots``, timers, ...).
    max_payload : int
        Largest payload the depacketizer accepts, bytes.
    rx_slots : int
        Receive packet buffers (see :class:`~hdl.link.packet.Depacketizer`).

    Attributes
    ----------
    address : In(8)
        This node's address, 1..254; stable while the link carries packets.
    tx : In(stream.Signature(Beat))
        Packets from the node logic to the master (``header.src`` is filled in).
    rx : Out(stream.Signature(Beat))
        Good packets addressed to this node or broadcast.
    up, down : Out(line_signature(slots))
        The upstream and downstream line ports.
    tc_strobe : Out(1)
        A time-code arrived (one-cycle pulse).
    tc_time : Out(8)
        Its value (flags in bits 7:6, time in 5:0); held until the next one.
    tc_stamp : Out(32)
        ``cycle`` when it arrived; held until the next one.
    tc_in_sequence : Out(1)
        Its time (bits 5:0) was the previous time-code's plus 1, mod 64; held with ``tc_time``.
    cycle : Out(32)
        Free-running cycle counter (50 MHz), wrapping.
    up_running, down_running : Out(1)
        The links are in Run.
    rx_stats : Out(RxStats)
        Depacketizer counters.
    dropped : Out(16)
        Router discards (see :class:`~hdl.link.router.Router`).
    up_errors, down_errors : Out(ErrorCounts)
        The codecs' link error counters.
    """

    def __init__(self, *, codec: dict | None = None, max_payload: int = DEFAULT_MAX_PAYLOAD,
                 rx_slots: int = 2):
        codec = dict(codec or {})
        parts = []
        with rejecting(self):
            try:
                parts.append(Depacketizer(max_payload=max_payload, slots=rx_slots))
                parts.append(Codec(**codec))
                parts.append(Codec(**codec))
            except BaseException:
                for part in parts:
                    part._MustUse__silence = True
                raise
        self._depacketizer, self._up_codec, self._down_codec = parts
        slots = self._up_codec.slots
        super().__init__({
            "address":        In(8),
            "tx":             In(stream.Signature(Beat)),
            "rx":             Out(stream.Signature(Beat)),
            "up":             Out(line_signature(slots)),
            "down":           Out(line_signature(slots)),
            "tc_strobe":      Out(1),
            "tc_time":        Out(8),
            "tc_stamp":       Out(32),
            "tc_in_sequence": Out(1),
            "cycle":          Out(32),
            "up_running":     Out(1),
            "down_running":   Out(1),
            "rx_stats":       Out(RxStats),
            "dropped":        Out(16),
            "up_errors":      Out(ErrorCounts),
            "down_errors":    Out(ErrorCounts),
        })

    @property
    def max_payload(self) -> int:
        return self._depacketizer.max_payload

    @property
    def up_codec(self) -> Codec:
        return self._up_codec

    @property
    def down_codec(self) -> Codec:
        return self._down_codec

    def elaborate(self, platform):
        m = Module()
        m.submodules.up_codec     = up_codec   = self._up_codec
        m.submodules.down_codec   = down_codec = self._down_codec
        m.submodules.router       = router     = Router()
        m.submodules.depacketizer = depack     = self._depacketizer
        m.submodules.packetizer   = pack       = Packetizer()

        for codec, line in ((up_codec, self.up), (down_codec, self.down)):
            m.d.comb += [
                codec.d_in.eq(line.d_in),
                codec.s_in.eq(line.s_in),
                line.d_out.eq(codec.d_out),
                line.s_out.eq(codec.s_out),
            ]
        m.d.comb += [
            up_codec.auto_start.eq(1),
            down_codec.link_start.eq(1),
            router.up_running.eq(up_codec.running),
            router.down_running.eq(down_codec.running),
            router.address.eq(self.address),
            pack.address.eq(self.address),
            self.up_running.eq(up_codec.running),
            self.down_running.eq(down_codec.running),
            self.up_errors.eq(up_codec.errors),
            self.down_errors.eq(down_codec.errors),
            self.rx_stats.eq(depack.stats),
            self.dropped.eq(router.dropped),
        ]
        wiring.connect(m, codec_rx=up_codec.rx, router_up_rx=router.up_rx)
        wiring.connect(m, router_up_tx=router.up_tx, codec_tx=up_codec.tx)
        wiring.connect(m, codec_rx=down_codec.rx, router_down_rx=router.down_rx)
        wiring.connect(m, router_down_tx=router.down_tx, codec_tx=down_codec.tx)
        wiring.connect(m, router_local_rx=router.local_rx, depacketizer=depack.chars)
        wiring.connect(m, packetizer=pack.chars, router_local_tx=router.local_tx)
        wiring.connect(m, host_tx=wiring.flipped(self.tx), packetizer=pack.beats)
        wiring.connect(m, depacketizer=depack.beats, host_rx=wiring.flipped(self.rx))

        # Time-codes: on to the next node at once; stamped here.
        m.d.comb += [
            down_codec.tick_in.eq(up_codec.tick_out),
            down_codec.time_in.eq(up_codec.time_out),
        ]
        m.d.sync += [
            self.cycle.eq(self.cycle + 1),
            self.tc_strobe.eq(up_codec.tick_out),
        ]
        with m.If(up_codec.tick_out):
            m.d.sync += [
                self.tc_stamp.eq(self.cycle),
                self.tc_time.eq(up_codec.time_out),
                self.tc_in_sequence.eq(up_codec.time_out[:6] == (self.tc_time[:6] + 1)[:6]),
            ]

        return m


def link_node_top(*, slots: int = DEFAULT_SLOTS, start_div: int | None = None,
                  run_div: int = DEFAULT_RUN_DIV,
                  reset_cycles: int = 320, wait_cycles: int = 640, disconnect_cycles: int = 43,
                  rx_fifo_depth: int = 64, max_payload: int = DEFAULT_MAX_PAYLOAD,
                  rx_slots: int = 2) -> LinkNode:
    """Factory for the ``link_node`` Verilog top (``mrm hdl verilog --top link_node``).

    The codec parameters are those of :class:`~hdl.link.codec.Codec`; ``max_payload`` and
    ``rx_slots`` those of :class:`LinkNode`.
    """
    return LinkNode(codec=dict(slots=slots, start_div=start_div, run_div=run_div,
                               reset_cycles=reset_cycles, wait_cycles=wait_cycles,
                               disconnect_cycles=disconnect_cycles,
                               rx_fifo_depth=rx_fifo_depth),
                    max_payload=max_payload, rx_slots=rx_slots)
