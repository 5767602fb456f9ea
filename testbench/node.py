"""Bus-functional model of the master for one slave node, for Amaranth testbenches.

* :class:`NodeBench` — a master-side :class:`~mrm_cosim.hdl.link.codec.Codec` wired over the
  real data-strobe lines to one :class:`~mrm_cosim.hdl.node.top.SlaveNode` at address 1 (the
  device under test), with the node's encoder lines, torque and status as ports;
* :class:`NodeMaster` — what the master does to that node, packet by packet: bring the link
  up, **upload** CONFIG and PARAM payloads (:mod:`mrm_cosim.protocol.regs`), send time-codes,
  **read back** the upload CRC and count a Comm A reply carries and check them against
  :func:`~mrm_cosim.protocol.regs.upload_check` of what was sent, and run one **Comm A–D
  exchange** (time-code, A request → reply, B, C request → reply, D).

Every reply is checked as the master checks it (CRC and framing, addresses, type, sequence);
a wrong one fails with an ``AssertionError`` that says what came back. The payloads are the
protocol room's (``vdc_upload``, ``joint_upload``, ``config_payloads``, ``pack_comm_b``,
``pack_comm_d``), so a testbench compares the node's replies with its bit-exact reference
(:class:`mrm_cosim.hdl.node.core_ref.NodeModel`), as tests/test_node_link.py does.

It drives Amaranth's simulator (``sim.add_testbench``); docs/testbenches.md says how the
compiled backend exercises the same node.
"""

from amaranth import *
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.hdl.link.chain import get_chars, put_chars
from mrm_cosim.hdl.link.chars import Char
from mrm_cosim.hdl.link.codec import Codec
from mrm_cosim.hdl.node.top import SlaveNode
from mrm_cosim.protocol import packet as proto
from mrm_cosim.protocol.encoder import EncoderParams
from mrm_cosim.protocol.fixed import WORD
from mrm_cosim.protocol.regs import parse_comm_a, parse_comm_c, upload_check

__all__ = ["NodeBench", "NodeMaster", "SHORT_CODEC", "UPLOAD_TYPES"]

#: Codec timers short enough for a testbench (start-up in about 400 cycles, not 2000).
SHORT_CODEC = {"reset_cycles": 60, "wait_cycles": 150}
#: The packet types a node counts as uploads (``upload_crc`` / ``upload_count`` of Comm A).
UPLOAD_TYPES = (proto.PacketType.CONFIG, proto.PacketType.PARAM)


