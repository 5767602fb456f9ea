"""Quintic point-to-point: closed-form peaks vs an independent polynomial reference."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.polynomial import Polynomial

from mrm_cosim.master.quintic import QuinticProfile, mrm_test_profile
from mrm_cosim.errors import InputError

DELTA = 0.1571   # the MRM paper's p_f − p_0, rad (20,000 encoder counts)


def reference(q0, qf, tf):
    """q(t) and its derivatives as numpy Polynomials in t (expanded, independent of the code)."""
    d = qf - q0
    q = Polynomial([q0, 0, 0, 10 * d / tf**3, -15 * d / tf**4, 6 * d / tf**5])
    return q, q.deriv(1), q.deriv(2), q.deriv(3)


def test_paper_trajectory_peaks_are_exact():
    p = QuinticProfile(0.0, DELTA, 1.0)
    assert p.peak_velocity[0] == pytest.approx(15 / 8 * DELTA, rel=1e-15)
    assert p.peak_velocity[0] == pytest.approx(0.2946, abs=1e-4)        # the paper's figure
    assert p.peak_acceleration[0] == pytest.approx(10 / math.sqrt(3) * DELTA, rel=1e-15)
    assert p.peak_acceleration[0] == pytest.approx(0.90702, abs=1e-5)
    assert p.peak_jerk[0] == pytest.approx(60 * DELTA, rel=1e-15)


def test_paper_printed_acceleration_is_the_value_at_a_quarter():
    """The paper's (45/8)Δ/tf² = 0.8837 is q̈(tf/4), not the maximum (10/√3)Δ/tf²."""
    p = QuinticProfile(0.0, DELTA, 1.0)
    _, _, qdd, _ = p.evaluate([0.25])
    assert qdd[0, 0] == pytest.approx(45 / 8 * DELTA, rel=1e-14)
    assert qdd[0, 0] == pytest.approx(0.8837, abs=1e-4)
    t_star = 0.5 - math.sqrt(3) / 6
    _, _, qdd_star, _ = p.evaluate([t_star])
    assert qdd_star[0, 0] == pytest.approx(p.peak_acceleration[0], rel=1e-14)
    assert qdd_star[0, 0] > qdd[0, 0] * 1.02


def test_peaks_are_where_the_reference_derivative_vanishes():
    """Peaks located by the roots of the next derivative of the reference polynomial."""
    q, qd, qdd, qddd = reference(0.0, DELTA, 1.0)
    for f, df, peak in ((qd, qdd, 15 / 8), (qdd, qddd, 10 / math.sqrt(3))):
        roots = df.roots()
        roots = roots[np.isreal(roots)].real
        inside = roots[(roots >= 0) & (roots <= 1)]
        candidates = np.concatenate([inside, [0.0, 1.0]])
        assert np.max(np.abs(f(candidates))) == pytest.approx(peak * DELTA, rel=1e-12)
    # jerk is a parabola: extremes at the ends (60Δ) and the vertex (−30Δ)
    assert np.max(np.abs(qddd(np.array([0.0, 0.5, 1.0])))) == pytest.approx(60 * DELTA)


@pytest.mark.parametrize("tf", [0.5, 1.0, 3.0])
def test_evaluator_matches_reference_for_many_joints(tf):
    rng = np.random.default_rng(0)
    q0 = rng.uniform(-2, 2, 6)
    qf = rng.uniform(-2, 2, 6)
    p = QuinticProfile(q0, qf, tf)
    t = np.sort(rng.uniform(0, tf, 400))
    out = p.evaluate(t)
    for j in range(6):
        ref = reference(q0[j], qf[j], tf)
        for k in range(4):
            np.testing.assert_allclose(out[k][:, j], ref[k](t), rtol=1e-11,
                                       atol=1e-12 * (1 + abs(qf[j] - q0[j]) / tf**k))
    assert out[0].shape == (400, 6)   # time-major


