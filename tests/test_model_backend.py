"""The ``model`` backend (cosim.model, cosim.model_node): its encoder interface equals the cycle
reference, and the closed loop on it equals the compiled gateware bit for bit — the plant's q at
every plant step, the torque words, and every reply payload the master receives (issue 5)."""

import numpy as np
import pytest

from mrm_cosim.cosim.model import ModelAssumptionError
from mrm_cosim.cosim.model_node import EncoderEvents
from mrm_cosim.hdl.node.encoder_ref import EncoderModel, EncoderParams
from mrm_cosim.models.encoder import quadrature_levels


def _walk(rng, n):
    """Counts per cycle: runs of constant speed, stops, reversals, one-cycle dithers."""
    out = np.empty(n, dtype=np.int64)
    c, k = 12_345, 0
    while k < n:
        length = int(rng.integers(20, 3000))
        kind = rng.integers(0, 4)
        period = int(rng.integers(1, 400))
        sign = 1 if rng.random() < 0.5 else -1
        for j in range(min(length, n - k)):
            if kind == 1 and j % period == 0:
                c += sign
            elif kind == 2 and rng.random() < 0.02:      # dither: a count and back
                c += sign
                out[k] = c
                k += 1
                c -= sign
                if k >= n:
                    break
            elif kind == 3 and j % 2 == 0:                # fastest legal speed
                c += sign
            out[k] = c
            k += 1
            if k >= n:
                break
    return out


@pytest.mark.parametrize("seed, params", [
    (0, EncoderParams()),
    (1, EncoderParams(min_window=256, stop_cycles=5_000)),
    (2, EncoderParams(filter_cycles=1, min_window=64, stop_cycles=3_000)),
    (3, EncoderParams(filter_cycles=3, min_window=512)),
])
def test_encoder_events_equal_the_cycle_reference(seed, params):
    rng = np.random.default_rng(seed)
    n = 60_000
    counts = _walk(rng, n)
    a, b = quadrature_levels(counts)
    ticks = set(range(0, n, 50)) | {int(x) for x in rng.integers(0, n, 40)}
    ticks |= {t + 1 for t in list(ticks)[:10]}                  # ignored strobes
    ref = EncoderModel(params)
    fast = EncoderEvents(params, int(counts[0]))
    pos = 0
    checked = 0
    speeds = set()
    for c in range(n):
        if c == pos:                                            # feed in uneven chunks
            size = int(rng.integers(1, 900))
            fast.feed(c, counts[c:c + size])
            pos = min(n, c + size)
        if c in ticks:
            got = fast.sample(c)
            assert got == (ref.count, ref.velocity, ref.errors), f"cycle {c}"
            checked += 1
            speeds.add(got[1])
        ref.cycle(int(a[c]), int(b[c]), sample=c in ticks)
    assert checked > 1000
    assert len(speeds) > 50 and 0 in speeds          # measured, bounded and stopped



@pytest.mark.parametrize("seed, params, lazy", [
    (5, EncoderParams(), False),
    (6, EncoderParams(min_window=256, stop_cycles=5_000), False),
    (7, EncoderParams(filter_cycles=1, min_window=64, stop_cycles=3_000), True),
    (8, EncoderParams(min_window=256, stop_cycles=5_000), True),
])
def test_encoder_presets_equal_the_cycle_reference(seed, params, lazy):
    """CONFIG PRESET (homing) on the model backend's encoder interface: the count and the
    reference count load the value at the end of the cycle, as in the cycle reference (and the
    gateware, tests/test_node_encoder.py), on a moving joint, in a strobe's cycle (its MEASURE
    does not move the reference), the cycle after one, and with the strobes deferred. Before,
    the model ignored PRESET."""
    rng = np.random.default_rng(seed)
    n = 60_000
    counts = _walk(rng, n)
    a, b = quadrature_levels(counts)
    ticks = set(range(0, n, 50)) | {int(x) for x in rng.integers(0, n, 40)}
    presets = {int(t) + int(rng.integers(0, 3)): int(rng.integers(-2**31, 2**31))
               for t in rng.choice(sorted(ticks), 60, replace=False)}
    presets[0] = 777
    ref = EncoderModel(params)
    fast = EncoderEvents(params, int(counts[0]))
    pos = 0
    checked = 0
    for c in range(n):
        if c == pos:
            size = int(rng.integers(1, 900))
            fast.feed(c, counts[c:c + size])
            pos = min(n, c + size)
        if c in ticks:
            if lazy and c not in presets and rng.random() < 0.7:
                assert fast.defer(c) == ref.count, f"cycle {c}"
            else:
                assert fast.sample(c) == (ref.count, ref.velocity, ref.errors), f"cycle {c}"
                checked += 1
        if c in presets:
            fast.preset(c, presets[c])
        ref.cycle(int(a[c]), int(b[c]), sample=c in ticks, preset=presets.get(c))
    assert checked > 300
    assert fast.sample(n) == (ref.count, ref.velocity, ref.errors)


