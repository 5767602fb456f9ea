"""Quaternion helpers (w, x, y, z) against scipy's Rotation and closed forms."""

import math

import numpy as np
import pytest
import scipy.linalg
from scipy.spatial.transform import Rotation, Slerp

from mrm_cosim.master import quaternion as quat


def random_rotations(n, seed=0):
    return Rotation.random(n, random_state=np.random.default_rng(seed))


def wxyz(rot):
    """scipy's scalar-last quaternion as (w, x, y, z)."""
    return np.roll(rot.as_quat(), 1, axis=-1)


def same_rotation(q1, q2, tol=1e-12):
    return min(np.max(np.abs(q1 - q2)), np.max(np.abs(q1 + q2))) < tol


def test_from_matrix_matches_scipy():
    for rot in random_rotations(200):
        q = quat.from_matrix(rot.as_matrix())
        assert q[0] >= 0
        assert same_rotation(q, wxyz(rot))


@pytest.mark.parametrize("axis", [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -2, 3]])
@pytest.mark.parametrize("angle", [math.pi, math.pi - 1e-9, 1e-12, 0.0])
def test_from_matrix_near_half_turn_and_identity(axis, angle):
    """Eq. (9) of the trig paper divides by 4s and fails at a half-turn; Shepperd does not."""
    rot = Rotation.from_rotvec(angle * np.asarray(axis) / np.linalg.norm(axis))
    q = quat.from_matrix(rot.as_matrix())
    np.testing.assert_allclose(np.linalg.norm(q), 1.0, rtol=1e-15)
    np.testing.assert_allclose(quat.to_matrix(q), rot.as_matrix(), atol=1e-15)


def test_to_matrix_round_trip_and_batch():
    rots = random_rotations(50, seed=1)
    np.testing.assert_allclose(quat.to_matrix(wxyz(rots)), rots.as_matrix(), atol=1e-15)


def test_hamilton_product_composes_rotations():
    a, b = random_rotations(2, seed=2)
    pq = quat.multiply(wxyz(a), wxyz(b))
    np.testing.assert_allclose(quat.to_matrix(pq), a.as_matrix() @ b.as_matrix(), atol=1e-15)
    np.testing.assert_allclose(quat.multiply(wxyz(a), quat.conjugate(wxyz(a))), [1, 0, 0, 0],
                               atol=1e-15)


def test_rotation_angle_is_shortest_and_sign_free():
    rots = random_rotations(100, seed=3)
    for a, b in zip(rots[:50], rots[50:], strict=True):
        expected = (a.inv() * b).magnitude()          # in [0, π]
        q1, q2 = wxyz(a), wxyz(b)
        assert quat.rotation_angle(q1, q2) == pytest.approx(expected, abs=1e-12)
        assert quat.rotation_angle(q1, -q2) == pytest.approx(expected, abs=1e-12)
        # The paper's eq. (10) without |·| gives 2π − θ whenever q1·q2 < 0:
        q2_far = -q2 if q1 @ q2 > 0 else q2
        naive = 2 * math.acos(np.clip(q1 @ q2_far, -1, 1))
        assert naive == pytest.approx(2 * math.pi - expected, abs=1e-7)


def test_relative_axis_is_in_base_frame():
    a, b = random_rotations(2, seed=4)
    axis, angle = quat.relative_axis_angle(wxyz(a), wxyz(b))
    R = Rotation.from_rotvec(angle * axis).as_matrix() @ a.as_matrix()
    np.testing.assert_allclose(R, b.as_matrix(), atol=1e-14)


def test_slerp_matches_scipy_and_hits_end_points_exactly():
    a, b = random_rotations(2, seed=5)
    q1, q2 = wxyz(a), wxyz(b)
    k = np.linspace(0, 1, 41)
    q = quat.slerp(q1, q2, k)
    ref = Slerp([0, 1], Rotation.concatenate([a, b]))(k)
    np.testing.assert_allclose(quat.to_matrix(q), ref.as_matrix(), atol=1e-14)
    assert np.array_equal(q[0], q1)
    end = q2 if q1 @ q2 >= 0 else -q2
    assert np.array_equal(q[-1], end)
    theta = quat.rotation_angle(q1, q2)
    for kk, qk in zip(k, q, strict=True):
        assert quat.rotation_angle(q1, qk) == pytest.approx(kk * theta, abs=1e-12)


def test_slerp_tiny_angle_is_finite():
    q1 = np.array([1.0, 0, 0, 0])
    q2 = quat.normalize([1.0, 1e-12, 0, 0])
    q = quat.slerp(q1, q2, [0.0, 0.5, 1.0])
    assert np.all(np.isfinite(q))
    np.testing.assert_allclose(q[1], quat.normalize([1.0, 0.5e-12, 0, 0]), atol=1e-16)


def test_projection_is_the_polar_factor():
    rng = np.random.default_rng(6)
    for rot in random_rotations(20, seed=7):
        M = rot.as_matrix() + rng.normal(scale=1e-3, size=(3, 3))
        R = quat.project_to_so3(M)
        U, _ = scipy.linalg.polar(M)                  # independent reference
        np.testing.assert_allclose(R, U, atol=1e-14)
        assert quat.orthonormality_error(R) < 1e-14
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)
    R0 = random_rotations(1, seed=8).as_matrix()[0]
    np.testing.assert_allclose(quat.project_to_so3(R0), R0, atol=1e-15)


def test_angular_velocity_of_constant_rate_rotation():
    rng = np.random.default_rng(9)
    omega = rng.normal(size=3)
    R0 = random_rotations(1, seed=10)[0]
    h = 1e-6
    t = 0.3
    def q_at(tt):
        return wxyz(Rotation.from_rotvec(omega * tt) * R0)   # base-frame ω
    q, qp, qm = q_at(t), q_at(t + h), q_at(t - h)
    qp = qp if qp @ q > 0 else -qp
    qm = qm if qm @ q > 0 else -qm
    np.testing.assert_allclose(quat.angular_velocity(q, (qp - qm) / (2 * h)), omega, atol=1e-8)
