"""Drive models: Stribeck friction curve, current loop, spring, and the stick-slip step solver."""

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from mrm_cosim.models.drive import (
    CurrentLoop, FrictionParams, solve_stick_slip, solve_stick_slip_bruteforce, spring_energy,
    spring_torque,
)
from mrm_cosim.models.modules import SpringSpec

FR = FrictionParams(coulomb=[0.5, 1.0], static=[0.7, 1.4], stribeck_velocity=[0.01, 0.02],
                    viscous=[0.08, 0.16])


def _stribeck_slope_plus_b(v, fc, fs, vs, b):
    """−d/dv of the Stribeck term minus b: zero at the minimum of the friction curve."""
    return 2.0 * v * (fs - fc) / vs**2 * math.exp(-(v / vs) ** 2) - b


def test_friction_level_limits():
    assert np.array_equal(FR.level(np.zeros(2)), FR.static)
    np.testing.assert_allclose(FR.level(np.full(2, 10.0)), FR.coulomb, rtol=0, atol=1e-15)
    # at v = v_s the Stribeck excess has fallen to 1/e
    np.testing.assert_allclose(FR.level(FR.stribeck_velocity),
                               FR.coulomb + (FR.static - FR.coulomb) / math.e, rtol=1e-15)


def test_stribeck_curve_closed_form_and_shape():
    v = np.geomspace(1e-4, 5.0, 400)
    for j in range(2):
        fc, fs, vs, b = (FR.coulomb[j], FR.static[j], FR.stribeck_velocity[j], FR.viscous[j])
        expected = fc + (fs - fc) * np.exp(-(v / vs) ** 2) + b * v
        vv = np.zeros((v.size, 2))
        vv[:, j] = v
        got = np.array([FR.sliding(row)[j] for row in vv])
        np.testing.assert_allclose(got, expected, rtol=1e-14)
        # odd in v
        np.testing.assert_allclose([FR.sliding(-row)[j] for row in vv], -expected, rtol=1e-14)
        # falls from F_s towards F_c (Stribeck), then rises with b v: one interior minimum
        dmin = np.argmin(got)
        assert 0 < dmin < v.size - 1
        assert np.all(np.diff(got[: dmin + 1]) < 0.0)
        assert np.all(np.diff(got[dmin:]) > 0.0)
        # the minimum sits where the Stribeck slope equals −b
        v_min = brentq(_stribeck_slope_plus_b, vs / math.sqrt(2.0), 20.0 * vs,
                       args=(fc, fs, vs, b))
        assert v[dmin - 1] <= v_min <= v[dmin + 1]
    assert np.array_equal(FR.sliding(np.zeros(2)), np.zeros(2))


def test_friction_rejects_bad_parameters():
    with pytest.raises(ValueError):
        FrictionParams([1.0], [0.5], [0.01], [0.0])          # static below Coulomb
    with pytest.raises(ValueError):
        FrictionParams([1.0], [1.5], [0.0], [0.0])           # zero Stribeck velocity


def test_current_loop_step_response_63_percent_at_time_constant():
    T, dt = 1e-4, 1e-5
    loop = CurrentLoop([T, T], [11.0, 28.0], dt)
    tau = np.zeros(2)
    mean = np.zeros(2)
    u = np.array([2.0, -5.0])
    history = []
    for _ in range(30):
        loop.advance(tau, u, mean)
        history.append((tau.copy(), mean.copy()))
    at_T = history[9][0]                                     # after 10 steps = T
    np.testing.assert_allclose(at_T, u * (1.0 - math.exp(-1.0)), rtol=1e-13)
    np.testing.assert_allclose(at_T / u, 0.6321205588285577, rtol=1e-13)
    # the mean over each step is the exact integral of the exponential
    for k, (_, m) in enumerate(history):
        t0, t1 = k * dt, (k + 1) * dt
        integral = u * (dt - T * (math.exp(-t0 / T) - math.exp(-t1 / T)))
        np.testing.assert_allclose(m, integral / dt, rtol=1e-12)