@pytest.mark.parametrize("arity", [1, 2, 3, 4, 5, 7])
def test_fx_point_equals_fx(arity):
    """The references' rounding points (hdl.node.vdc_ref.fx_point: the joint controller's and
    the VDC's hot path, which the model backend runs) against fx on random words and LSBs,
    extremes included so that every saturation acts."""
    from mrm_cosim.hdl.node.vdc_ref import fx, fx_point
    from mrm_cosim.protocol.fixed import Fmt

    rng = np.random.default_rng(arity)
    lo, hi = -(1 << 23), (1 << 23) - 1
    for _ in range(300):
        fmt = Fmt("X", int(rng.integers(-40, 12)), "")
        lsbs = [int(x) for x in rng.integers(-50, 12, arity)]
        point = fx_point(fmt, *lsbs)
        for _ in range(20):
            values = [int(rng.choice([lo, hi, 0, -1, 1])) if rng.random() < 0.1 else
                      int(rng.integers(-(1 << 46), 1 << 46)) for _ in range(arity)]
            assert point(*values) == fx(list(zip(values, lsbs, strict=True)), fmt)


def test_strict_model_refuses_a_grid_it_cannot_match():
    """Period 0 off the nodes' timer grid: the time-code resynchronises them, which the model
    can only place by its approximate latency, so a strict run stops and says why."""
    from mrm_cosim.cosim.closed_loop import ClosedLoop
    from mrm_cosim.cosim.model import ModelBackend
    from mrm_cosim.cosim.track import _trajectory
    from mrm_cosim.master.cycle import Master
    from mrm_cosim.master.uploads import Gains, node_uploads
    from mrm_cosim.models.plant import Plant
    from mrm_cosim.models.robot import load_robot

    robot = load_robot("mrm3")
    master = Master(robot, "vdc", _trajectory(robot), robot.counts_per_rev)
    plant = Plant(robot, seed=0)
    plant.reset(robot.home)
    loop = ClosedLoop(robot, ModelBackend(strict=True), master, plant, 20_000,
                      node_uploads(robot, "vdc", Gains()))
    with pytest.raises(ModelAssumptionError, match="grid|resynchronised"):
        loop.run(5_000)


class RecordingMaster:
    """Wraps the master's ``on_packet`` to keep every reply payload with its period."""

    @staticmethod
    def make(robot, controller):
        from tests.recording import recording_master

        return recording_master(robot, controller, _wiggle(robot))


def _wiggle(robot):
    """A 25 Hz swing from rest, 2-4 mrad: the joints move by thousands of counts in the window
    (the paper's quintic moves less than a count in its first 20 ms)."""
    amp = np.array([2e-3, 3e-3, 4e-3])
    w = 2 * np.pi * 25.0
    home = np.asarray(robot.home, dtype=float)

    def trajectory(t):
        return (home + amp * (1 - np.cos(w * t)), amp * w * np.sin(w * t),
                amp * w * w * np.cos(w * t))

    return trajectory


