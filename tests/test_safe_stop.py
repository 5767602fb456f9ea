"""The node's safe stop (IEC 61800-5-2 SS1: stop, hold, brake, STO) through the master's uploads
and every backend: its parameters' words, the model backend's paths (kernel, Python, eager)
against each other, and the model against the gateware (compiled) around a trip.

The RTL == reference tests of the sequence are in tests/test_node_watchdog.py (the output
stage) and tests/test_node_core.py (the node core: hold → brake → STO → re-arm)."""

import numpy as np
import pytest

from mrm_cosim.errors import InputError
from mrm_cosim.protocol import packet as ref
from mrm_cosim.protocol.regs import Config, Status, parse_comm_a
from mrm_cosim.master.uploads import hold_gains
from mrm_cosim.protocol.safe_stop import SafeStopParams, safe_stop_config
from mrm_cosim.units import CLOCK_HZ

#: A trip in every period (the master talks for ~0.1 ms of each 1 ms period, the nodes time
#: out after 0.6 ms) and a short safe stop, so a run of a few periods sees all of it: the
#: fixed timer (the standstill rule off; the hold's reference the first hold tick's count).
TIMEOUT = 30_000
SHORT = SafeStopParams(stop_s=0.002, brake_s=0.002, standstill=0.0)
#: The same with the standstill rule: the arm trips near rest (period 0); joints 1 and 2 are
#: at standstill (0.5 ms within ±2 mrad/s) and brake within 0.1 ms of the trip (the hold's
#: reference frozen at the first hold tick), joint 3 still moves (~30 mrad/s at most): the
#: reference follows its count to the 4 ms time limit, where it brakes (STOP_LIMIT).
STILL = SafeStopParams(stop_s=0.004, brake_s=0.002, standstill=2e-3, standstill_s=0.0005,
                       stop_trail=0.0)
#: The same with a trail of 0.02 mrad (3 counts): joint 3 (moving ~0.1 mrad in the 4 ms)
#: drives the hold's target through it.
TRAIL = SafeStopParams(stop_s=0.004, brake_s=0.002, standstill=2e-3, standstill_s=0.0005,
                       stop_trail=0.02)


def test_safe_stop_words_follow_the_durations_and_bad_values_name_their_field():
    p = SafeStopParams(stop_s=0.05, brake_s=0.03, hold_hz=10.0, standstill=0.0)
    assert safe_stop_config(p) == {Config.STOP_CYCLES: round(0.05 * CLOCK_HZ),
                                   Config.BRAKE_CYCLES: round(0.03 * CLOCK_HZ)}
    g = hold_gains(p, 2.0)
    w = 2 * np.pi * 10.0
    assert g["kp"] == pytest.approx(3 * 2.0 * w * w) and g["kd"] == pytest.approx(6.0 * w)
    for kw, field in (({"stop_s": -1e-3}, "safe_stop.stop_s"),
                      ({"brake_s": float("nan")}, "safe_stop.brake_s"),
                      ({"stop_s": 100.0}, "safe_stop.stop_s"),
                      ({"stop_s": 0.34}, "safe_stop.stop_s"),      # 24-bit register: 0.3355 s
                      ({"brake_s": 0.34}, "safe_stop.brake_s"),
                      ({"hold_hz": 0.0}, "safe_stop.hold_hz"),
                      ({"standstill": -1e-3}, "safe_stop.standstill"),
                      ({"standstill": 20.0}, "safe_stop.standstill"),
                      ({"standstill": 1e-7}, "safe_stop.standstill"),
                      ({"standstill_s": float("inf")}, "safe_stop.standstill_s"),
                      ({"standstill_s": -1.0}, "safe_stop.standstill_s"),
                      ({"stop_trail": -0.5}, "safe_stop.stop_trail"),
                      ({"stop_trail": float("nan")}, "safe_stop.stop_trail"),
                      ({"stop_trail": 51.0}, "safe_stop.stop_trail")):
        with pytest.raises(InputError) as e:
            SafeStopParams(**kw)
        assert e.value.field == field


