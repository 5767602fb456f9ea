"""Ruckig time-optimal line vs the trigonometric one under the same limits."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from ruckig import InputParameter, Ruckig, Synchronization, Trajectory
from scipy.spatial.transform import Rotation

from mrm_cosim.master import quaternion as quat
from mrm_cosim.master.ruckig_profile import plan_line_ruckig
from mrm_cosim.master.trig_planner import AxisLimits, LineLimits, plan_line, sample_times

START = [[1, 0, 0, 0.3], [0, 1, 0, 0.0], [0, 0, 1, 0.4], [0, 0, 0, 1]]
END = [[0, -1, 0, 0.1], [1, 0, 0, 0.2], [0, 0, 1, 0.5], [0, 0, 0, 1]]
LIMITS = LineLimits(AxisLimits(1.0, 4.0, 40.0), AxisLimits(1.0, 4.0, 40.0))


def pose(R, p):
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = p
    return M


def ruckig_1d(distance, lim):
    """Independent single-DOF Ruckig solve, for the minimum time of one part alone."""
    otg, inp, traj = Ruckig(1), InputParameter(1), Trajectory(1)
    inp.current_position, inp.target_position = [0.0], [distance]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = ([lim.velocity],
                                                            [lim.acceleration], [lim.jerk])
    otg.calculate(inp, traj)
    return traj.duration


def test_example_durations():
    trig = plan_line(START, END, LIMITS)
    rk = plan_line_ruckig(trig)
    assert rk.duration <= trig.duration
    assert rk.trig_duration == trig.duration
    assert rk.translation_time == pytest.approx(ruckig_1d(0.3, LIMITS.translation), rel=1e-12)
    assert rk.rotation_time == pytest.approx(ruckig_1d(np.pi / 2, LIMITS.rotation), rel=1e-12)
    assert rk.duration == max(rk.translation_time, rk.rotation_time)
    # velocity-bound rotation: θ/V + V/A + A/J = π/2 + 1/4 + 1/10
    assert rk.rotation_time == pytest.approx(np.pi / 2 + 0.25 + 0.1, rel=1e-12)
    summary = rk.summary()
    assert summary["trig_duration_s"] == trig.duration
    assert summary["duration_s"] == rk.duration


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), v=st.floats(0.1, 3), a=st.floats(0.2, 10),
       j=st.floats(1, 200), scale=st.floats(1e-3, 2))
def test_ruckig_is_never_slower_than_trig(seed, v, a, j, scale):
    rng = np.random.default_rng(seed)
    R0, R1 = Rotation.random(2, random_state=rng).as_matrix()
    lim = LineLimits(AxisLimits(v, a, j), AxisLimits(1.3 * v, 0.7 * a, 2 * j))
    trig = plan_line(pose(R0, rng.normal(size=3) * scale), pose(R1, rng.normal(size=3) * scale),
                     lim)
    rk = plan_line_ruckig(trig)
    assert rk.duration <= trig.duration * (1 + 1e-12)
    assert rk.translation_time <= trig.translation_time * (1 + 1e-12)
    assert rk.rotation_time <= trig.rotation_time * (1 + 1e-12)


def test_profile_evaluation_matches_ruckig_at_time():
    trig = plan_line(START, END, LIMITS)
    rk = plan_line_ruckig(trig)
    otg, inp, traj = Ruckig(2), InputParameter(2), Trajectory(2)
    inp.current_position = [0.0, 0.0]
    inp.target_position = [trig.geometry.distance, trig.geometry.angle]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [1.0, 1.0], [4.0, 4.0], [40.0, 40.0]
    inp.synchronization = Synchronization.Time
    otg.calculate(inp, traj)
    for t in np.random.default_rng(1).uniform(0, rk.duration, 50):
        p, v, a = traj.at_time(t)
        for k, path in enumerate((rk.translation, rk.rotation)):
            s, sd, sdd, _ = path.evaluate([t])
            assert s[0] == pytest.approx(p[k], abs=1e-12)
            assert sd[0] == pytest.approx(v[k], abs=1e-12)
            assert sdd[0] == pytest.approx(a[k], abs=1e-11)


def test_samples_respect_limits_and_end_exactly():
    trig = plan_line(START, END, LIMITS)
    rk = plan_line_ruckig(trig)
    t = sample_times(rk.duration, 0.001)
    smp = rk.sample(t)
    for vecs, lim in (((smp.velocity, smp.acceleration, smp.jerk), LIMITS.translation),
                      ((smp.angular_velocity, smp.angular_acceleration, smp.angular_jerk),
                       LIMITS.rotation)):
        v, a, j = (np.max(np.linalg.norm(x, axis=1)) for x in vecs)
        assert v <= lim.velocity * (1 + 1e-9)
        assert a <= lim.acceleration * (1 + 1e-9)
        assert j <= lim.jerk * (1 + 1e-9)
    assert np.array_equal(smp.position[-1], [0.1, 0.2, 0.5])
    np.testing.assert_allclose(quat.to_matrix(smp.quaternion[-1]),
                               np.asarray(END, float)[:3, :3], atol=1e-15)
    s, *_ = rk.translation.evaluate(t)
    phi, *_ = rk.rotation.evaluate(t)
    assert np.all(np.diff(s) >= -1e-15) and np.all(np.diff(phi) >= -1e-15)   # no backing up
    assert s[-1] == trig.geometry.distance and phi[-1] == trig.geometry.angle


def test_zero_translation_or_rotation():
    for end in (START, [[0, -1, 0, 0.3], [1, 0, 0, 0.0], [0, 0, 1, 0.4], [0, 0, 0, 1]]):
        trig = plan_line(START, end, LIMITS)
        rk = plan_line_ruckig(trig)
        assert rk.translation_time == 0.0
        smp = rk.sample(sample_times(rk.duration, 0.01))
        assert np.all(np.isfinite(smp.table()))
        assert np.all(smp.velocity == 0)
        assert rk.duration <= trig.duration
