"""Simulation helpers for the packet layer: stream bus-functional models and a daisy chain.

:class:`Chain` wires a master-side :class:`~hdl.link.codec.Codec` to ``n_nodes``
:class:`~hdl.link.node.LinkNode` s back to back (master ─ node 1 ─ node 2 ─ … ─ node N, node
``k`` at address ``k``; the last node's downstream port is left unconnected). The async helpers
below drive and check its streams from Amaranth testbenches (``sim.add_testbench``); characters
and packets are in the integer form of :mod:`mrm_cosim.protocol.packet`.

With ``line_faults=True`` every line of the chain passes through a fault injector the testbench
controls (cut, stuck, flipped line samples; see :func:`line_fault_layout`). It exists for
simulation only: ``Chain`` is no Verilog top, and the exported ``link_node`` has no such ports.
"""

from __future__ import annotations

from amaranth import *
from amaranth.lib import data, stream, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol import packet as proto
from mrm_cosim.protocol.packet import DEFAULT_MAX_PAYLOAD

from ..helpers import rejecting
from .chars import Char, CharKind
from .codec import Codec
from .node import LinkNode
from .packet import Beat, Header

__all__ = ["Chain", "line_fault_layout", "faulty_line", "char_value", "char_int", "beat_value",
           "beat_fields", "put_chars", "get_chars", "put_packet", "get_packet", "master_send",
           "master_receive", "node_send", "node_receive", "read_stats"]


_CHAR = Char.as_shape()
_BEAT = Beat.as_shape()
_HEADER = Header.as_shape()
_KIND_OF = {proto.EOP: CharKind.EOP.value, proto.EEP: CharKind.EEP.value}
_INT_OF = {CharKind.EOP.value: proto.EOP, CharKind.EEP.value: proto.EEP}


def char_value(char: int) -> int:
    """Raw value of a :class:`~hdl.link.chars.Char` for an integer character."""
    if 0 <= char <= 0xFF:
        return (CharKind.DATA.value << _CHAR["kind"].offset) | (char << _CHAR["data"].offset)
    return _KIND_OF[char] << _CHAR["kind"].offset


def char_int(raw: int) -> int:
    """Integer character for the raw value of a :class:`~hdl.link.chars.Char`."""
    kind = (raw >> _CHAR["kind"].offset) & 0b11
    if kind == CharKind.DATA.value:
        return (raw >> _CHAR["data"].offset) & 0xFF
    return _INT_OF[kind]


def beat_value(header: proto.Header, byte: int, last: bool) -> int:
    """Raw value of a :class:`~hdl.link.packet.Beat`."""
    h = 0
    for name in ("dest", "src", "type", "seq"):
        h |= getattr(header, name) << _HEADER[name].offset
    return ((h << _BEAT["header"].offset) | (byte << _BEAT["data"].offset) |
            (int(bool(last)) << _BEAT["last"].offset))


def beat_fields(raw: int) -> tuple[proto.Header, int, bool]:
    """``(header, byte, last)`` of the raw value of a :class:`~hdl.link.packet.Beat`."""
    h = raw >> _BEAT["header"].offset
    header = proto.Header(*((h >> _HEADER[name].offset) & 0xFF
                          for name in ("dest", "src", "type", "seq")))
    return header, (raw >> _BEAT["data"].offset) & 0xFF, bool((raw >> _BEAT["last"].offset) & 1)


async def _idle(ctx, rng, p_idle):
    while rng is not None and p_idle and rng.random() < p_idle:
        await ctx.tick()


async def _offer(ctx, stream):
    """Hold ``valid`` until a clock edge where ``ready`` is high (the transfer)."""
    ctx.set(stream.valid, 1)
    while True:
        _, _, ready = await ctx.tick().sample(stream.ready)
        if ready:
            break
    ctx.set(stream.valid, 0)


async def put_chars(ctx, stream, chars, *, rng=None, p_idle: float = 0.0):
    """Offer integer characters on a Char stream, idling a random cycle with ``p_idle``."""
    for char in chars:
        await _idle(ctx, rng, p_idle)
        ctx.set(stream.payload.as_value(), char_value(char))
        await _offer(ctx, stream)