def _loop(backend, controller, cycles, seed=3, joints="rigid"):
    from mrm_cosim.cosim.track import run_loop
    from mrm_cosim.master.uploads import Gains, node_uploads
    from mrm_cosim.models.plant import PlantConfig, make_plant
    from mrm_cosim.models.robot import load_robot

    robot = load_robot("mrm3")
    master = RecordingMaster.make(robot, controller)
    plant = make_plant(robot, PlantConfig(joints=joints), seed=seed)
    plant.reset(robot.home)
    result, _ = run_loop(robot, backend, master, plant, 50_000,
                         node_uploads(robot, controller, Gains()), cycles)
    return result, master


@pytest.mark.parametrize("controller", ["vdc", "pid-fpga", "pid-1khz"])
def test_model_equals_compiled_bit_for_bit(controller):
    """20 ms after period 0 on mrm3: the plant's q at every plant step, the torque words the
    plant received, and every reply payload per period are the gateware's exactly; only the
    timeline (arrival cycles) is the model's approximation."""
    cycles = 1_000_000
    compiled, m_c = _loop("compiled", controller, cycles)
    model, m_m = _loop("model", controller, cycles)
    assert model.violations == []
    assert m_c.overruns == m_c.missing == m_c.unexpected == 0
    assert m_m.overruns == m_m.missing == m_m.unexpected == 0
    assert len(m_c.records) == 20 and all(r.complete for r in m_c.records[:-1])
    np.testing.assert_array_equal(model.q, compiled.q)
    np.testing.assert_array_equal(model.tau, compiled.tau)
    assert model.trace_sha256 == compiled.trace_sha256
    assert len(m_m.payloads) == len(m_c.payloads) == (6 if controller == "vdc" else 3) * 20
    assert m_m.payloads == m_c.payloads
    assert m_c.node_totals() == m_m.node_totals() == dict.fromkeys(m_c.node_totals(), 0)
    # the joints moved and the torques changed, so the comparison means something
    # (torque-only nodes hold the master's 1 kHz torque for a period)
    assert np.ptp(compiled.q, axis=0).min() > 5e-4
    assert len(np.unique(compiled.tau[:, 2])) > (15 if controller == "pid-1khz" else 100)
    # the phases' order is the same, their cycles are the model's
    for rc, rm in zip(m_c.records[:-1], m_m.records[:-1], strict=True):
        assert list(rc.events) == list(rm.events)
        assert abs(rc.events["D_sent"] - rm.events["D_sent"]) < 500


@pytest.mark.parametrize("controller", ["vdc", "pid-fpga"])
def test_model_equals_compiled_on_the_compliant_plant(controller):
    """The same agreement on the compliant plant (motor-side encoder, gear, noise, ripple),
    20 ms after period 0: what the nodes count is the motor, what is recorded the link."""
    cycles = 1_000_000
    compiled, m_c = _loop("compiled", controller, cycles, joints="compliant")
    model, m_m = _loop("model", controller, cycles, joints="compliant")
    assert model.violations == []
    assert m_c.overruns == m_c.missing == m_c.unexpected == 0
    np.testing.assert_array_equal(model.q, compiled.q)
    np.testing.assert_array_equal(model.tau, compiled.tau)
    assert model.trace_sha256 == compiled.trace_sha256
    assert m_m.payloads == m_c.payloads
    assert np.ptp(compiled.q, axis=0).min() > 2e-4     # the links moved (the gears lag)
    assert len(np.unique(compiled.tau[:, 2])) > 100
    # and it is not the rigid plant's run
    rigid, _ = _loop("model", controller, cycles)
    assert not np.array_equal(rigid.q, model.q)


