"""Trigonometric jerk-continuous line planner (seeds/002): closed forms, limits, geometry."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import cumulative_trapezoid
from scipy.spatial.transform import Rotation

from mrm_cosim.master import quaternion as quat
from mrm_cosim.master.trig_planner import (
    AxisLimits, LineLimits, TrigProfile, plan_line, pose_from_matrix, sample_times,
    trig_min_duration,
)
from mrm_cosim.errors import InputError

EXAMPLE_START = [[1, 0, 0, 0.3], [0, 1, 0, 0.0], [0, 0, 1, 0.4], [0, 0, 0, 1]]
EXAMPLE_END = [[0, -1, 0, 0.1], [1, 0, 0, 0.2], [0, 0, 1, 0.5], [0, 0, 0, 1]]
EXAMPLE_LIMITS = LineLimits(AxisLimits(1.0, 4.0, 40.0), AxisLimits(1.0, 4.0, 40.0))

# The paper's §V example, eqs. (19)-(20), positions in mm as printed.
PAPER_TS = [[0.500, -0.866, 0, 671.170], [0.866, 0.500, 0, 387.500], [0, 0, 1, 570],
            [0, 0, 0, 1]]
PAPER_TE = [[-0.085, -0.912, -0.401, -623.717], [0.753, -0.322, 0.573, 312.221],
            [-0.652, -0.253, 0.715, 504.095], [0, 0, 0, 1]]
PAPER_LIMITS = LineLimits(AxisLimits(2.0, 8.0, 60.0), AxisLimits(2.0, 8.0, 60.0))


def in_metres(T):
    return [[*row[:3], row[3] / 1000.0] for row in T[:3]] + [T[3]]


def pose(R, p):
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = p
    return M


# ------------------------------------------------------------------ the 1-D profile


@pytest.mark.parametrize("L, T", [(1.0, 1.0), (0.3, 0.77), (2.878835, 2.878835), (1e-6, 0.01)])
def test_profile_hits_the_closed_forms(L, T):
    """Eqs. (11)-(13) at the instants they name: s(T) = AT²/8, v(T/2) = AT/4, a(T/4) = A,
    j(T/8) = 2πA/T; and dense sampling never exceeds them."""
    p = TrigProfile(L, T)
    A = p.amplitude
    assert A == pytest.approx(8 * L / T**2, rel=1e-15)
    s, v, a, j = p.evaluate([T / 8, T / 4, T / 2, T])
    assert s[3] == L
    assert v[2] == pytest.approx(A * T / 4, rel=1e-14)
    assert a[1] == pytest.approx(A, rel=1e-14)
    assert j[0] == pytest.approx(2 * math.pi * A / T, rel=1e-14)
    assert s[2] == pytest.approx(L / 2, rel=1e-14)
    t = np.linspace(0, T, 8001)
    s, v, a, j = p.evaluate(t)
    for x, peak in ((v, p.peak_velocity), (np.abs(a), p.peak_acceleration),
                    (np.abs(j), p.peak_jerk)):
        assert np.max(x) <= peak * (1 + 1e-12)
        assert np.max(x) >= peak * (1 - 1e-6)
    assert np.all(np.diff(s) >= 0)


def test_profile_integrates_consistently():
    """Integrating the sampled jerk three times (trapezoid) gives back a, v, s."""
    p = TrigProfile(0.8, 1.3)
    t = np.linspace(0, 1.3, 20001)
    s, v, a, j = p.evaluate(t)
    np.testing.assert_allclose(cumulative_trapezoid(j, t, initial=0), a, atol=1e-6)
    np.testing.assert_allclose(cumulative_trapezoid(a, t, initial=0), v, atol=1e-7)
    np.testing.assert_allclose(cumulative_trapezoid(v, t, initial=0), s, atol=1e-7)


def test_jerk_is_continuous_everywhere():
    """|Δj| between samples is bounded by max|snap|·dt (snap = A ω²/2), including at 0, T/2
    and T where the pieces meet; a jump would break the bound."""
    p = TrigProfile(1.0, 1.0)
    w = 4 * math.pi / p.duration
    snap_max = p.amplitude * w * w / 2
    dt = 1e-5
    t = np.arange(-0.1, 1.1, dt)
    _, _, a, j = p.evaluate(t)
    assert np.max(np.abs(np.diff(j))) <= snap_max * dt * (1 + 1e-6)
    assert np.max(np.abs(np.diff(a))) <= p.peak_jerk * dt * (1 + 1e-6)


@settings(max_examples=60, deadline=None)
@given(L=st.floats(1e-4, 10), v=st.floats(0.05, 5), a=st.floats(0.05, 20),
       j=st.floats(0.5, 500))
def test_min_duration_respects_all_limits_and_binds_one(L, v, a, j):
    lim = AxisLimits(v, a, j)
    T = trig_min_duration(L, lim)
    p = TrigProfile(L, T)
    ratios = [p.peak_velocity / v, p.peak_acceleration / a, p.peak_jerk / j]
    assert max(ratios) == pytest.approx(1.0, rel=1e-12)
    assert all(r <= 1 + 1e-12 for r in ratios)
    _, sv, sa, sj = p.evaluate(np.linspace(0, T, 1601))
    assert np.max(sv) <= v * (1 + 1e-12)
    assert np.max(np.abs(sa)) <= a * (1 + 1e-12)
    assert np.max(np.abs(sj)) <= j * (1 + 1e-12)


def test_zero_length_profile():
    assert trig_min_duration(0.0, AxisLimits(1, 1, 1)) == 0.0
    p = TrigProfile(0.0, 0.0)
    assert all(np.all(x == 0) for x in p.evaluate([0.0, 1.0]))
    p = TrigProfile(0.0, 2.0)
    assert p.amplitude == 0.0 and all(np.all(x == 0) for x in p.evaluate([0.5, 1.0]))
    with pytest.raises(InputError):
        TrigProfile(1.0, 0.0)


# ------------------------------------------------------------------ the paper's example


def test_paper_example_distance_and_timing_law():
    """§V: D ≈ 1298.747 mm from (5); with the paper's θ = 2878.835 mrad, eqs. (15)-(17) give
    T ≈ 2.878835 s, A_D ≈ 1.254 m/s², A_θ ≈ 2.779 rad/s²."""
    p_s, _, _ = pose_from_matrix(in_metres(PAPER_TS), "start.pose")
    p_e, _, _ = pose_from_matrix(in_metres(PAPER_TE), "end.pose")
    D = float(np.linalg.norm(p_e - p_s))
    assert D * 1000 == pytest.approx(1298.747, abs=5e-4)
    theta_paper = 2.878835
    T = max(trig_min_duration(D, PAPER_LIMITS.translation),
            trig_min_duration(theta_paper, PAPER_LIMITS.rotation))
    assert T == pytest.approx(2.878835, abs=5e-7)        # 2θ/V_r binds
    assert TrigProfile(D, T).amplitude == pytest.approx(1.254, abs=5e-4)
    assert TrigProfile(theta_paper, T).amplitude == pytest.approx(2.779, abs=5e-4)


def test_paper_rotation_angle_is_not_the_angle_between_the_printed_poses():
    """The angle between T_s and T_e as printed is 1.0738 rad, by eq. (10) with |q1·q2| and
    by the relative rotation matrix alike. The paper's 2.878835 rad is, to the 3-decimal
    rounding of the printed matrices, eq. (10) evaluated with q1's vector part negated,
    which is the angle of R_s·R_e instead of R_sᵀ·R_e. See docs/trajectories.md."""
    plan = plan_line(in_metres(PAPER_TS), in_metres(PAPER_TE), PAPER_LIMITS)
    _, R_s, _ = pose_from_matrix(in_metres(PAPER_TS), "start.pose")
    _, R_e, _ = pose_from_matrix(in_metres(PAPER_TE), "end.pose")
    true_angle = Rotation.from_matrix(R_s.T @ R_e).magnitude()
    assert plan.geometry.angle == pytest.approx(true_angle, abs=1e-12)
    assert plan.geometry.angle == pytest.approx(1.07384, abs=1e-5)
    q1, q2 = quat.from_matrix(R_s), quat.from_matrix(R_e)
    wrong = 2 * math.acos(abs(quat.conjugate(q1) @ q2))
    assert wrong == pytest.approx(2.878835, abs=1e-3)
    assert Rotation.from_matrix(R_s @ R_e).magnitude() == pytest.approx(wrong, abs=1e-12)


def test_paper_example_planned_from_the_printed_poses():
    """Our plan of the printed poses: translation binds (T = 2D/V_t), both parts within
    limits, and a note that T_s and T_e were projected onto SO(3)."""
    plan = plan_line(in_metres(PAPER_TS), in_metres(PAPER_TE), PAPER_LIMITS)
    D = plan.geometry.distance
    assert plan.duration == pytest.approx(2 * D / 2.0, rel=1e-15)
    assert plan.translation_time == plan.duration
    assert plan.rotation_time < plan.duration
    assert plan.translation.amplitude == pytest.approx(2 * 2.0**2 / D, rel=1e-14)   # 6.160
    assert plan.rotation.amplitude == pytest.approx(8 * plan.geometry.angle / plan.duration**2)
    assert plan.rotation.peak_velocity < 2.0 and plan.rotation.peak_jerk < 60.0
    assert len(plan.notes) == 2 and "start.pose" in plan.notes[0] and "end.pose" in plan.notes[1]


# ------------------------------------------------------------------ Cartesian samples


def test_end_points_are_exact():
    plan = plan_line(EXAMPLE_START, EXAMPLE_END, EXAMPLE_LIMITS)
    t = sample_times(plan.duration, 0.001)
    assert t[-1] >= plan.duration and t[-2] < plan.duration
    smp = plan.sample(t)
    assert np.array_equal(smp.position[0], [0.3, 0.0, 0.4])
    assert np.array_equal(smp.position[-1], [0.1, 0.2, 0.5])
    np.testing.assert_allclose(quat.to_matrix(smp.quaternion[-1]),
                               np.asarray(EXAMPLE_END, float)[:3, :3], atol=1e-15)
    assert np.array_equal(smp.quaternion[-1], plan.geometry.q_end)
    assert np.array_equal(smp.quaternion[0], [1.0, 0, 0, 0])
    for x in (smp.velocity, smp.acceleration, smp.jerk, smp.angular_velocity,
              smp.angular_acceleration, smp.angular_jerk):
        assert np.all(x[[0, -1]] == 0)


def test_path_is_straight_and_synchronized():
    plan = plan_line(EXAMPLE_START, EXAMPLE_END, EXAMPLE_LIMITS)
    smp = plan.sample(np.linspace(0, plan.duration, 501))
    g = plan.geometry
    k_trans = (smp.position - g.p_start) @ g.direction / g.distance
    off_line = smp.position - g.p_start - np.outer(k_trans * g.distance, g.direction)
    assert np.max(np.abs(off_line)) < 1e-15
    k_rot = np.array([quat.rotation_angle(g.q_start, q) for q in smp.quaternion]) / g.angle
    np.testing.assert_allclose(k_trans, k_rot, atol=1e-12)   # same normalized profile


def test_sampled_peaks_equal_formulas_and_respect_limits():
    plan = plan_line(EXAMPLE_START, EXAMPLE_END, EXAMPLE_LIMITS)
    smp = plan.sample(np.linspace(0, plan.duration, 8001))
    for vec, prof, lim in (
            ((smp.velocity, smp.acceleration, smp.jerk), plan.translation,
             EXAMPLE_LIMITS.translation),
            ((smp.angular_velocity, smp.angular_acceleration, smp.angular_jerk), plan.rotation,
             EXAMPLE_LIMITS.rotation)):
        peaks = [np.max(np.linalg.norm(x, axis=1)) for x in vec]
        formulas = [prof.peak_velocity, prof.peak_acceleration, prof.peak_jerk]
        np.testing.assert_allclose(peaks, formulas, rtol=1e-6)
        assert peaks[0] <= lim.velocity * (1 + 1e-12)
        assert peaks[1] <= lim.acceleration * (1 + 1e-12)
        assert peaks[2] <= lim.jerk * (1 + 1e-12)


def test_velocities_match_finite_differences_of_the_pose():
    """ω from central differences of the sampled quaternion (ω = 2 vec(q̇ q*)) and v from
    differences of the position agree with the planner's analytic values."""
    rng = np.random.default_rng(0)
    R0, R1 = Rotation.random(2, random_state=rng).as_matrix()
    plan = plan_line(pose(R0, [0.1, 0.2, 0.3]), pose(R1, [0.5, -0.1, 0.4]), EXAMPLE_LIMITS)
    h = 1e-6
    t = np.linspace(0.01, plan.duration - 0.01, 37)
    mid, plus, minus = plan.sample(t), plan.sample(t + h), plan.sample(t - h)
    q_dot = (plus.quaternion - minus.quaternion) / (2 * h)
    omega = quat.angular_velocity(mid.quaternion, q_dot)
    np.testing.assert_allclose(omega, mid.angular_velocity, atol=1e-7)
    np.testing.assert_allclose((plus.position - minus.position) / (2 * h), mid.velocity,
                               atol=1e-8)
    np.testing.assert_allclose((plus.angular_velocity - minus.angular_velocity) / (2 * h),
                               mid.angular_acceleration, atol=1e-6)