async def get_chars(ctx, stream, n_packets: int, *, rng=None, p_stall: float = 0.0
                    ) -> list[int]:
    """Take characters from a Char stream until ``n_packets`` EOP/EEP have passed."""
    chars = []
    ends = 0
    while ends < n_packets:
        ready = not (rng is not None and p_stall and rng.random() < p_stall)
        ctx.set(stream.ready, ready)
        _, _, valid, raw = await ctx.tick().sample(stream.valid, stream.payload.as_value())
        if ready and valid:
            chars.append(char_int(raw))
            ends += chars[-1] in (proto.EOP, proto.EEP)
    ctx.set(stream.ready, 0)
    return chars


async def put_packet(ctx, stream, header: proto.Header, payload, *, rng=None,
                     p_idle: float = 0.0):
    """Offer one packet as :class:`~hdl.link.packet.Beat` s on a host stream."""
    payload = bytes(payload)
    for index, byte in enumerate(payload):
        await _idle(ctx, rng, p_idle)
        ctx.set(stream.payload.as_value(), beat_value(header, byte, index == len(payload) - 1))
        await _offer(ctx, stream)


async def get_packet(ctx, stream, *, rng=None, p_stall: float = 0.0
                     ) -> tuple[proto.Header, bytes]:
    """Take one packet from a host :class:`~hdl.link.packet.Beat` stream.

    Checks that the header stays the same on every beat of the packet.
    """
    header, payload = None, bytearray()
    while True:
        ready = not (rng is not None and p_stall and rng.random() < p_stall)
        ctx.set(stream.ready, ready)
        _, _, valid, raw = await ctx.tick().sample(stream.valid, stream.payload.as_value())
        if ready and valid:
            beat_header, byte, last = beat_fields(raw)
            assert header is None or beat_header == header, \
                f"header changed inside a packet: {header} -> {beat_header}"
            header = beat_header
            payload.append(byte)
            if last:
                ctx.set(stream.ready, 0)
                return header, bytes(payload)


def line_fault_layout(slots: int) -> data.StructLayout:
    """Fault controls for one direction of one line, ``slots`` bits per field (bit 0 = the
    earliest slot of the cycle).

    Each line sample is ``((x & ~clear) | set) ^ flip``, per line (D, S) and slot: clear both
    lines to cut the wire, set or clear one to make it stuck, flip a slot for a bit error (both
    D and S in one slot: one bit's value inverted, framing kept). All zero: a good wire.
    """
    return data.StructLayout({name: slots for name in
                              ("clear_d", "set_d", "flip_d", "clear_s", "set_s", "flip_s")})


def faulty_line(src, fault, line):
    """Drive ``src`` (a line word) through the ``fault`` controls of line ``"d"`` or ``"s"``."""
    clear, set_, flip = (getattr(fault, f"{op}_{line}") for op in ("clear", "set", "flip"))
    return ((src & ~clear) | set_) ^ flip


