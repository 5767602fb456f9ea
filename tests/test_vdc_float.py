"""Float VDC of one module (hdl/node/vdc_float_ref.py) against pinocchio and closed forms."""

import numpy as np
import pinocchio as pin
import pytest

from mrm_cosim.hdl.node.vdc_float_ref import (
    ModuleGains, ModuleVDC, adaptation_signal, link_a_acceleration, link_a_velocity,
    link_regressor, projection_update, required_net_force, rz,
)
from mrm_cosim.models.robot import load_robot, robot_from_dict
from mrm_cosim.models.spatial import regressor, rigid_body_wrench, theta_to_pinocchio, transform_U

G0 = 9.81


def _random_theta(rng):
    m = rng.uniform(0.3, 4.0)
    c = rng.uniform(-0.1, 0.1, 3)
    A = rng.normal(size=(3, 3)) * 0.03
    Ic = A @ A.T + 1e-4 * np.eye(3)
    return np.array([m, *(m * c), m * c[0]**2, m * c[1]**2, m * c[2]**2,
                     m * c[0] * c[1] - Ic[0, 1], m * c[0] * c[2] - Ic[0, 2],
                     m * c[1] * c[2] - Ic[1, 2], Ic[0, 0], Ic[1, 1], Ic[2, 2]])


def test_regressor_matches_pinocchio_body_regressor():
    rng = np.random.default_rng(0)
    for _ in range(50):
        theta = _random_theta(rng)
        V = rng.normal(size=6)
        dV = rng.normal(size=6) * 3.0
        g = rng.normal(size=3) * 5.0
        ours = regressor(V[3:], V, dV, g) @ theta
        # Pinocchio: f = I a + v ×* I v with gravity as an upward acceleration of the frame.
        a = dV + np.concatenate([g, np.zeros(3)])
        theirs = pin.bodyRegressor(pin.Motion(V), pin.Motion(a)) @ theta_to_pinocchio(theta)
        np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12)


def test_fast_regressor_is_the_spatial_one():
    rng = np.random.default_rng(6)
    for _ in range(30):
        w, g = rng.normal(size=(2, 3))
        V_r, dV_r = rng.normal(size=(2, 6))
        np.testing.assert_allclose(link_regressor(w, V_r, dV_r, g), regressor(w, V_r, dV_r, g),
                                   rtol=1e-13, atol=1e-13)


def test_net_force_is_regressor_plus_velocity_feedback():
    rng = np.random.default_rng(1)
    theta = _random_theta(rng)
    V, V_r, dV_r = rng.normal(size=(3, 6))
    g = rng.normal(size=3)
    K = rng.uniform(1.0, 50.0, 6)
    F = required_net_force(theta, V, V_r, dV_r, g, K)
    np.testing.assert_allclose(F, rigid_body_wrench(theta, V[3:], V_r, dV_r, g) + K * (V_r - V),
                               rtol=1e-13, atol=1e-13)
    s = adaptation_signal(V, V_r, dV_r, g)
    np.testing.assert_allclose(s, regressor(V[3:], V_r, dV_r, g).T @ (V_r - V), atol=1e-13)


def _frames(model, robot):
    ids = []
    for k in range(robot.n):
        ids.append((model.getFrameId(f"link{k + 1}b"), model.getFrameId(f"link{k + 1}a")))
    return ids


def _robot(name):
    from .test_vdc_master import ODD

    return robot_from_dict(ODD) if name == "odd" else load_robot(name)


@pytest.mark.parametrize("name", ["mrm3", "mrm6", "odd"])
def test_velocity_mapping_and_acceleration_match_pinocchio(name):
    robot = _robot(name)
    model = robot.pinocchio_model()
    data = model.createData()
    rng = np.random.default_rng(2)
    for _ in range(10):
        q = rng.uniform(-2.0, 2.0, robot.n)
        v = rng.normal(size=robot.n)
        a = rng.normal(size=robot.n) * 3.0
        pin.forwardKinematics(model, data, q, v, a)
        pin.updateFramePlacements(model, data)
        for k, (fc, fa) in enumerate(_frames(model, robot)):
            V_C = pin.getFrameVelocity(model, data, fc, pin.LOCAL).vector
            dV_C = pin.getFrameAcceleration(model, data, fc, pin.LOCAL).vector
            V_A = pin.getFrameVelocity(model, data, fa, pin.LOCAL).vector
            dV_A = pin.getFrameAcceleration(model, data, fa, pin.LOCAL).vector
            np.testing.assert_allclose(link_a_velocity(q[k], v[k], V_C), V_A, atol=1e-12)
            np.testing.assert_allclose(link_a_acceleration(q[k], v[k], a[k], V_C, dV_C), dV_A,
                                       atol=1e-11)


