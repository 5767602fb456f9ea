"""The master's recovery from trips (master/recovery.py, master/cycle.py): the blend, the
re-arm sequence and the end, as packets."""

import numpy as np
import pytest

from mrm_cosim.master.cycle import Master, MasterTiming
from mrm_cosim.master.recovery import Blend, quintic_blend
from mrm_cosim.models.robot import load_robot
from mrm_cosim.protocol.packet import PacketType
from mrm_cosim.protocol.regs import Config, Status, config_payloads, pack_comm_d


def test_quintic_blend_meets_both_ends():
    rng = np.random.default_rng(0)
    ends = rng.normal(size=(6, 4))
    T = 0.2
    c = quintic_blend(*ends, T)
    p = np.polynomial.polynomial
    for k in range(4):
        poly = c[:, k]
        d1, d2 = p.polyder(poly), p.polyder(poly, 2)
        np.testing.assert_allclose([p.polyval(0, poly), p.polyval(0, d1), p.polyval(0, d2)],
                                   ends[:3, k], atol=1e-12)
        np.testing.assert_allclose([p.polyval(T, poly), p.polyval(T, d1), p.polyval(T, d2)],
                                   ends[3:, k], rtol=1e-9, atol=1e-9)


def test_blend_starts_at_rest_and_joins_the_trajectory():
    def traj(t):
        return np.array([t, 2 * t]), np.array([1.0, 2.0]), np.zeros(2)

    b = Blend(traj, [0.3, 0.1], 0.5, 0.2)
    q, v, a = b(0.5)
    np.testing.assert_allclose(q, [0.3, 0.1])
    np.testing.assert_allclose(v, 0.0, atol=1e-12)
    q, v, _ = b(0.7 - 1e-9)
    np.testing.assert_allclose(q, [0.7, 1.4], atol=1e-6)
    np.testing.assert_allclose(v, [1.0, 2.0], atol=1e-5)
    assert b(0.8)[0].tolist() == [0.8, 1.6]


def comm_a(period: int, status: int, count: int = 0, crc: int = 0xFFFF, n_up: int = 0) -> bytes:
    """A Comm A reply payload (protocol/regs.py layout) with the fields the master reads."""
    from mrm_cosim.protocol.regs import PAYLOAD

    out = bytearray(PAYLOAD)
    out[0:4] = count.to_bytes(4, "little", signed=True)
    out[10:12] = int(status).to_bytes(2, "little")
    out[14] = period & 0x3F
    out[21:23] = crc.to_bytes(2, "little")
    out[23:25] = n_up.to_bytes(2, "little")
    return bytes(out)


def make_master(on_trip):
    robot = load_robot("mrm3")

    def traj(t):
        return np.full(3, 0.1 * t), np.full(3, 0.1), np.zeros(3)

    return Master(robot, "pid-fpga", traj, robot.counts_per_rev, MasterTiming(), uploads=[],
                  on_trip=on_trip, rearm_blend=0.1)


def period(m, p: int, status: int, answer=(1, 2, 3)) -> list:
    """Period ``p``: the master's sends at its start, the Comm A replies of ``answer``, then
    what it sends in the period."""
    from mrm_cosim.protocol.regs import parse_comm_a

    start = m.start + p * m.timing.period_cycles
    sends = m.poll(start)
    request = [s for s in sends if s.ptype == PacketType.COMM_A]
    for k in answer:
        payload = comm_a(p, status)
        assert parse_comm_a(payload)["period"] == p & 0x3F
        m.on_packet(start + 2000, k, PacketType.COMM_A, payload, request[0].seq if request else
                    None)
    later = m.poll(start + m.timing.period_cycles - 1)
    return sends + later


def test_rearm_sends_a_hold_then_arm_and_blends_back():
    m = make_master("rearm")
    m.begin(0)
    for p in range(3):
        period(m, p, Status.ARMED | (1 << 5))
    period(m, 3, 0, answer=())                  # the link is down: nothing comes
    sends = period(m, 4, Status.ARMED | Status.TRIPPED | Status.HOLD)
    assert m.lost == {1, 2, 3} and m.tripped == {1, 2, 3}
    assert [s.ptype for s in sends if s.kind == "packet"] == [PacketType.COMM_A]
    assert m.rearms == 0                        # still stopping: the re-arm waits for BRAKE
    sends = period(m, 5, Status.ARMED | Status.TRIPPED | Status.HOLD | Status.BRAKE)
    arm = config_payloads({Config.ARM: 1})
    kinds = [(s.dest, s.ptype, s.payload) for s in sends
             if s.kind == "packet" and s.ptype != PacketType.COMM_A]
    # a Comm D holding the reported position at rest to every node, then ARM to every node
    hold = [pack_comm_d(0.0, g, 0.0, 0.0, 0.0, int(m.counts_per_rev[k]))
            for k, g in enumerate(m.gravity_in_C(np.zeros(3)))]
    assert kinds == [(k + 1, PacketType.COMM_D, hold[k]) for k in range(3)] + \
        [(k, PacketType.CONFIG, p) for k in (1, 2, 3) for p in arm]
    assert m.rearms == 1 and m.ended is None
    # the period the ARM lands in still reports the trip (its snapshot is before the ARM):
    # no second re-arm, the blend's references
    sends = period(m, 6, Status.ARMED | Status.TRIPPED | Status.HOLD | Status.BRAKE)
    assert m.rearms == 1
    assert any(s.ptype == PacketType.COMM_D for s in sends)


def test_end_stops_sending_at_the_first_lost_period():
    m = make_master("end")
    m.begin(0)
    period(m, 0, Status.ARMED)
    period(m, 1, 0, answer=(1, 3))               # node 2 silent
    assert m.poll(m.start + 2 * m.timing.period_cycles) == []
    assert m.ended is not None and "node 2" in m.ended
    assert m.poll(m.start + 10 * m.timing.period_cycles) == []
    overruns = m.overruns
    m.finish(m.start + 20 * m.timing.period_cycles)
    assert m.overruns == overruns


@pytest.mark.parametrize("on_trip", ["end", "rearm"])
def test_a_trip_reported_in_comm_a_is_acted_on(on_trip):
    m = make_master(on_trip)
    m.begin(0)
    period(m, 0, Status.ARMED)
    period(m, 1, Status.ARMED | Status.TRIPPED | Status.BRAKE)
    assert m.tripped == {1, 2, 3}
    assert (m.ended is not None) == (on_trip == "end")
    assert m.rearms == (on_trip == "rearm")


def test_primitive_driven_joints_are_not_rearmed():
    robot = load_robot("mrm3")

    def traj(t):
        return np.zeros(3), np.zeros(3), np.zeros(3)

    m = Master(robot, "pid-fpga", traj, robot.counts_per_rev, MasterTiming(), uploads=[],
               references="dmp", on_trip="rearm")
    m.begin(0)
    period(m, 0, Status.ARMED)
    period(m, 1, Status.ARMED | Status.TRIPPED | Status.BRAKE)
    assert m.rearms == 0 and "primitives" in m.ended
