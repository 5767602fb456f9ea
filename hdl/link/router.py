"""Daisy-chain forwarding inside one node: upstream port, downstream port and the local host.

# Ref: ECSS-E-ST-50-12C §5.4 (packets, EOP/EEP); wormhole (cut-through) routing as in a
# SpaceWire router, reduced to a two-port chain element.

::

            up_rx ──► [down path] ──┬──► down_tx   (other nodes, broadcast)
    master                          └──► local_rx  (own address, broadcast)
    side    up_tx ◄── [arbiter] ◄───┬─── down_rx   (replies of nodes further down)
                                    └─── local_tx  (own replies)

Down path: the first character of a packet (its destination) picks the outputs — own address
to the host, broadcast (0xFF) to the host and downstream, any other address downstream — and
the rest of the packet follows character by character, without waiting for its end.

Up path: a round-robin arbiter between the node's own packets and those arriving from
downstream. The grant is held from a packet's first character to its EOP/EEP, so packets are
never interleaved; when both wait at a packet boundary, the one that did not go last goes.

Every output is a register stage (one cycle of latency, one character per cycle; the two
codec outputs hold a second character, so the codec's ``ready`` stops there: see
``_OutputStage``). The router
relies on the codec's link-error rules (:mod:`hdl.link.codec`): a packet cut on a receiving
link is ended with an EEP by that codec, and the rest of a packet cut on a sending link is taken
and dropped by that codec. So the router only has to decide about packets the codec has not
started: a packet routed to a port whose link is not running, or whose link stops before the
codec took any of it, is discarded by the router (all of it, even if the link comes back).
``dropped`` counts those packets, packets that reach no output at all (an address that is
neither this node's, nor broadcast, at the end of the chain) and stray EOP/EEP characters.
"""

from amaranth import *
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.packet import BROADCAST, COUNTER_MAX

from .chars import Char, CharKind


__all__ = ["Router"]


class _OutputStage:
    """Register stage in front of an output stream, one or two characters deep.

    ``opened`` mirrors the codec's own "inside a packet" flag: it is set when the codec takes a
    data character and cleared when it takes an EOP/EEP. While the link is not running and the
    codec holds no part of a packet, the stage is ``dead``: it empties and accepts everything.

    With ``depth = 2`` (the two codec outputs) the stage holds a second character behind the
    one it offers, and ``can`` ("the router may load a character") is ``not full``: a
    register, not the codec's ``ready``. The codec's ``ready`` comes from its link state and its
    data-strobe transmitter's free slots through logic of its own (docs/link.md, SERDES and
    rates); without the second place it ran on through the router's routing and drop decisions
    into the drop counter and the node's reply path in the same cycle, the slowest path of the
    whole node (docs/node.md, Clock). The codec sees every character at the cycle it saw it
    with one place: a character it takes is followed, the next cycle, by the one behind it.
    """

    def __init__(self, m, port, running, name, depth=1):
        self.load   = Signal(name=f"{name}_load")
        self.char   = Signal(Char, name=f"{name}_char")
        self.can    = Signal(name=f"{name}_can")
        self.dead   = Signal(name=f"{name}_dead")
        self.opened = Signal(name=f"{name}_opened")
        take = port.valid & port.ready
        with m.If(take):
            m.d.sync += self.opened.eq(port.payload.kind == CharKind.DATA)
        m.d.comb += self.dead.eq(~running & ~self.opened)
        if depth == 1:
            m.d.comb += self.can.eq(~port.valid | port.ready | self.dead)
            with m.If(self.dead):
                m.d.sync += port.valid.eq(0)
            with m.Elif(self.load):
                m.d.sync += [
                    port.valid.eq(1),
                    port.payload.eq(self.char),
                ]
            with m.Elif(port.ready):
                m.d.sync += port.valid.eq(0)
            return
        full = Signal(name=f"{name}_full")          # a second character waits behind
        second = Signal(Char, name=f"{name}_second")
        m.d.comb += self.can.eq(~full | self.dead)
        with m.If(self.dead):
            m.d.sync += [port.valid.eq(0), full.eq(0)]
        with m.Elif(take):
            with m.If(full):                        # (no load: can is low)
                m.d.sync += [port.payload.eq(second), full.eq(0)]
            with m.Elif(self.load):
                m.d.sync += port.payload.eq(self.char)
            with m.Else():
                m.d.sync += port.valid.eq(0)
        with m.Elif(self.load):
            with m.If(port.valid):
                m.d.sync += [second.eq(self.char), full.eq(1)]
            with m.Else():
                m.d.sync += [port.valid.eq(1), port.payload.eq(self.char)]


