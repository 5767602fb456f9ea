# amaranth: UnusedElaboratable=no
"""The slave node on the real link, driven with the kit's node bus-functional model
(mrm_cosim.testbench.NodeBench / NodeMaster): uploads, a time-code and the A/B/C/D exchange;
the node's replies equal the transaction-level reference, and the upload read-back holds."""

import numpy as np
import pytest
from amaranth.sim import Simulator

from mrm_cosim.hdl.node.core_ref import NodeModel
from mrm_cosim.models.robot import load_robot
from mrm_cosim.protocol import packet as proto
from mrm_cosim.protocol.encoder import EncoderParams
from mrm_cosim.protocol.regs import (
    Config, Status, config_payloads, pack_comm_b, pack_comm_d, parse_comm_a, parse_comm_c,
    upload_check, vdc_upload,
)
from mrm_cosim.testbench import NodeBench, NodeMaster, run_simulation

ENC = EncoderParams(min_window=256)


def test_node_answers_the_exchange_over_the_link():
    bench = NodeBench(encoder=ENC)
    nm = NodeMaster(bench)
    robot = load_robot("mrm3")
    theta = robot.nominal_theta[1]
    rng = np.random.default_rng(1)
    uploads = [(proto.PacketType.PARAM, p) for p in
               vdc_upload(theta, np.full((2, 6), 30.0), np.zeros((2, 13)), theta - 0.01,
                          theta + 0.01)]
    uploads += [(proto.PacketType.CONFIG, p) for p in config_payloads({Config.RAMP: 3})]
    g = np.array([0.0, 0.0, 9.81])
    V = rng.normal(size=6) * 0.2
    b = pack_comm_b(0.2, V, V + 1e-3, prime=True)
    d = pack_comm_d(0.5, g, 0.0, 0.2, 0.0)
    out = {}

    async def master(ctx):
        await nm.bring_up(ctx)
        await nm.upload(ctx, uploads)
        await nm.send(ctx, proto.PacketType.COMM_D, d)      # gravity for the first VDC run
        out.update(await nm.exchange(ctx, period=5, comm_b=b, comm_d=d))
        out["read_back"] = await nm.read_back(ctx)
        out["seqs"] = [h.seq for h, _ in nm.replies]

    sim = Simulator(bench)
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

    assert out["A"] == ref_a
    a = parse_comm_a(out["A"])
    assert a["period"] == 5
    assert (a["upload_crc"], a["upload_count"]) == upload_check(p for _, p in uploads)
    assert a["upload_count"] == len(uploads) > 1
    assert out["C"] == ref_c
    F_a, F_b, status, _ = parse_comm_c(out["C"])
    assert status & Status.FRESH and any(F_b)
    # uploads, then D (seq n), A request, B, C request, D, read-back A: replies echo their seq
    n = len(uploads)
    assert out["seqs"] == [n + 1, n + 3, n + 5]
    assert out["read_back"]["upload_count"] == len(uploads)


def _comm_a(crc, count):
    payload = bytearray(40)
    payload[21:23] = crc.to_bytes(2, "little")
    payload[23:25] = count.to_bytes(2, "little")
    return bytes(payload)


def test_upload_read_back_fails_on_a_lost_or_changed_upload():
    nm = NodeMaster(bench=object())      # the check reads no signal: no design needed
    nm.uploads = [b"\x01" * 9, b"\x02" * 17]
    nm.check_uploads(_comm_a(*upload_check(nm.uploads)))
    with pytest.raises(AssertionError, match="count 1, expected .* count 2"):
        nm.check_uploads(_comm_a(*upload_check(nm.uploads[:1])))     # the second one lost
    with pytest.raises(AssertionError, match="expected crc"):
        nm.check_uploads(_comm_a(*upload_check([b"\x01" * 9, b"\x03" * 17])))