def test_model_reports_a_comm_d_near_the_commit_phase():
    """A master slow enough that its Comm D reaches the nodes within the model's margin of
    the commit phase: the gateware may commit it this period or the next, so the model says
    it cannot vouch for the result. A Comm D well after the phase is late on both backends,
    counted, committed a period later, and the runs are still identical."""
    from mrm_cosim.cosim.closed_loop import ClosedLoop
    from mrm_cosim.cosim.model import ModelBackend
    from mrm_cosim.cosim.track import _trajectory, run_loop
    from mrm_cosim.master.cycle import Master, MasterTiming
    from mrm_cosim.master.uploads import Gains, node_uploads
    from mrm_cosim.models.plant import Plant
    from mrm_cosim.models.robot import load_robot

    robot = load_robot("mrm3")

    def parts(force_cycles):
        master = Master(robot, "vdc", _trajectory(robot), robot.counts_per_rev,
                        MasterTiming(force_cycles=force_cycles))
        plant = Plant(robot, seed=0)
        plant.reset(robot.home)
        return master, plant, node_uploads(robot, "vdc", Gains())

    master, plant, uploads = parts(6_800)
    near = ClosedLoop(robot, ModelBackend(), master, plant, 50_000, uploads)
    near.run(120_000)
    assert any("commit phase" in v for v in near.backend.violations)

    runs = {}
    for backend in ("compiled", "model"):
        master, plant, uploads = parts(9_000)
        result, _ = run_loop(robot, backend, master, plant, 50_000, uploads, 150_000)
        runs[backend] = (result, master)
    (compiled, m_c), (model, m_m) = runs["compiled"], runs["model"]
    assert model.violations == []
    assert model.trace_sha256 == compiled.trace_sha256
    # periods 0 and 1 of each node, as period 2's Comm A reports them
    assert m_m.node_totals()["late_d"] == m_c.node_totals()["late_d"] == 2 * 3


def _quintic_loop(controller, cycles, lazy, uploads=None, hook=None, start=50_000):
    """The paper's quintic on mrm3 for ``cycles`` after period 0, model backend only;
    ``hook(loop)`` before the run."""
    from mrm_cosim.cosim.closed_loop import ClosedLoop
    from mrm_cosim.cosim.model import ModelBackend
    from mrm_cosim.cosim.track import _trajectory
    from mrm_cosim.master.uploads import Gains, node_uploads, pid_shifts
    from mrm_cosim.models.plant import Plant
    from mrm_cosim.models.robot import load_robot
    from tests.recording import recording_master

    robot = load_robot("mrm3")
    gains = Gains()
    master = recording_master(robot, controller, _trajectory(robot), stamp="cycle")
    plant = Plant(robot, seed=0)
    plant.reset(robot.home)
    loop = ClosedLoop(robot, ModelBackend(lazy=lazy, pid_shift=pid_shifts(robot)), master, plant,
                      start, uploads or node_uploads(robot, controller, gains))
    if hook is not None:
        hook(loop)
    return loop, loop.run(cycles), master


def _same_runs(lazy, eager, violations=False):
    (l_loop, l_res, l_m), (e_loop, e_res, e_m) = lazy, eager
    assert l_res.violations == e_res.violations == l_loop.backend.violations
    assert bool(l_res.violations) == violations
    np.testing.assert_array_equal(l_res.q, e_res.q)
    np.testing.assert_array_equal(l_res.tau, e_res.tau)
    assert l_res.trace_sha256 == e_res.trace_sha256
    assert l_m.payloads == e_m.payloads and len(l_m.payloads) > 0
    assert l_res.frames == e_res.frames
    for a, b in zip(l_loop.backend.nodes, e_loop.backend.nodes, strict=True):
        a._materialize()
        assert (a.joint.q_des, a.joint.v_des, a.joint.i_lo, a.joint.i_hi, a.torque,
                a.overruns, a.late_d, a.sync_errors) == \
            (b.joint.q_des, b.joint.v_des, b.joint.i_lo, b.joint.i_hi, b.torque,
             b.overruns, b.late_d, b.sync_errors)


