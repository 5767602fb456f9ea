"""Motion primitives in the closed loop: deployed with the uploads, read back before the start,
started by the master, generated on every joint; the model backend equal to the compiled
gateware bit for bit; the traditional and modularized architectures of the DMP paper."""

import numpy as np
import pytest

from mrm_cosim.cosim.preview import paper_test_profile
from mrm_cosim.cosim.track import run_faults, run_track
from mrm_cosim.errors import InputError
from mrm_cosim.master.cycle import Master, MasterTiming
from mrm_cosim.master.dmp import learn_dmp
from mrm_cosim.master.uploads import Gains, dmp_uploads, node_uploads
from mrm_cosim.models.robot import load_robot
from mrm_cosim.protocol.packet import PacketType
from mrm_cosim.protocol.regs import Config, DmpControl, config_payloads

PERIOD = 500_000                     # a 10 ms master
DELAY = PERIOD / 50e6


def _primitive(robot, tf=0.4):
    """One primitive per joint learned from the paper's quintic test (scaled to ``tf``)."""
    prof = paper_test_profile(robot, tf=tf)
    t = np.arange(0.0, tf + 5e-4, 1e-3)
    return prof, learn_dmp(prof.evaluate(t)[0], 1e-3, 30, alpha=25.0, alpha_s=3.0)


class _Delayed:
    def __init__(self, prof, delay):
        self.prof, self.delay = prof, delay

    def evaluate(self, t):
        return self.prof.evaluate(np.asarray(t, dtype=float) - self.delay)


def _run(backend, references, duration=0.15, robot="mrm3"):
    robot = load_robot(robot)
    prof, dmp = _primitive(robot)
    result, summary = run_track(robot, "pid-fpga", backend, duration, 1,
                                timing=MasterTiming(period_cycles=PERIOD),
                                profile=_Delayed(prof, DELAY), references=references,
                                dmp=dmp, commit_cycles=10_000)
    q_d = prof.evaluate(result.t - DELAY)[0]
    return result, summary, np.abs(result.q - q_d).max(axis=0)


def test_modularized_tracks_and_traditional_lags_at_the_same_slow_period():
    """At a 10 ms master the joints' own generators follow the quintic (error bounded by the
    primitive's fit and the PID's lag); the held references of the traditional master lag by
    up to a period of motion. Both runs clean, the primitives confirmed and running."""
    _, s_dmp, e_dmp = _run("model", "dmp")
    _, s_hold, e_hold = _run("model", "hold")
    assert run_faults(s_dmp) == [] and run_faults(s_hold) == []
    assert s_dmp["dmp_errors"] == 0 and s_dmp["references"] == "dmp"
    assert e_dmp.max() < 2e-3                       # rad (the 1 ms master: 0.96e-3)
    assert (e_hold > 5 * e_dmp).all()


def test_model_equals_compiled_with_primitives_on_the_joints():
    """The generator in every node: the model backend's plant trajectory, torques and trace
    hash are the Verilated gateware's, bit for bit (35 ms: the primitives start at 10 ms)."""
    m, s_m, _ = _run("model", "dmp", duration=0.035)
    c, s_c, _ = _run("compiled", "dmp", duration=0.035)
    assert s_m["dmp_errors"] == s_c["dmp_errors"] == 0
    assert m.violations == []
    np.testing.assert_array_equal(m.q, c.q)
    np.testing.assert_array_equal(m.tau, c.tau)
    assert m.trace_sha256 == c.trace_sha256
    assert np.ptp(c.q[:, 2]) > 1e-5                 # the joints moved under the primitives


def _comm_a(crc_count):
    from mrm_cosim.protocol.regs import PAYLOAD

    payload = bytearray(PAYLOAD)
    payload[21:23] = crc_count[0].to_bytes(2, "little")
    payload[23:25] = crc_count[1].to_bytes(2, "little")
    return bytes(payload)


def _master_after_period0_comm_a(wrong_node=None):
    robot = load_robot("mrm3")
    _, dmp = _primitive(robot)
    uploads = node_uploads(robot, "pid-fpga", Gains()) + dmp_uploads(robot, dmp)
    m = Master(robot, "pid-fpga", lambda t: (robot.home, np.zeros(3), np.zeros(3)),
               robot.counts_per_rev, uploads=uploads, references="dmp")
    m.begin(50_000)
    m.poll(50_000)
    for k in range(1, 4):
        crc, count = m.expected_uploads[k]
        if k == wrong_node:
            crc ^= 1                                 # a deploy word changed on the way
        m.on_packet(50_100 + k, k, PacketType.COMM_A, _comm_a((crc, count)))
    return m, [s for s in m.poll(60_000) if s.kind == "packet"]