def test_standstill_words_follow_the_threshold_and_the_tick():
    """The standstill rule: the threshold as a VEL word (2^-19 rad/s), the duration in ticks;
    off (0, the default) nothing is sent (the reset values: the fixed timer)."""
    p = SafeStopParams(stop_s=0.3, standstill=2e-3, standstill_s=0.01)
    w = safe_stop_config(p, tick_cycles=50)
    assert w[Config.STANDSTILL] == round(2e-3 * 2**19) == 1049
    assert w[Config.STANDSTILL_TICKS] == 10_000                  # 10 ms of 1 µs ticks
    assert safe_stop_config(p, tick_cycles=500)[Config.STANDSTILL_TICKS] == 1_000
    assert safe_stop_config(SafeStopParams(standstill=1e-3, standstill_s=0.0))[
        Config.STANDSTILL_TICKS] == 1
    assert Config.STANDSTILL not in safe_stop_config(SafeStopParams(standstill=0.0))
    with pytest.raises(InputError) as e:
        safe_stop_config(SafeStopParams(standstill=1e-3, standstill_s=0.1), tick_cycles=50)
    assert e.value.field == "safe_stop.standstill_s"


def test_stop_trail_is_uploaded_per_joint_in_counts():
    """STOP_TRAIL: ``stop_trail`` mrad in each joint's counts (800,000 per revolution on the
    mrm3: 127.3 counts per mrad), rounded, at most the trail whose P term is half the joint's
    peak torque (joint 1: 11 N·m against a 15 Hz hold of 2.2 kg·m², 12 counts); 0 is not sent
    (the reset value: the uploads of a stop without the trail, byte for byte); too many
    counts for 16 bits names the field."""
    from mrm_cosim.master.uploads import Gains, node_uploads, trail_cap_counts
    from mrm_cosim.models.robot import load_robot
    from mrm_cosim.protocol.safe_stop import stop_trail_counts

    assert stop_trail_counts(SafeStopParams(stop_trail=1.0), 800_000) == 127
    assert stop_trail_counts(SafeStopParams(stop_trail=0.0), 800_000) == 0
    with pytest.raises(InputError) as e:
        stop_trail_counts(SafeStopParams(stop_trail=50.0), 10_000_000)
    assert e.value.field == "safe_stop.stop_trail"
    robot = load_robot("mrm3")
    default = round(SafeStopParams().stop_trail * 1e-3 * 800_000 / (2 * np.pi))
    for k, want in ((1, 12), (2, default), (3, default)):
        cfg, _ = _cfg_and_kp(node_uploads(robot, "vdc", Gains()), k)
        assert cfg[Config.STOP_TRAIL] == want
    assert trail_cap_counts(57_600.0, 11.0, 800_000) == 12       # ⌊0.5 · 11 / kp · K⌋
    cfg, _ = _cfg_and_kp(node_uploads(robot, "pid-fpga", Gains(), safe_stop=STILL), 2)
    assert Config.STOP_TRAIL not in cfg
    cfg, _ = _cfg_and_kp(node_uploads(robot, "pid-1khz", Gains(), safe_stop=TRAIL), 2)
    assert cfg[Config.STOP_TRAIL] == 3