@pytest.mark.parametrize("controller", ["vdc", "pid-fpga", "pid-1khz"])
def test_lazy_ticks_equal_the_eager_path(controller):
    """200 ms of the quintic (model backend only, 10x the compiled comparison's window): the
    lazy path (only observed ticks computed, the plant's count changes instead of per-cycle
    arrays) gives the eager path's plant q, torques, reply payloads and final node state."""
    cycles = 10_000_000
    lazy = _quintic_loop(controller, cycles, True)
    eager = _quintic_loop(controller, cycles, False)
    _same_runs(lazy, eager)
    assert np.ptp(lazy[1].q, axis=0).min() > 1e-3           # the joints moved


def test_lazy_ticks_equal_the_eager_path_with_the_integral_clipped():
    """PID in the node with an anti-windup bound of a few IHI words: the coarse integral sits
    on its clip for much of the run; the lazy path's integral (updated on every tick, torque
    only where observed) is still the eager one."""
    from mrm_cosim.protocol import packet as ref
    from mrm_cosim.hdl.node.joint_ref import JointParams
    from mrm_cosim.master.uploads import Gains, node_uploads, pid_gains, pid_shifts
    from mrm_cosim.models.actuators import ACTUATORS
    from mrm_cosim.models.robot import load_robot
    from mrm_cosim.protocol.regs import Config, config_payloads, joint_upload

    robot = load_robot("mrm3")
    gains = Gains()
    pid = pid_gains(robot, gains.pid_fpga_hz)
    shifts = pid_shifts(robot)
    arm = config_payloads({Config.ARM: 1})
    uploads = []
    for dest, ptype, payload in node_uploads(robot, "pid-fpga", gains):
        if ptype == ref.PacketType.CONFIG and [payload] == arm:     # before the ARM: a tight
            k = dest - 1                                            # integral bound
            mod = robot.modules[k]
            joint = JointParams.from_float(
                counts_per_rev=mod.type.counts_per_rev, lam=gains.lam, k_j=gains.k_j,
                inertia=ACTUATORS[mod.type.actuator].output_inertia, k_p=pid["kp"][k],
                k_i=pid["ki"][k], k_d=pid["kd"][k], i_max=2e-8, pid_shift=shifts[k],
                field=f"joint{dest}")
            assert 0 < joint.ihi <= 4
            uploads += [(dest, ref.PacketType.PARAM, p) for p in joint_upload(joint)]
        uploads.append((dest, ptype, payload))

    class Watch:
        """Counts the ticks that end with the coarse integral on its bound."""

        def __init__(self, loop):
            self.hits = 0
            for node in loop.backend.nodes:
                joint = node.joint
                bound = (joint.params.ilo, joint.params.ihi)
                orig = node._fast_tick

                def tick(*a, node=node, orig=orig, bound=bound, **kw):
                    orig(*a, **kw)
                    self.hits += node.joint.i_hi in bound
                node._fast_tick = tick

    watches = []
    runs = [_quintic_loop("pid-fpga", 5_000_000, lazy, uploads,
                          hook=lambda loop: watches.append(Watch(loop)))
            for lazy in (True, False)]
    assert watches[1].hits > 1000                    # the eager ticks saw the clip often
    _same_runs(*runs)


def _feed_both(rng, counts, pos: int, per_cycle, changes) -> int:
    """The next chunk of ``counts`` (random length) from cycle ``pos``: per cycle into
    ``per_cycle`` (:meth:`EncoderEvents.feed`), as count changes into ``changes``
    (:meth:`EncoderEvents.feed_changes`); returns the cycle after it."""
    chunk = counts[pos:pos + int(rng.integers(1, 900))]
    per_cycle.feed(pos, chunk)
    prev = counts[pos - 1] if pos else counts[0]
    before = np.concatenate([[prev], chunk[:-1]])
    idx = np.flatnonzero(chunk != before)
    changes.feed_changes(pos, len(chunk), list(zip(idx.tolist(), chunk[idx].tolist(),
                                                   strict=True)))
    return pos + len(chunk)


