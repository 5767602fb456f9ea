"""Spatial algebra and the 13-parameter rigid body against pinocchio (independent reference)."""

import numpy as np
import pinocchio as pin
import pytest

from mrm_cosim.models.spatial import (
    coriolis_matrix, force_to, gravity_in_frame, gravity_wrench, mass_matrix,
    physical_from_theta, regressor, rigid_body_wrench, skew, theta_from_physical,
    theta_to_pinocchio, transform_theta, transform_U, velocity_to,
)


def random_body(rng):
    m = rng.uniform(0.2, 5.0)
    c = rng.normal(scale=0.1, size=3)
    A = rng.normal(size=(3, 3))
    Ic = 0.01 * (A @ A.T) + 0.005 * np.eye(3)
    return m, c, Ic


def random_se3(rng):
    return pin.SE3(pin.exp3(rng.normal(size=3)), rng.normal(size=3))


@pytest.mark.parametrize("seed", range(5))
def test_theta_maps_to_pinocchio_dynamic_parameters(seed):
    rng = np.random.default_rng(seed)
    m, c, Ic = random_body(rng)
    theta = theta_from_physical(m, c, Ic)
    expected = pin.Inertia(m, c, Ic).toDynamicParameters()
    np.testing.assert_allclose(theta_to_pinocchio(theta), expected, rtol=0, atol=1e-15)


@pytest.mark.parametrize("seed", range(5))
def test_physical_round_trip(seed):
    m, c, Ic = random_body(np.random.default_rng(seed))
    m2, c2, Ic2 = physical_from_theta(theta_from_physical(m, c, Ic))
    assert m2 == pytest.approx(m)
    np.testing.assert_allclose(c2, c, atol=1e-15)
    np.testing.assert_allclose(Ic2, Ic, atol=1e-15)


@pytest.mark.parametrize("seed", range(10))
def test_regressor_equals_pinocchio_body_dynamics(seed):
    """Y θ = I a + V ×* I V with gravity entering as an upward acceleration (RNEA's a₀ = −g)."""
    rng = np.random.default_rng(seed)
    m, c, Ic = random_body(rng)
    theta = theta_from_physical(m, c, Ic)
    V, dV = rng.normal(size=6), rng.normal(size=6)
    R_world = pin.exp3(rng.normal(size=3))
    g_A = gravity_in_frame(R_world)
    a = dV.copy()
    a[:3] += R_world.T @ -np.array([0.0, 0.0, -9.81])
    expected = pin.bodyRegressor(pin.Motion(V), pin.Motion(a)) @ \
        pin.Inertia(m, c, Ic).toDynamicParameters()
    Y = regressor(V[3:], V, dV, g_A)
    np.testing.assert_allclose(Y @ theta, expected, atol=1e-12)
    np.testing.assert_allclose(rigid_body_wrench(theta, V[3:], V, dV, g_A), expected, atol=1e-12)
    lhs = mass_matrix(theta) @ dV + coriolis_matrix(theta, V[3:]) @ V + gravity_wrench(theta, g_A)
    np.testing.assert_allclose(lhs, expected, atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_coriolis_matrix_is_skew_symmetric_and_mass_matrix_matches(seed):
    rng = np.random.default_rng(seed)
    m, c, Ic = random_body(rng)
    theta = theta_from_physical(m, c, Ic)
    C = coriolis_matrix(theta, rng.normal(size=3))
    np.testing.assert_allclose(C, -C.T, atol=1e-15)
    np.testing.assert_allclose(mass_matrix(theta), pin.Inertia(m, c, Ic).matrix(), atol=1e-15)


def test_regressor_with_required_velocity_differs_from_actual_only_through_it():
    """Y(ω, V_r, ...) is linear in (V_r, dV_r) for fixed ω: superposition holds."""
    rng = np.random.default_rng(7)
    w = rng.normal(size=3)
    V1, V2, dV1, dV2 = (rng.normal(size=6) for _ in range(4))
    g = np.zeros(3)
    np.testing.assert_allclose(regressor(w, V1 + V2, dV1 + dV2, g),
                               regressor(w, V1, dV1, g) + regressor(w, V2, dV2, g), atol=1e-14)


@pytest.mark.parametrize("seed", range(5))
def test_velocity_and_force_transforms_match_pinocchio_action(seed):
    """ᴮV = ᴬU_Bᵀ ᴬV is pinocchio's actInv; ᴬF = ᴬU_B ᴮF is its act on forces."""
    rng = np.random.default_rng(seed)
    M = random_se3(rng)  # pose of B in A
    V_A = rng.normal(size=6)
    F_B = rng.normal(size=6)
    np.testing.assert_allclose(velocity_to(M.rotation, M.translation, V_A),
                               M.actInv(pin.Motion(V_A)).vector, atol=1e-14)
    np.testing.assert_allclose(force_to(M.rotation, M.translation, F_B),
                               M.act(pin.Force(F_B)).vector, atol=1e-14)
    # Power is frame-independent: (ᴬV)ᵀ ᴬF = (ᴮV)ᵀ ᴮF.
    V_B = velocity_to(M.rotation, M.translation, V_A)
    assert V_A @ force_to(M.rotation, M.translation, F_B) == pytest.approx(V_B @ F_B)
    np.testing.assert_allclose(transform_U(M.rotation, M.translation), M.toDualActionMatrix(),
                               atol=1e-14)


@pytest.mark.parametrize("seed", range(5))
def test_transform_theta_matches_pinocchio_se3_action_on_inertia(seed):
    rng = np.random.default_rng(seed)
    m, c, Ic = random_body(rng)
    M = random_se3(rng)
    theta_A = transform_theta(theta_from_physical(m, c, Ic), M.rotation, M.translation)
    expected = M.act(pin.Inertia(m, c, Ic)).toDynamicParameters()
    np.testing.assert_allclose(theta_to_pinocchio(theta_A), expected, atol=1e-14)


def test_skew_is_cross_product():
    a, b = np.array([1.0, -2.0, 3.0]), np.array([0.5, 4.0, -1.0])
    np.testing.assert_array_equal(skew(a) @ b, np.cross(a, b))


def test_rejects_non_positive_mass():
    with pytest.raises(ValueError, match="mass must be positive"):
        physical_from_theta(np.zeros(13))