def test_rest_outside_and_exact_end_points():
    p = QuinticProfile([0.1, -0.2], [0.4, 0.3], 2.0)
    q, qd, qdd, qddd = p.evaluate([-1.0, 0.0, 2.0, 3.0])
    assert np.array_equal(q[0], p.q0) and np.array_equal(q[1], p.q0)
    assert np.array_equal(q[2], p.qf) and np.array_equal(q[3], p.qf)
    assert np.all(qd == 0) and np.all(qdd == 0)
    assert np.all(qddd[[0, 3]] == 0)
    np.testing.assert_allclose(qddd[1], p.peak_jerk * np.sign(p.delta), rtol=1e-15)


@settings(max_examples=40, deadline=None)
@given(delta=st.floats(-5, 5).filter(lambda d: abs(d) > 1e-3), tf=st.floats(0.05, 20))
def test_sampled_maxima_never_exceed_closed_form(delta, tf):
    p = QuinticProfile(0.0, delta, tf)
    t = np.linspace(0, tf, 2001)
    _, qd, qdd, qddd = p.evaluate(t)
    for sampled, exact in ((qd, p.peak_velocity), (qdd, p.peak_acceleration),
                           (qddd, p.peak_jerk)):
        m = np.max(np.abs(sampled))
        assert m <= exact[0] * (1 + 1e-12)
        assert m >= exact[0] * (1 - 1e-5)


def test_mrm_paper_joints_are_multiples():
    p = mrm_test_profile()
    assert p.n_dof == 3
    q, *_ = p.evaluate(np.linspace(0, 1, 11))
    np.testing.assert_allclose(q[:, 1], 2 * q[:, 0], rtol=1e-15)
    np.testing.assert_allclose(q[:, 2], 3 * q[:, 0], rtol=1e-15)
    np.testing.assert_allclose(p.peak_velocity, [0.2945625, 0.589125, 0.8836875], rtol=1e-15)


@pytest.mark.parametrize("kwargs, field", [
    ({"q0": 0, "qf": 1, "tf": 0}, "tf"),
    ({"q0": 0, "qf": 1, "tf": -1}, "tf"),
    ({"q0": 0, "qf": 1, "tf": float("nan")}, "tf"),
    ({"q0": float("nan"), "qf": 1, "tf": 1}, "q0"),
    ({"q0": 0, "qf": [1, float("inf")], "tf": 1}, "qf"),
    ({"q0": [0, 0, 0], "qf": [1, 2], "tf": 1}, "qf"),
    ({"q0": [[0, 1]], "qf": [[1, 2]], "tf": 1}, "q0"),
    ({"q0": 0, "qf": 1, "tf": 1e-300}, "tf"),            # peak jerk 6e901: not a float
    ({"q0": -1e308, "qf": 1e308, "tf": 1}, "qf"),        # qf − q0 overflows
])
def test_rejects_bad_input(kwargs, field):
    with pytest.raises(InputError) as exc:
        QuinticProfile(**kwargs)
    assert exc.value.field == field


def test_rejects_bad_times():
    p = QuinticProfile(0, 1, 1)
    with pytest.raises(InputError, match="t"):
        p.evaluate([0.1, float("nan")])


def test_at_is_evaluate_bit_for_bit():
    """The master's one-time path gives exactly :meth:`evaluate`'s floats."""
    import numpy as np
    from mrm_cosim.master.quintic import QuinticProfile
    p = QuinticProfile([0.1, -0.3, 0.7], [0.2571, 0.0142, 1.1713], 1.0)
    for t in [-0.5, 0.0, 1e-9] + [k * 1e-3 for k in range(1, 1001)] + [1.0, 1.0 + 1e-12, 3.0]:
        ref = p.evaluate(np.array([t]))
        for a, b in zip(p.at(t), ref, strict=True):
            assert a.tobytes() == b[0].tobytes(), t