def test_shortest_path_across_the_sign_flip():
    """Rz(170°) → Rz(−170°) turns 20° through 180°, not 340° back through 0°."""
    Rs = Rotation.from_euler("z", 170, degrees=True).as_matrix()
    Re = Rotation.from_euler("z", -170, degrees=True).as_matrix()
    plan = plan_line(pose(Rs, [0, 0, 0]), pose(Re, [0, 0, 0]), EXAMPLE_LIMITS)
    assert plan.geometry.angle == pytest.approx(math.radians(20), abs=1e-12)
    smp = plan.sample(np.linspace(0, plan.duration, 11))
    yaw = Rotation.from_matrix(quat.to_matrix(smp.quaternion)).as_euler("zyx")[:, 0]
    assert np.all(np.abs(yaw) >= math.radians(170) - 1e-9)   # stays near ±180°


@pytest.mark.parametrize("end, moves", [
    ([[1, 0, 0, 0.3], [0, 1, 0, 0.0], [0, 0, 1, 0.4], [0, 0, 0, 1]], (False, False)),
    ([[1, 0, 0, 0.5], [0, 1, 0, 0.0], [0, 0, 1, 0.4], [0, 0, 0, 1]], (True, False)),
    ([[0, -1, 0, 0.3], [1, 0, 0, 0.0], [0, 0, 1, 0.4], [0, 0, 0, 1]], (False, True)),
])
def test_zero_distance_or_zero_rotation(end, moves):
    plan = plan_line(EXAMPLE_START, end, EXAMPLE_LIMITS)
    assert (plan.translation_time > 0, plan.rotation_time > 0) == moves
    smp = plan.sample(sample_times(plan.duration, 0.01))
    assert np.all(np.isfinite(smp.table()))
    assert np.array_equal(smp.position[-1], np.asarray(end, float)[:3, 3])
    np.testing.assert_allclose(quat.to_matrix(smp.quaternion[-1]),
                               np.asarray(end, float)[:3, :3], atol=1e-15)
    if not moves[0]:
        assert np.all(smp.velocity == 0) and np.all(smp.position == smp.position[0])
    if not moves[1]:
        assert np.all(smp.angular_velocity == 0)
        assert np.all(smp.quaternion == smp.quaternion[0])