class Chain(wiring.Component):
    """Master-side codec plus ``n_nodes`` link nodes in a daisy chain, for simulation.

    Parameters
    ----------
    n_nodes : int
        Nodes in the chain (1..254); node ``k`` (1-based) gets address ``k``.
    codec : dict
        Keyword arguments for every :class:`~hdl.link.codec.Codec` (master's and nodes'),
        e.g. shortened ``reset_cycles``/``wait_cycles`` for fast tests.
    max_payload : int
        Largest payload the nodes accept.
    line_faults : bool
        Add the fault-injection ports ``fault_down`` and ``fault_up`` (testbench only).

    Attributes
    ----------
    master_tx : In(stream.Signature(Char))
        Characters the master sends (frames from :func:`~mrm_cosim.protocol.packet.encode`).
    master_rx : Out(stream.Signature(Char))
        Characters the master receives.
    tick_in, time_in : In(1), In(8)
        Time-code to send from the master.
    master_running : Out(1)
        The master's link is in Run.
    nodes : list of LinkNode
        The nodes, index ``k - 1`` for node ``k``; testbenches drive their ``tx``/``rx`` host
        streams and read their time-code and status outputs directly.
    cycle : Out(32)
        Free-running cycle counter (the same count every node captures time-codes with).
    fault_down, fault_up : In(data.ArrayLayout(line_fault_layout(slots), n_nodes))
        Only with ``line_faults``. Element ``k - 1`` acts on the line above node ``k``:
        ``fault_down`` on the direction towards node ``k`` (from the master or node ``k - 1``),
        ``fault_up`` on the direction from node ``k`` up. The faulted samples reach the receiving
        codec in the same cycle (no extra register).
    """

    def __init__(self, n_nodes: int = 3, *, codec: dict | None = None,
                 max_payload: int = DEFAULT_MAX_PAYLOAD, line_faults: bool = False):
        parts = []
        with rejecting(self):
            if (not isinstance(n_nodes, int) or isinstance(n_nodes, bool) or
                    not 1 <= n_nodes <= 254):
                raise ValueError(f"Node count must be an integer in 1..254, not {n_nodes!r}")
            try:
                parts.append(Codec(**dict(codec or {})))
                for _ in range(n_nodes):
                    parts.append(LinkNode(codec=codec, max_payload=max_payload))
            except BaseException:
                for part in parts:
                    part._MustUse__silence = True
                raise
        self.master, *self.nodes = parts
        self._line_faults = bool(line_faults)
        ports = {
            "master_tx":      In(stream.Signature(Char)),
            "master_rx":      Out(stream.Signature(Char)),
            "tick_in":        In(1),
            "time_in":        In(8),
            "master_running": Out(1),
            "cycle":          Out(32),
        }
        if self._line_faults:
            faults = data.ArrayLayout(line_fault_layout(self.master.slots), n_nodes)
            ports["fault_down"] = In(faults)
            ports["fault_up"]   = In(faults)
        super().__init__(ports)

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    def elaborate(self, platform):
        m = Module()
        m.submodules.master = master = self.master
        m.d.comb += [
            master.link_start.eq(1),
            master.tick_in.eq(self.tick_in),
            master.time_in.eq(self.time_in),
            self.master_running.eq(master.running),
        ]
        wiring.connect(m, tx=wiring.flipped(self.master_tx), codec=master.tx)
        wiring.connect(m, rx=wiring.flipped(self.master_rx), codec=master.rx)
        m.d.sync += self.cycle.eq(self.cycle + 1)

        upper = master  # the line port above the next node: the master codec, then `down`s
        for k, node in enumerate(self.nodes, start=1):
            m.submodules[f"node{k}"] = node
            down_d, down_s = upper.d_out, upper.s_out
            up_d, up_s = node.up.d_out, node.up.s_out
            if self._line_faults:
                down, up = self.fault_down[k - 1], self.fault_up[k - 1]
                down_d, down_s = faulty_line(down_d, down, "d"), faulty_line(down_s, down, "s")
                up_d, up_s = faulty_line(up_d, up, "d"), faulty_line(up_s, up, "s")
            m.d.comb += [
                node.address.eq(k),
                node.up.d_in.eq(down_d),
                node.up.s_in.eq(down_s),
                upper.d_in.eq(up_d),
                upper.s_in.eq(up_s),
            ]
            upper = node.down
        return m


async def master_send(ctx, chain: Chain, header: proto.Header, payload, **kwargs):
    """Send one frame from the master (``kwargs`` go to :func:`put_chars`)."""
    await put_chars(ctx, chain.master_tx, proto.encode(header, payload), **kwargs)


async def master_receive(ctx, chain: Chain, n_packets: int = 1, **kwargs
                         ) -> list[list[int]]:
    """Receive ``n_packets`` packets at the master, as character lists."""
    return proto.split_packets(await get_chars(ctx, chain.master_rx, n_packets, **kwargs))


async def node_send(ctx, node: LinkNode, header: proto.Header, payload, **kwargs):
    """Send one packet from a node's host interface (``kwargs`` go to :func:`put_packet`)."""
    await put_packet(ctx, node.tx, header, payload, **kwargs)


async def node_receive(ctx, node: LinkNode, **kwargs) -> tuple[proto.Header, bytes]:
    """Receive one packet at a node's host interface."""
    return await get_packet(ctx, node.rx, **kwargs)


def read_stats(ctx, view) -> dict[str, int]:
    """The fields of a struct port of plain-width fields (``RxStats``, ``ErrorCounts``)."""
    layout = data.Layout.cast(view.shape())
    raw = ctx.get(view.as_value())
    return {name: (raw >> field.offset) & ((1 << field.width) - 1) for name, field in layout}