def test_feed_changes_equals_feed():
    """The encoder interface fed count changes is the one fed per-cycle counts."""
    rng = np.random.default_rng(11)
    n = 40_000
    counts = _walk(rng, n)
    params = EncoderParams(min_window=256, stop_cycles=5_000)
    a, b = EncoderEvents(params, int(counts[0])), EncoderEvents(params, int(counts[0]))
    pos = 0
    for c in range(0, n, 50):
        if c >= pos:
            pos = _feed_both(rng, counts, pos, a, b)
        assert a.sample(c) == b.sample(c), c


@pytest.mark.parametrize("seed, params", [
    (0, EncoderParams()),
    (1, EncoderParams(min_window=256, stop_cycles=5_000)),
    (2, EncoderParams(filter_cycles=1, min_window=64, stop_cycles=3_000)),
    (3, EncoderParams(filter_cycles=3, min_window=512)),
])
def test_deferred_strobes_equal_strobing_every_tick(seed, params):
    """EncoderEvents.defer (the dead ticks' path: the count now, the velocity strobe folded
    into the next sample) against strobing at every tick: the same counts at every deferred
    tick and the same (count, velocity, errors) at every sample, through measurements, bounds,
    stops, strobes closer than the velocity latency, and ages that saturate."""
    from mrm_cosim.hdl.node.encoder_ref import AGE_MAX

    rng = np.random.default_rng(100 + seed)
    n = 60_000
    counts = _walk(rng, n)
    ref = EncoderEvents(params, int(counts[0]))
    lazy = EncoderEvents(params, int(counts[0]))
    strobes = sorted(set(range(0, n, 50)) | {int(x) for x in rng.integers(0, n, 300)})
    pos = 0
    samples = deferred = 0
    velocities = set()
    for c in strobes:
        while c >= pos:
            pos = _feed_both(rng, counts, pos, ref, lazy)
        want = ref.sample(c)
        velocities.add(want[1])
        if rng.random() < 0.85:
            assert lazy.defer(c) == want[0], c
            deferred += 1
        else:
            assert lazy.sample(c) == want, c
            samples += 1
    # a long rest: ages saturate (AGE_MAX cycles), strobes deferred across it
    quiet = AGE_MAX + 3_000_000
    ref.feed_changes(pos, quiet, ())
    lazy.feed_changes(pos, quiet, ())
    for c in range(pos + 50, pos + quiet, 1_000_003):
        want = ref.sample(c)
        velocities.add(want[1])
        assert lazy.defer(c) == want[0]
    c = pos + quiet - 1
    assert lazy.sample(c) == ref.sample(c)
    assert deferred > 900 and samples > 100
    assert len(velocities) > 50 and 0 in velocities


def test_the_bound_never_grows_with_its_denominator():
    """What folding a run of BOUND strobes relies on (EncoderEvents._flush): the reciprocal
    ``y1 · 2^−p`` of every denominator 1 … AGE_MAX is at most that of the one before, so
    ``velocity_word(num, den)`` is non-increasing in ``den`` (a rounding of a non-increasing
    value). All 2^26 denominators, vectorised, spot-checked against ``reciprocal``."""
    from mrm_cosim.hdl.node.encoder_ref import AGE_MAX, RECIP_TABLE, reciprocal

    table = np.array(RECIP_TABLE, dtype=np.int64)
    prev = None
    for p in range(AGE_MAX.bit_length()):
        for lo in range(1 << p, min(1 << (p + 1), AGE_MAX + 1), 1 << 20):
            den = np.arange(lo, min(lo + (1 << 20), 1 << (p + 1), AGE_MAX + 1), dtype=np.int64)
            m17 = (den << (25 - p)) >> 9
            y0 = table[(m17 >> 8) & 0xFF]
            y1 = y0 + ((y0 * ((1 << 17) - ((m17 * y0) >> 16))) >> 17)
            value = y1 << (26 - p)                   # y1 · 2^−p, scaled by 2^26: exact
            assert prev is None or value[0] <= prev
            assert np.all(np.diff(value) <= 0)
            prev = int(value[-1])
            for i in (0, len(den) - 1):
                assert reciprocal(int(den[i])) == (int(y1[i]), p)