# ------------------------------------------------------------------ input validation


def test_nearly_orthonormal_block_is_projected_with_a_note():
    R = np.round(Rotation.from_euler("xyz", [0.3, -0.2, 1.1]).as_matrix(), 3)
    p, Rp, notes = pose_from_matrix(pose(R, [1, 2, 3]), "end.pose")
    assert len(notes) == 1 and "end.pose" in notes[0] and "projected" in notes[0]
    assert quat.orthonormality_error(Rp) < 1e-14
    assert np.max(np.abs(Rp - R)) < 1e-3
    _, _, notes = pose_from_matrix(pose(Rotation.from_euler("z", 0.3).as_matrix(), [0, 0, 0]),
                                   "start.pose")
    assert notes == []


@pytest.mark.parametrize("matrix, field, words", [
    (np.diag([1.0, 1.0, -1.0, 1.0]), "end.pose", "det"),                 # reflection
    (np.diag([1.0, 1.0, 0.0, 1.0]), "end.pose", "det"),                  # singular
    (np.diag([1.1, 1.0, 1.0, 1.0]), "end.pose", "orthonormal"),          # scaled: 0.21
    ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], "end.pose[3]", "[0, 0, 0, 1]"),
    ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]], "end.pose", "4x4"),
    ([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 0]], "end.pose[0]", "4 numbers"),
    ([[1, 0, 0, float("nan")], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "end.pose[0][3]",
     "finite"),
    ([[1, 0, 0, "0"], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "end.pose[0][3]", "number"),
    ([[True, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "end.pose[0][0]", "number"),
    ("identity", "end.pose", "4x4"),
])
def test_rejects_bad_poses(matrix, field, words):
    with pytest.raises(InputError) as exc:
        pose_from_matrix(matrix, "end.pose")
    assert exc.value.field == field
    assert words in exc.value.message


def test_orthonormality_tolerance_boundary():
    """‖RᵀR − I‖_F of diag(1+e, 1, 1) is 2e + e²: 0.0099 passes, 0.0101 fails (limit 0.02)."""
    pose_from_matrix(np.diag([1.0099, 1.0, 1.0, 1.0]), "start.pose")
    with pytest.raises(InputError):
        pose_from_matrix(np.diag([1.0101, 1.0, 1.0, 1.0]), "start.pose")


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), "1"])
def test_rejects_bad_limits(bad):
    with pytest.raises(InputError):
        AxisLimits(bad, 1.0, 1.0)


def test_rejects_bad_sample_step():
    for dt in (0.0, -1e-3, float("nan")):
        with pytest.raises(InputError) as exc:
            sample_times(1.0, dt)
        assert exc.value.field == "dt"