@pytest.mark.parametrize("name", ["mrm3", "mrm6", "odd"])
def test_link_forces_propagated_give_rnea(name):
    """With V_r = V, exact accelerations and true parameters, the links' required net forces,
    propagated tip → base and projected on each joint, are pinocchio's RNEA torques."""
    robot = _robot(name)
    model = robot.pinocchio_model()
    data = model.createData()
    theta = robot.nominal_theta
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(-2.0, 2.0, robot.n)
        v = rng.normal(size=robot.n)
        a = rng.normal(size=robot.n) * 3.0
        tau_ref = pin.rnea(model, data, q, v, a)
        pin.forwardKinematics(model, data, q, v, a)
        pin.updateFramePlacements(model, data)
        frames = robot.link_frames(q)
        zero_K = np.zeros(6)
        links = []
        for k, (fc, _fa) in enumerate(_frames(model, robot)):
            V_C = pin.getFrameVelocity(model, data, fc, pin.LOCAL).vector
            dV_C = pin.getFrameAcceleration(model, data, fc, pin.LOCAL).vector
            g_C = frames[k][0][:3, :3].T @ np.array([0.0, 0.0, G0])
            V_A = link_a_velocity(q[k], v[k], V_C)
            dV_A = link_a_acceleration(q[k], v[k], a[k], V_C, dV_C)
            g_A = rz(q[k]).T @ g_C
            F_a = required_net_force(theta[k, 0], V_A, V_A, dV_A, g_A, zero_K)
            F_b = required_net_force(theta[k, 1], V_C, V_C, dV_C, g_C, zero_K)
            links.append((F_a, F_b))
        tau = np.zeros(robot.n)
        F_next_C = np.zeros(6)  # force that module k+1's {C} needs, expressed in that {C}
        for k in reversed(range(robot.n)):
            F_A = links[k][0].copy()
            if k + 1 < robot.n:
                T = robot.mount_transform(k + 1)  # pose of {C_k+1} in {A_k}
                F_A += transform_U(T[:3, :3], T[:3, 3]) @ F_next_C
            tau[k] = F_A[5]
            R = rz(q[k])
            F_C = links[k][1] + transform_U(R, np.zeros(3)) @ F_A
            F_next_C = F_C
        np.testing.assert_allclose(tau, tau_ref, rtol=1e-10, atol=1e-10)


def test_projection_function_cases():
    lower = np.array([1.0, 1.0, 1.0, 1.0, 1.0])
    upper = np.array([2.0, 2.0, 2.0, 2.0, 2.0])
    theta = np.array([1.0, 1.0, 2.0, 1.5, 0.5])
    s = np.array([-3.0, 3.0, 3.0, 100.0, -1.0])
    rho_T = np.full(5, 0.1)
    out = projection_update(theta, s, rho_T, lower, upper)
    # at the lower bound pushing down: frozen; pushing up: moves; at the upper pushing up:
    # frozen; a big step is clipped; below the bound pushing down: frozen where it is.
    np.testing.assert_allclose(out, [1.0, 1.3, 2.0, 2.0, 0.5])


def test_backward_difference_converges_to_exact_acceleration():
    """The node's derived accelerations approach the exact ones as the period shrinks (lag of
    half a period), for a smooth motion of {C} and of the joint."""
    rng = np.random.default_rng(4)
    theta = np.array([_random_theta(rng), _random_theta(rng)])
    w = rng.uniform(1.0, 3.0, 6)
    ph = rng.uniform(0, 2 * np.pi, 6)

    def V_C(t):
        return 0.3 * np.sin(w * t + ph)

    def dV_C(t):
        return 0.3 * w * np.cos(w * t + ph)

    def joint(t):
        return 0.2 * np.sin(2.0 * t), 0.4 * np.cos(2.0 * t), -0.8 * np.sin(2.0 * t)

    g_C = np.array([0.0, 3.0, 9.0])
    errors = []
    for T in (1e-3, 1e-4):
        vdc = ModuleVDC(theta, ModuleGains(K=np.zeros((2, 6))), period=T)
        t1 = 0.5
        for t in (t1 - T, t1):
            q, qd, _ = joint(t)
            F_a, F_b = vdc.step(q, qd, qd, V_C(t), V_C(t), g_C, adapt=False)
        q, qd, qdd = joint(t1)
        V_A = link_a_velocity(q, qd, V_C(t1))
        dV_A = link_a_acceleration(q, qd, qdd, V_C(t1), dV_C(t1))
        F_a_exact = required_net_force(theta[0], V_A, V_A, dV_A, rz(q).T @ g_C, np.zeros(6))
        F_b_exact = required_net_force(theta[1], V_C(t1), V_C(t1), dV_C(t1), g_C, np.zeros(6))
        errors.append(max(np.abs(F_a - F_a_exact).max(), np.abs(F_b - F_b_exact).max()))
    assert errors[0] < 1e-2
    assert errors[1] < errors[0] / 8.0  # first order in T


def test_first_period_has_zero_required_acceleration_and_adaptation_moves_theta():
    rng = np.random.default_rng(5)
    theta = np.array([_random_theta(rng), _random_theta(rng)])
    gains = ModuleGains(K=np.ones((2, 6)), rho=np.full((2, 13), 0.5),
                        lower=theta * 0.5 - 1.0, upper=theta * 1.5 + 1.0)
    vdc = ModuleVDC(theta.copy(), gains, period=1e-3)
    V_C, V_rC = rng.normal(size=(2, 6))
    g_C = np.array([0.0, 0.0, G0])
    F_a, F_b = vdc.step(0.3, 0.1, 0.2, V_C, V_rC, g_C)
    expect_b = required_net_force(theta[1], V_C, V_rC, np.zeros(6), g_C, np.ones(6))
    np.testing.assert_allclose(F_b, expect_b, atol=1e-12)
    s_b = adaptation_signal(V_C, V_rC, np.zeros(6), g_C)
    np.testing.assert_allclose(vdc.theta[1], theta[1] + 0.5e-3 * s_b, atol=1e-15)