class NodeBench(wiring.Component):
    """A master codec and one :class:`~mrm_cosim.hdl.node.top.SlaveNode` (address 1) on a link.

    Parameters
    ----------
    codec : dict, optional
        :class:`~mrm_cosim.hdl.link.codec.Codec` parameters of both ends (default
        :data:`SHORT_CODEC`).
    encoder : EncoderParams, optional
        The node's encoder interface (default: a 256-cycle minimum velocity window).
    pid_shift : int
        The node's PID gain shift.

    Attributes
    ----------
    master_tx, master_rx : stream of Char
        Characters the master sends and receives (frames of :func:`protocol.packet.encode`).
    tick_in, time_in : In(1), In(8)
        Strobe a time-code from the master.
    enc_a, enc_b : In(1)
        The node's encoder lines (held at 0 unless driven: the joint rests at count 0).
    master_running, node_running : Out(1)
        Each end of the link is in Run.
    torque : Out(signed(24))
        The node's torque command (FORCE word).
    status : Out(16)
        :class:`~mrm_cosim.protocol.regs.Status` bits.
    count : Out(signed(32))
        The node's live encoder count.
    events : Out(16)
        The node's observation port (:class:`~mrm_cosim.protocol.regs.NodeEvent` strobes).
    master, node : Codec, SlaveNode
        The two ends, for reading their internals (``bench.node.link.up_codec.state``).
    """

    master_tx:      In(stream.Signature(Char))
    master_rx:      Out(stream.Signature(Char))
    tick_in:        In(1)
    time_in:        In(8)
    enc_a:          In(1)
    enc_b:          In(1)
    master_running: Out(1)
    node_running:   Out(1)
    torque:         Out(signed(WORD))
    status:         Out(16)
    count:          Out(signed(32))
    events:         Out(16)

    def __init__(self, *, codec: dict | None = None, encoder: EncoderParams | None = None,
                 pid_shift: int = 0):
        codec = dict(SHORT_CODEC if codec is None else codec)
        self.master = Codec(**codec)
        self.node = SlaveNode(codec=codec, encoder=encoder or EncoderParams(min_window=256),
                              pid_shift=pid_shift)
        super().__init__()

    def elaborate(self, platform):
        m = Module()
        m.submodules.master = master = self.master
        m.submodules.node = node = self.node
        m.d.comb += [
            master.link_start.eq(1),
            master.tick_in.eq(self.tick_in),
            master.time_in.eq(self.time_in),
            node.address.eq(1),
            node.up.d_in.eq(master.d_out),
            node.up.s_in.eq(master.s_out),
            master.d_in.eq(node.up.d_out),
            master.s_in.eq(node.up.s_out),
            node.enc_a.eq(self.enc_a),
            node.enc_b.eq(self.enc_b),
            self.master_running.eq(master.running),
            self.node_running.eq(node.link.up_running),
            self.torque.eq(node.torque),
            self.status.eq(node.status),
            self.count.eq(node.count),
            self.events.eq(node.events),
        ]
        wiring.connect(m, tx=wiring.flipped(self.master_tx), codec=master.tx)
        wiring.connect(m, rx=wiring.flipped(self.master_rx), codec=master.rx)
        return m