class Router(wiring.Component):
    """Forwarding between a node's upstream port, downstream port and host.

    Attributes
    ----------
    address : In(8)
        This node's address (1..254); must be stable while packets flow.
    up_rx, up_tx : In/Out(stream.Signature(Char))
        Characters from / to the upstream codec (towards the master).
    down_rx, down_tx : In/Out(stream.Signature(Char))
        Characters from / to the downstream codec (towards the end of the chain).
    local_rx : Out(stream.Signature(Char))
        Packets for this node, to its depacketizer.
    local_tx : In(stream.Signature(Char))
        This node's packets, from its packetizer.
    up_running, down_running : In(1)
        The codecs' ``running`` outputs.
    dropped : Out(16)
        Discarded or truncated packets and stray end markers; saturates at 0xFFFF.
    """

    address:      In(8)
    up_rx:        In(stream.Signature(Char))
    up_tx:        Out(stream.Signature(Char))
    down_rx:      In(stream.Signature(Char))
    down_tx:      Out(stream.Signature(Char))
    local_rx:     Out(stream.Signature(Char))
    local_tx:     In(stream.Signature(Char))
    up_running:   In(1)
    down_running: In(1)
    dropped:      Out(16)

    def elaborate(self, platform):
        m = Module()

        local = _OutputStage(m, self.local_rx, C(1),              "local")
        down  = _OutputStage(m, self.down_tx,  self.down_running, "down", depth=2)
        up    = _OutputStage(m, self.up_tx,    self.up_running,   "up",   depth=2)

        drop_down = Signal()   # a packet from upstream went nowhere or lost its tail
        drop_up   = Signal()   # the same for a packet going upstream
        stray     = Signal(2)  # bare EOP/EEP on the upstream / an upward input

        # Down path: upstream -> host and/or downstream.
        m.d.comb += [
            local.char.eq(self.up_rx.p),
            down.char.eq(self.up_rx.p),
        ]
        dest     = self.up_rx.p.data
        is_end   = self.up_rx.p.kind != CharKind.DATA
        to_local = Signal()
        to_down  = Signal()
        with m.FSM(name="down_path"):
            with m.State("Head"):
                want_local = (dest == self.address) | (dest == BROADCAST)
                want_down  = (dest != self.address) & self.down_running
                with m.If(self.up_rx.valid & is_end):
                    m.d.comb += [
                        self.up_rx.ready.eq(1),
                        stray[0].eq(1),
                    ]
                with m.Elif(self.up_rx.valid):
                    m.d.comb += self.up_rx.ready.eq((~want_local | local.can) &
                                                    (~want_down | down.can))
                    with m.If(self.up_rx.ready):
                        m.d.comb += [
                            local.load.eq(want_local),
                            down.load.eq(want_down),
                            drop_down.eq(~want_local & ~want_down),
                        ]
                        m.d.sync += [
                            to_local.eq(want_local),
                            to_down.eq(want_down),
                        ]
                        m.next = "Body"

            with m.State("Body"):
                down_on = to_down & ~down.dead
                with m.If(to_down & down.dead):
                    m.d.sync += to_down.eq(0)
                    m.d.comb += drop_down.eq(1)
                m.d.comb += self.up_rx.ready.eq((~to_local | local.can) & (~down_on | down.can))
                with m.If(self.up_rx.valid & self.up_rx.ready):
                    m.d.comb += [
                        local.load.eq(to_local),
                        down.load.eq(down_on),
                    ]
                    with m.If(is_end):
                        m.next = "Head"

        # Up path: whole-packet round-robin arbiter between the host and downstream.
        up_drop  = Signal()  # the packet being passed up is discarded by the router
        last_fwd = Signal()  # the last packet granted came from downstream
        sources = {"Local": self.local_tx, "Forward": self.down_rx}
        with m.FSM(name="up_path"):
            with m.State("Idle"):
                pick_local = self.local_tx.valid & (~self.down_rx.valid | last_fwd)
                pick_fwd   = self.down_rx.valid & ~pick_local
                for state, pick, is_fwd in (("Local", pick_local, 0), ("Forward", pick_fwd, 1)):
                    source = sources[state]
                    with m.If(pick):
                        with m.If(source.p.kind != CharKind.DATA):
                            m.d.comb += [
                                source.ready.eq(1),
                                stray[1].eq(1),
                            ]
                        with m.Else():
                            m.d.sync += [
                                last_fwd.eq(is_fwd),
                                up_drop.eq(~self.up_running),
                            ]
                            m.d.comb += drop_up.eq(~self.up_running)
                            m.next = state

            for state, source in sources.items():
                with m.State(state):
                    with m.If(~up_drop & up.dead):
                        m.d.sync += up_drop.eq(1)
                        m.d.comb += drop_up.eq(1)
                    discard = up_drop | up.dead
                    m.d.comb += [
                        source.ready.eq(discard | up.can),
                        up.char.eq(source.p),
                        up.load.eq(source.valid & ~discard & up.can),
                    ]
                    with m.If(source.valid & source.ready & (source.p.kind != CharKind.DATA)):
                        m.next = "Idle"

        # dropped = min(dropped + events, COUNTER_MAX) each cycle, split at a register: the
        # cycle's events are registered (``pending``) and added the next cycle, and the
        # output is ``counted`` plus them. The same value in every cycle (by induction:
        # counted' = dropped, pending' = events, so dropped' = min(dropped + events, MAX)), but
        # the drop decisions (from the codecs' FIFO outputs) no longer run into the 16-bit
        # adder and saturation in one cycle: that was the node's slowest path (docs/node.md,
        # Clock).
        events  = drop_down + drop_up + stray[0] + stray[1]
        pending = Signal(range(5))
        counted = Signal(16)
        total   = counted + pending
        m.d.comb += self.dropped.eq(Mux(total > COUNTER_MAX, COUNTER_MAX, total))
        m.d.sync += [counted.eq(self.dropped), pending.eq(events)]

        return m