@pytest.mark.parametrize("controller", ["vdc", "pid-fpga"])
def test_lazy_ticks_equal_the_eager_path_when_the_watchdog_trips(controller):
    """A watchdog timeout shorter than the period: every node trips between packets, ramps
    its torque down and is re-armed by nothing; the ticks around the trip (the ramp reads the
    torque, PRIME follows) are computed one by one and the runs stay identical."""
    from mrm_cosim.master.uploads import Gains, node_uploads
    from mrm_cosim.models.robot import load_robot

    uploads = node_uploads(load_robot("mrm3"), controller, Gains(), timeout_cycles=30_000)
    runs = [_quintic_loop(controller, 1_500_000, lazy, uploads) for lazy in (True, False)]
    _same_runs(*runs, violations=True)
    assert any("tripped" in v for v in runs[0][0].backend.violations)
    assert all(node.tripped for node in runs[1][0].backend.nodes)


@pytest.mark.parametrize("controller, start", [("vdc", 2_000), ("pid-fpga", 20_000)])
def test_lazy_ticks_equal_the_eager_path_off_the_plant_grid(controller, start):
    """Period 0 before the uploads are done (``mrm bench``'s 2,000 cycles) or off the nodes'
    timer grid: time-codes resynchronise the nodes, whose ticks then fall off the plant
    step's 50-cycle grid, so a step's last tick lands after the plant samples the torque and
    the tick before it is the one observed. The model reports the conditions it cannot vouch
    for (the same on both paths) and the paths stay identical."""
    runs = [_quintic_loop(controller, 1_500_000, lazy, start=start) for lazy in (True, False)]
    _same_runs(*runs, violations=True)
    phases = {b % 50 for node in runs[0][0].backend.nodes for b in node.boundaries[1:]}
    assert phases - {0}                                 # ticks off the step's grid


def test_progress_is_reported_every_simulated_millisecond():
    from mrm_cosim.cosim.track import run_track

    calls = []
    run_track("mrm3", "vdc", "model", duration=0.003,
              progress=lambda t, total: calls.append((round(t, 6), round(total, 6))))
    assert calls == [(0.001, 0.003), (0.002, 0.003), (0.003, 0.003)]


def test_every_backend_is_the_one_gateware_side_and_closed_loop_the_one_loop():
    """pysim, compiled and model implement cosim.gateware_side.GatewareSide, and no class in
    cosim/ but ClosedLoop has a ``run`` that steps the plant (the model backend's loop used to
    be a second copy, ModelLoop)."""
    import ast
    import inspect
    from pathlib import Path

    import mrm_cosim.cosim as cosim_pkg
    from mrm_cosim.cosim.backends import CompiledBackend, PysimBackend
    from mrm_cosim.cosim.closed_loop import ClosedLoop
    from mrm_cosim.cosim.gateware_side import GatewareSide
    from mrm_cosim.cosim.model import ModelBackend
    from mrm_cosim.cosim.track import loop_backend
    from mrm_cosim.models.robot import load_robot

    for cls in (PysimBackend, CompiledBackend, ModelBackend):
        assert issubclass(cls, GatewareSide), cls
    robot = load_robot("mrm3")
    assert isinstance(loop_backend(robot, "model"), GatewareSide)

    stepping = []
    for path in sorted(Path(cosim_pkg.__file__).parent.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ClassDef):
                continue
            for fn in node.body:
                if isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef) and \
                        fn.name in ("run", "arun") and any(
                            isinstance(c, ast.Attribute) and c.attr == "step"
                            and isinstance(c.value, ast.Name | ast.Attribute)
                            and "plant" in ast.unparse(c.value)
                            for c in ast.walk(fn)):
                    stepping.append((path.name, node.name))
    assert stepping == [("closed_loop.py", "ClosedLoop")]
    assert "plant.step" in inspect.getsource(ClosedLoop.arun)