class NodeMaster:
    """The master's side of one node, driven from a testbench coroutine.

    ``uploads`` lists the CONFIG and PARAM payloads sent so far, in order: the node must
    report their :func:`~mrm_cosim.protocol.regs.upload_check` in every Comm A
    (:meth:`check_uploads`). ``replies`` logs every ``(header, payload)`` received.

    Example::

        bench = NodeBench()
        nm = NodeMaster(bench)

        async def testbench(ctx):
            await nm.bring_up(ctx)
            await nm.upload(ctx, [(PacketType.PARAM, p) for p in vdc_upload(...)])
            out = await nm.exchange(ctx, period=5, comm_b=pack_comm_b(...),
                                    comm_d=pack_comm_d(...))
            nm.check_uploads(out["A"])
    """

    def __init__(self, bench: NodeBench, address: int = 1):
        self.bench = bench
        self.address = address
        self.uploads: list[bytes] = []
        self.replies: list[tuple[proto.Header, bytes]] = []
        self.seq = 0

    async def bring_up(self, ctx, limit: int = 5000) -> int:
        """Clock until both ends of the link are in Run; return the cycles it took."""
        for n in range(limit):
            if ctx.get(self.bench.master_running) and ctx.get(self.bench.node_running):
                return n
            await ctx.tick()
        raise AssertionError(f"the link did not come up within {limit} cycles")

    async def send(self, ctx, ptype, payload, seq: int | None = None) -> int:
        """Send one packet to the node (sequence number ``seq``, else the next one); return
        the sequence number used. CONFIG and PARAM payloads are logged in ``uploads``."""
        if seq is None:
            seq, self.seq = self.seq, (self.seq + 1) & 0xFF
        header = proto.Header(self.address, proto.MASTER_ADDRESS, int(ptype), seq)
        await put_chars(ctx, self.bench.master_tx, proto.encode(header, bytes(payload)))
        if proto.PacketType(int(ptype)) in UPLOAD_TYPES:
            self.uploads.append(bytes(payload))
        return seq

    async def upload(self, ctx, packets) -> None:
        """Send ``(ptype, payload)`` pairs in order (CONFIG and PARAM: the node's uploads)."""
        for ptype, payload in packets:
            await self.send(ctx, ptype, payload)

    async def timecode(self, ctx, time: int) -> None:
        """Strobe a time-code with value ``time`` (0..63) from the master for one cycle."""
        ctx.set(self.bench.time_in, time)
        ctx.set(self.bench.tick_in, 1)
        await ctx.tick()
        ctx.set(self.bench.tick_in, 0)

    async def receive(self, ctx, ptype=None, seq: int | None = None
                      ) -> tuple[proto.Header, bytes]:
        """Take the next packet at the master; fail unless it is a good frame from the node
        to the master (and of type ``ptype`` and sequence ``seq`` when given)."""
        (chars,) = proto.split_packets(await get_chars(ctx, self.bench.master_rx, 1))
        verdict, header, payload = proto.check_frame(chars)
        if verdict != proto.Verdict.GOOD:
            raise AssertionError(f"the master received a bad frame ({verdict.name}): {chars}")
        payload = bytes(payload)
        self.replies.append((header, payload))
        want = (proto.MASTER_ADDRESS, self.address)
        if (header.dest, header.src) != want:
            raise AssertionError(f"reply addressed {header.dest} from {header.src}, expected "
                                 f"{want[0]} from {want[1]}")
        if ptype is not None and header.type != int(ptype):
            raise AssertionError(f"reply of type {header.type}, expected {int(ptype)} "
                                 f"({proto.PacketType(int(ptype)).name})")
        if seq is not None and header.seq != seq:
            raise AssertionError(f"reply with sequence {header.seq}, expected {seq}")
        return header, payload

    async def request(self, ctx, ptype) -> bytes:
        """Send a Comm A or Comm C request and return the node's reply payload."""
        seq = await self.send(ctx, ptype, b"\0")
        return (await self.receive(ctx, ptype, seq))[1]

    async def read_back(self, ctx) -> dict:
        """A Comm A request; the reply's fields (:func:`~mrm_cosim.protocol.regs.parse_comm_a`)
        after :meth:`check_uploads` passed on it."""
        fields = parse_comm_a(await self.request(ctx, proto.PacketType.COMM_A))
        self.check_uploads(fields)
        return fields

    def check_uploads(self, comm_a) -> None:
        """Fail unless a Comm A reply (payload or parsed fields) reports the CRC and count of
        exactly the uploads sent (:func:`~mrm_cosim.protocol.regs.upload_check`)."""
        fields = parse_comm_a(comm_a) if isinstance(comm_a, bytes | bytearray) else comm_a
        got = (fields["upload_crc"], fields["upload_count"])
        want = upload_check(self.uploads)
        if got != want:
            raise AssertionError(f"node reports uploads crc {got[0]:#06x} count {got[1]}, "
                                 f"expected crc {want[0]:#06x} count {want[1]} "
                                 f"({len(self.uploads)} sent)")

    async def exchange(self, ctx, *, period: int, comm_b: bytes | None, comm_d: bytes,
                       settle: int = 100) -> dict:
        """One period's Comm A–D exchange, as the master's cycle runs it.

        Time-code ``period``, ``settle`` cycles (the node takes its snapshot), Comm A request
        → reply, then for VDC (``comm_b`` given) Comm B and Comm C request → reply, and
        Comm D. Returns ``{"A": payload, "C": payload or None}``; both replies are checked for
        address, type and sequence, and Comm A's ``period`` must be ``period``.
        """
        await self.timecode(ctx, period)
        if settle:
            await ctx.tick().repeat(settle)
        out = {"A": await self.request(ctx, proto.PacketType.COMM_A), "C": None}
        if parse_comm_a(out["A"])["period"] != period:
            raise AssertionError(f"Comm A reports period {parse_comm_a(out['A'])['period']}, "
                                 f"expected {period}")
        if comm_b is not None:
            await self.send(ctx, proto.PacketType.COMM_B, comm_b)
            out["C"] = await self.request(ctx, proto.PacketType.COMM_C)
            parse_comm_c(out["C"])                      # 40 bytes, or it raises
        await self.send(ctx, proto.PacketType.COMM_D, comm_d)
        return out