def test_current_loop_saturates_at_peak_torque():
    loop = CurrentLoop([1.5e-4, 1.5e-4], [11.0, 28.0], 1e-5)
    tau = np.zeros(2)
    mean = np.zeros(2)
    for _ in range(2000):
        loop.advance(tau, np.array([500.0, -500.0]), mean)
        assert np.all(np.abs(tau) <= [11.0, 28.0])
        assert np.all(np.abs(mean) <= [11.0, 28.0])
    np.testing.assert_allclose(tau, [11.0, -28.0], rtol=1e-14)


def test_ideal_current_loop_is_a_clipped_torque_source():
    loop = CurrentLoop([0.0, 0.0], [11.0, 28.0], 1e-5)
    tau = np.array([3.0, 3.0])
    mean = np.zeros(2)
    loop.advance(tau, np.array([-4.0, 40.0]), mean)
    assert np.array_equal(tau, [-4.0, 28.0]) and np.array_equal(mean, [-4.0, 28.0])


def test_spring_torque_is_minus_gradient_of_energy():
    rng = np.random.default_rng(0)
    q = rng.uniform(-3, 3, size=5)
    amp = rng.uniform(-11, 11, size=5)
    phase = rng.uniform(-1, 1, size=5)
    eps = 1e-6
    fd = -(spring_energy(q + eps, amp, phase) - spring_energy(q - eps, amp, phase)) / (2 * eps)
    np.testing.assert_allclose(spring_torque(q, amp, phase), fd, rtol=1e-8, atol=1e-9)
    # the robot description's own formula
    for i in range(5):
        assert spring_torque(q[i], amp[i], phase[i]) == pytest.approx(
            SpringSpec(amp[i], phase[i]).torque_at(q[i]), rel=1e-15)


def _random_problem(rng, n):
    A = rng.normal(size=(n, n))
    M = A @ A.T + 0.05 * np.eye(n)
    v = rng.normal(size=n) * (rng.random(n) < 0.5)
    rhs = rng.normal(size=n)
    limit = rng.uniform(0.0, 2.0, size=n) * (rng.random(n) < 0.9)
    return M, rhs, v, limit


@pytest.mark.parametrize("max_pivots", [None, 0])      # 0: the coordinate-descent fallback
def test_stick_slip_matches_exhaustive_search(max_pivots):
    rng = np.random.default_rng(1)
    stuck_seen = 0
    for _ in range(250):
        n = int(rng.integers(1, 6))
        M, rhs, v, limit = _random_problem(rng, n)
        w, pattern = solve_stick_slip(M, rhs, v, limit, max_pivots=max_pivots)
        ref = solve_stick_slip_bruteforce(M, rhs, v, limit)
        np.testing.assert_allclose(w, ref, rtol=1e-9, atol=1e-12)
        assert np.array_equal(w == 0.0, ref == 0.0)
        assert np.array_equal(pattern, np.sign(w))
        stuck_seen += int(np.sum(w == 0.0))
        # the friction law holds: the impulse friction needs is inside its bound
        hold = rhs - M @ (w - v)
        stuck = w == 0.0
        assert np.all(np.abs(hold[stuck]) <= limit[stuck] * (1 + 1e-9))
        np.testing.assert_allclose(hold[~stuck], (limit * np.sign(w))[~stuck], atol=1e-9)
    assert stuck_seen > 60


def test_single_joint_closed_form():
    m, h = 0.08, 1e-5
    fs = 0.7
    for v0, torque, stuck in [(0.0, 0.69, True), (0.0, -0.69, True), (0.0, 0.71, False),
                              (1e-6, -0.5, True), (0.3, 0.0, False), (-2e-5, 0.0, True)]:
        w, _ = solve_stick_slip(np.array([[m]]), np.array([h * torque]), np.array([v0]),
                                np.array([h * fs]))
        if stuck:
            assert w[0] == 0.0
        else:
            s = np.sign(v0) if v0 != 0.0 else np.sign(torque)
            assert w[0] == pytest.approx(v0 + h * (torque - fs * s) / m, rel=1e-12)
