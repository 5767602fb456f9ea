# amaranth: UnusedElaboratable=no
"""The slave node on the real link: a master codec sends uploads, a time-code and the
A/B/C/D exchange to a SlaveNode; its replies equal the transaction-level reference."""

import numpy as np
from amaranth import *
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out
from amaranth.sim import Simulator

from mrm_cosim.protocol import packet as proto
from mrm_cosim.hdl.link.chain import master_receive, put_chars
from mrm_cosim.hdl.link.chars import Char
from mrm_cosim.hdl.link.codec import Codec
from mrm_cosim.hdl.node.core_ref import NodeModel
from mrm_cosim.protocol.encoder import EncoderParams
from mrm_cosim.protocol.regs import (
    Status, pack_comm_b, pack_comm_d, parse_comm_a, parse_comm_c, vdc_upload,
)
from mrm_cosim.hdl.node.top import SlaveNode
from mrm_cosim.models.robot import load_robot

from mrm_cosim.testbench import run_simulation

SHORT = {"reset_cycles": 60, "wait_cycles": 150}
ENC = EncoderParams(min_window=256)


class MasterAndNode(wiring.Component):
    """A master-side codec wired to one SlaveNode at address 1 (as hdl.link.chain.Chain)."""

    master_tx:      In(stream.Signature(Char))
    master_rx:      Out(stream.Signature(Char))
    tick_in:        In(1)
    time_in:        In(8)
    master_running: Out(1)
    node_running:   Out(1)
    status:         Out(16)

    def __init__(self):
        self.master = Codec(**SHORT)
        self.node = SlaveNode(codec=SHORT, encoder=ENC)
        super().__init__()

    def elaborate(self, platform):
        m = Module()
        m.submodules.master = master = self.master
        m.submodules.node = node = self.node
        m.d.comb += [
            master.link_start.eq(1),
            master.tick_in.eq(self.tick_in),
            master.time_in.eq(self.time_in),
            self.master_running.eq(master.running),
            self.node_running.eq(node.link.up_running),
            self.status.eq(node.status),
            node.address.eq(1),
            node.up.d_in.eq(master.d_out),
            node.up.s_in.eq(master.s_out),
            master.d_in.eq(node.up.d_out),
            master.s_in.eq(node.up.s_out),
        ]
        wiring.connect(m, tx=wiring.flipped(self.master_tx), codec=master.tx)
        wiring.connect(m, rx=wiring.flipped(self.master_rx), codec=master.rx)
        return m


def test_node_answers_the_exchange_over_the_link():
    dut = MasterAndNode()
    robot = load_robot("mrm3")
    theta = robot.nominal_theta[1]
    rng = np.random.default_rng(1)
    uploads = [(proto.PacketType.PARAM, p) for p in
               vdc_upload(theta, np.full((2, 6), 30.0), np.zeros((2, 13)), theta - 0.01,
                          theta + 0.01)]
    g = np.array([0.0, 0.0, 9.81])
    V = rng.normal(size=6) * 0.2
    b = pack_comm_b(0.2, V, V + 1e-3, prime=True)
    d = pack_comm_d(0.5, g, 0.0, 0.2, 0.0)
    replies = {}

    async def frame(ctx, ptype, payload, seq=0):
        await put_chars(ctx, dut.master_tx,
                        proto.encode(proto.Header(1, proto.MASTER_ADDRESS, int(ptype), seq),
                                     payload))

    async def reply(ctx):
        (chars,) = await master_receive(ctx, dut)
        verdict, header, payload = proto.check_frame(chars)
        assert verdict == proto.Verdict.GOOD
        return header, bytes(payload)

    async def master(ctx):
        for _ in range(3000):
            if ctx.get(dut.master_running) and ctx.get(dut.node_running):
                break
            await ctx.tick()
        else:
            raise AssertionError("link did not come up")
        for ptype, payload in uploads:
            await frame(ctx, ptype, payload)
        await frame(ctx, proto.PacketType.COMM_D, d)            # gravity for the first VDC run
        ctx.set(dut.time_in, 5)
        ctx.set(dut.tick_in, 1)
        await ctx.tick()
        ctx.set(dut.tick_in, 0)
        await ctx.tick().repeat(100)
        await frame(ctx, proto.PacketType.COMM_A, b"\0", seq=7)
        replies["A"] = await reply(ctx)
        await frame(ctx, proto.PacketType.COMM_B, b)
        await frame(ctx, proto.PacketType.COMM_C, b"\0", seq=8)
        replies["C"] = await reply(ctx)

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(master)
    run_simulation(sim, "node_link")

    model = NodeModel(encoder=ENC)
    for ptype, payload in uploads:
        model.packet(0, ptype, payload)
    model.packet(0, proto.PacketType.COMM_D, d)
    model.period_start(0, 0, 0)                    # the joint rests at count 0
    ref_a = model.packet(0, proto.PacketType.COMM_A, b"\0", period=5)
    model.packet(0, proto.PacketType.COMM_B, b)
    ref_c = model.packet(0, proto.PacketType.COMM_C, b"\0", period=5)

    header_a, payload_a = replies["A"]
    assert (header_a.dest, header_a.src, header_a.type, header_a.seq) == \
        (proto.MASTER_ADDRESS, 1, proto.PacketType.COMM_A, 7)
    assert payload_a == ref_a
    assert parse_comm_a(payload_a)["period"] == 5
    header_c, payload_c = replies["C"]
    assert (header_c.src, header_c.type, header_c.seq) == (1, proto.PacketType.COMM_C, 8)
    assert payload_c == ref_c
    F_a, F_b, status, _ = parse_comm_c(payload_c)
    assert status & Status.FRESH and any(F_b)