def _cfg_and_kp(uploads, dest):
    """The CONFIG values and the kp word uploaded to node ``dest``."""
    from mrm_cosim.protocol.joint_program import joint_microcode
    from mrm_cosim.protocol.regs import unpack_words

    cfg, kp = {}, None
    for d, ptype, payload in uploads:
        if d != dest:
            continue
        if ptype == ref.PacketType.CONFIG:
            for k in range(0, len(payload) - 4, 5):
                cfg[payload[k]] = int.from_bytes(payload[k + 1:k + 5], "little")
        elif ptype == ref.PacketType.PARAM and payload[0] == 1:
            addr = int.from_bytes(payload[1:3], "little")
            words = unpack_words(payload, (len(payload) - 3) // 3, 3)
            a = joint_microcode(0).addr("kp")
            if addr <= a < addr + len(words):
                kp = words[a - addr]
    return cfg, kp


def test_the_master_uploads_the_timings_and_hold_gains_in_every_mode():
    from mrm_cosim.master.uploads import Gains, node_uploads, pid_gains
    from mrm_cosim.models.robot import load_robot

    robot = load_robot("mrm3")
    p = SafeStopParams(stop_s=0.01, brake_s=0.02, hold_hz=20.0)
    words = safe_stop_config(p)
    kps = {}
    for controller in ("vdc", "pid-1khz", "pid-fpga"):
        cfg, kps[controller] = _cfg_and_kp(node_uploads(robot, controller, Gains(),
                                                        safe_stop=p), 2)
        assert cfg[Config.STOP_CYCLES] == words[Config.STOP_CYCLES] == 500_000
        assert cfg[Config.BRAKE_CYCLES] == words[Config.BRAKE_CYCLES]
    # VDC and torque nodes read the PID words only while holding: the hold gains; pid-fpga
    # nodes hold with their tracking gains (15 Hz, not 20)
    assert kps["vdc"] == kps["pid-1khz"] != 0
    assert kps["pid-fpga"] != kps["vdc"]
    assert pid_gains(robot, 20.0)["kp"][1] / pid_gains(robot, 15.0)["kp"][1] == \
        pytest.approx((20 / 15) ** 2)
    cfg, _ = _cfg_and_kp(node_uploads(robot, "vdc", Gains()), 1)      # the defaults
    assert cfg[Config.STOP_CYCLES] == safe_stop_config(SafeStopParams())[Config.STOP_CYCLES]
    # the rule on by default: 10 mrad/s for 10 ms (10,000 ticks of 1 µs), limit 0.2 s
    assert cfg[Config.STANDSTILL] == round(0.01 * 2**19)
    assert cfg[Config.STANDSTILL_TICKS] == 10_000
    assert cfg[Config.STOP_CYCLES] == round(0.2 * CLOCK_HZ)
    cfg, _ = _cfg_and_kp(node_uploads(robot, "vdc", Gains(), safe_stop=SHORT), 1)
    assert Config.STANDSTILL not in cfg                  # the rule off: the fixed timer
    p = SafeStopParams(stop_s=0.3, standstill=2e-3, standstill_s=0.01)
    cfg, _ = _cfg_and_kp(node_uploads(robot, "vdc", Gains(), tick_cycles=100, safe_stop=p), 3)
    assert cfg[Config.STANDSTILL] == 1049 and cfg[Config.STANDSTILL_TICKS] == 5_000
    with pytest.raises(InputError) as e:
        node_uploads(robot, "vdc", Gains(), safe_stop=SafeStopParams(hold_hz=500.0))
    assert e.value.field == "safe_stop.hold_hz"


def _trip_loop(backend_name, controller, cycles, safe=SHORT, **model_kw):
    """The paper's quintic on mrm3 with a watchdog timeout shorter than the period: every node
    trips in period 0 and runs the short safe stop; returns (result, master, backend)."""
    from mrm_cosim.cosim.closed_loop import ClosedLoop
    from mrm_cosim.cosim.track import _trajectory, loop_backend
    from mrm_cosim.master.uploads import Gains, node_uploads, pid_shifts
    from mrm_cosim.models.plant import Plant
    from mrm_cosim.models.robot import load_robot
    from tests.recording import recording_master

    robot = load_robot("mrm3")
    gains = Gains()
    master = recording_master(robot, controller, _trajectory(robot))
    plant = Plant(robot, seed=0)
    plant.reset(robot.home)
    if backend_name == "model":
        from mrm_cosim.cosim.model import ModelBackend

        backend = ModelBackend(pid_shift=pid_shifts(robot), **model_kw)
    else:
        backend = loop_backend(robot, backend_name)
    uploads = node_uploads(robot, controller, gains, timeout_cycles=TIMEOUT, safe_stop=safe)
    brakes = []
    advance = backend.advance

    async def watched(n, lines, offset=0):
        out = await advance(n, lines, offset)
        brakes.append((backend.cycle if hasattr(backend, "cycle") else 0, backend.brake()))
        return out

    backend.advance = watched
    loop = ClosedLoop(robot, backend, master, plant, 50_000, uploads)
    return loop.run(cycles), master, backend, brakes


def _statuses(master):
    """Comm A's status per (period index, node)."""
    return {(i, src): parse_comm_a(p)["status"] for i, src, t, p in master.payloads
            if t == ref.PacketType.COMM_A}


@pytest.mark.parametrize("controller, safe", [("vdc", SHORT), ("pid-fpga", SHORT),
                                              ("vdc", STILL), ("vdc", TRAIL)])
def test_model_paths_agree_through_the_safe_stop(controller, safe):
    """Kernel (numba), pure Python and eager model paths give the same plant trace, torques,
    replies and brake outputs through trip → hold → brake → STO: the fast paths decline to
    the reference's event loop while a node's safe stop may act (with the standstill rule
    too: its brakes at standstill, before the time limit)."""
    cycles = 400_000                                # 8 ms: hold 2 ms, brake 2 ms, STO
    runs = {name: _trip_loop("model", controller, cycles, safe, **kw) for name, kw in (
        ("numba", {"kernel": "numba"}), ("python", {"kernel": "python"}),
        ("eager", {"lazy": False}))}
    res0, m0, be0, br0 = runs["numba"]
    for name in ("python", "eager"):
        res, m, be, br = runs[name]
        np.testing.assert_array_equal(res.q, res0.q, err_msg=name)
        np.testing.assert_array_equal(res.tau, res0.tau, err_msg=name)
        assert m.payloads == m0.payloads, name
        # (the kernel's fast path runs whole plant steps without a chunk: compare the cycles
        # both sampled)
        common = dict(br).keys() & dict(br0).keys()
        assert len(common) > 50
        assert all(dict(br)[c].tolist() == dict(br0)[c].tolist() for c in common), name
    st = _statuses(m0)
    seen = {s & (Status.HOLD | Status.BRAKE | Status.SAFE) for s in st.values()}
    assert Status.HOLD in seen and Status.HOLD | Status.BRAKE in seen
    assert Status.BRAKE | Status.SAFE in seen
    assert all(b.all() for _, b in br0[-10:]) and not any(b.any() for _, b in br0[:10])
    assert np.all(res0.tau[-1] == 0)                        # STO: no torque at the end
    limit = {k for (_, k), s in st.items() if s & Status.STOP_LIMIT}
    if safe in (STILL, TRAIL):  # joints 1, 2 at standstill, joint 3 at the time limit 4 ms later
        assert limit == {3}
        on = [next(c for c, b in br0 if b[k]) for k in range(3)]
        assert on[0] == on[1] and on[2] - on[0] > 0.9 * 0.004 * 50e6 - 0.0005 * 50e6
    else:
        assert not limit


@pytest.mark.parametrize("controller, safe", [("vdc", SHORT), ("vdc", STILL), ("vdc", TRAIL)])
def test_model_equals_compiled_through_the_safe_stop(controller, safe):
    """The gateware (compiled) and the model backend through the safe stop: the same plant
    trace, torques, Comm A statuses and brake outputs. The model's trip is at its modelled
    packet arrival (a few cycles from the gateware's), the hold's ticks and the STO's ramp on
    the node's own tick grid: with the trip between the same two ticks on both, bit for
    bit."""
    cycles = 400_000
    compiled, m_c, _, br_c = _trip_loop("compiled", controller, cycles, safe)
    model, m_m, _, br_m = _trip_loop("model", controller, cycles, safe)
    np.testing.assert_array_equal(model.q, compiled.q)
    np.testing.assert_array_equal(model.tau, compiled.tau)
    assert m_m.payloads == m_c.payloads
    # brake() at the end of every chunk both ran (the model's fast path runs whole plant
    # steps without one)
    bm, bc = dict(br_m), dict(br_c)
    common = sorted(bm.keys() & bc.keys())
    assert len(common) > 50
    assert [bm[c].tolist() for c in common] == [bc[c].tolist() for c in common]
    assert any(bc[c].all() for c in common) and not bc[common[0]].any()
    assert not any(bc[c].any() for c in common if c < 100_000)