def test_the_master_starts_the_primitives_only_after_reading_the_deploy_back():
    m, sends = _master_after_period0_comm_a()
    start = config_payloads({Config.DMP: DmpControl.START})[0]
    assert [(s.dest, s.ptype, s.payload) for s in sends if s.ptype == PacketType.CONFIG] == \
        [(k, PacketType.CONFIG, start) for k in (1, 2, 3)]
    assert m.dmp_started and sum(m.dmp_errors.values()) == 0
    # the START record is part of what every later Comm A must read back
    from mrm_cosim.protocol.packet import BROADCAST
    from mrm_cosim.protocol.regs import upload_check

    ups = [p for d, t, p in m._uploads
           if t in (PacketType.CONFIG, PacketType.PARAM) and d in (1, BROADCAST)]
    assert ups[-1] == start and m.expected_uploads[1] == upload_check(ups)


def test_a_deploy_that_reads_back_wrong_starts_nothing_and_is_counted():
    m, sends = _master_after_period0_comm_a(wrong_node=2)
    assert not m.dmp_started
    assert all(s.ptype != PacketType.CONFIG for s in sends)
    assert m.dmp_errors == {1: 0, 2: 1, 3: 0}


def test_deploy_refuses_what_the_nodes_cannot_run():
    robot = load_robot("mrm3")
    _, dmp = _primitive(robot)
    with pytest.raises(InputError) as e:
        dmp_uploads(robot, dmp.with_goal(dmp.g + np.array([0.0, 0.0, 10.0])))
    assert e.value.field == "dmp.g[2]"
    with pytest.raises(InputError) as e:
        dmp_uploads(robot, dmp, step_cycles=30_000)
    assert e.value.field == "dmp.step_cycles"
    with pytest.raises(InputError) as e:
        dmp_uploads(robot, dmp.with_tau(0.01))
    assert e.value.field == "dmp.tau"
    with pytest.raises(InputError) as e:
        dmp_uploads(load_robot("mrm6"), dmp)
    assert e.value.field == "dmp"
    big = dmp.__class__(**{**dmp.__dict__, "weights": dmp.weights * 1e4})
    with pytest.raises(InputError) as e:
        dmp_uploads(robot, big)
    assert e.value.field.startswith("dmp.joint1.weights[")


def test_a_new_goal_and_tau_are_one_word_each_read_back_from_the_next_period():
    from mrm_cosim.master.uploads import dmp_retarget
    from mrm_cosim.protocol.dmp import INVTAU, Reg
    from mrm_cosim.protocol.regs import Bank, unpack_words

    robot = load_robot("mrm3")
    m, _ = _master_after_period0_comm_a()
    _, dmp = _primitive(robot)
    goals = dmp.g + 0.01
    packets = dmp_retarget(robot, dmp, goals=goals, tau=0.5)
    written = {}                                     # (node, address) -> word
    for d, t, p in packets:
        assert t == PacketType.PARAM and p[0] == Bank.DMP and len(p) == 6
        written[(d, int.from_bytes(p[1:3], "little"))] = unpack_words(p, 1, 3)[0]
    cpr = robot.counts_per_rev
    assert written == {
        **{(k + 1, Reg.GOAL): round(goals[k] * cpr[k] / (2 * np.pi) * 16) for k in range(3)},
        **{(k + 1, Reg.INVTAU): INVTAU.encode(2.0) for k in range(3)}}
    before = dict(m.expected_uploads)
    m.send_uploads(packets)
    sends = m.poll(50_000 + 50_000)                 # period 1 starts: request, then the words
    kinds = [(s.kind, s.ptype) for s in sends]
    assert kinds[:2] == [("timecode", 0), ("packet", PacketType.COMM_A)]
    assert [s.payload for s in sends if s.ptype == PacketType.PARAM] == [p for _, _, p in packets]
    assert m.expected_uploads == before              # period 1's Comm A: taken before them
    m.poll(150_000)                                  # period 2: judged against them too
    assert m.expected_uploads != before
    with pytest.raises(InputError) as e:
        dmp_retarget(robot, dmp, goals=dmp.g + np.array([0.0, 9.0, 0.0]))
    assert e.value.field == "goals[1]"
    for bad in (0.0, -1.0, 0.01, 1e9):
        with pytest.raises(InputError) as e:
            dmp_retarget(robot, dmp, tau=bad)
        assert e.value.field == "tau"
