"""The master's float VDC chain reproduces pinocchio's RNEA (frames and force bookkeeping)."""

import numpy as np
import pinocchio as pin
import pytest

from mrm_cosim.master.vdc import (
    inverse_dynamics, link_required_forces, propagate_forces, propagate_velocities,
)
from mrm_cosim.models.robot import BUILTIN_DIR, load_robot, robot_from_dict
from mrm_cosim.errors import InputError

#: An assembly unlike the built-in ones: a tilted and turned base, a tool pose with a rotation,
#: twists that are no multiple of 90°, a Type II first, a user type with its own lengths and
#: Link a, and a spring with a phase.
ODD = {"name": "odd", "base": {"xyz": [0.1, -0.2, 0.4], "rpy_deg": [25.0, -40.0, 70.0]},
       "tool": {"xyz": [0.03, -0.02, 0.05], "rpy_deg": [10.0, 20.0, -30.0]},
       "modules": [{"type": "II", "twist_deg": 33.0}, {"type": "Ix", "twist_deg": -61.0},
                   {"type": "I", "twist_deg": 120.0},
                   {"type": "II", "twist_deg": 90.0,
                    "spring": {"torque": 3.0, "phase_deg": 40.0}}],
       "module_types": {"Ix": {"like": "I", "length_a": 0.27, "length_b": 0.13,
                               "link_a": [1.9, 0.20, 0.01, -0.02, 0.021, 5.3e-5, 2.1e-4, 0.0,
                                          -2e-3, 0.0, 4e-3, 0.012, 0.010]}}}


def _robot(name):
    return robot_from_dict(ODD) if name == "odd" else load_robot(name)


@pytest.mark.parametrize("name", ["mrm3", "mrm6", "odd"])
@pytest.mark.parametrize("seed", range(5))
def test_inverse_dynamics_equals_rnea(name, seed):
    robot = _robot(name)
    model = robot.pinocchio_model()
    data = model.createData()
    rng = np.random.default_rng(seed)
    q, qd, qdd = (rng.uniform(-2.0, 2.0, robot.n) for _ in range(3))
    expected = pin.rnea(model, data, q, qd, qdd)
    tau = inverse_dynamics(robot, q, qd, qdd)
    assert np.max(np.abs(tau - expected)) <= 1e-12 * np.max(np.abs(expected))


def test_accepts_robot_object_and_toml_path():
    robot = load_robot("mrm3")
    q, qd, qdd = np.array([0.1, 0.2, 0.3]), np.array([0.4, -0.5, 0.6]), np.array([1.0, 2, 3])
    by_name = inverse_dynamics("mrm3", q, qd, qdd)
    np.testing.assert_array_equal(inverse_dynamics(robot, q, qd, qdd), by_name)
    np.testing.assert_array_equal(inverse_dynamics(str(BUILTIN_DIR / "mrm3.toml"), q, qd, qdd),
                                  by_name)


def test_static_case_is_generalized_gravity():
    robot = load_robot("mrm6")
    model = robot.pinocchio_model()
    tau = inverse_dynamics(robot, robot.home, np.zeros(6), np.zeros(6))
    np.testing.assert_allclose(tau, pin.computeGeneralizedGravity(model, model.createData(),
                                                                  robot.home), atol=1e-12)


def test_velocities_match_pinocchio_body_velocities():
    robot = load_robot("mrm6")
    model = robot.pinocchio_model()
    data = model.createData()
    rng = np.random.default_rng(9)
    q, qd = rng.uniform(-2, 2, 6), rng.uniform(-1, 1, 6)
    pin.forwardKinematics(model, data, q, qd)
    kin = propagate_velocities(robot, q, qd, qd, np.zeros(6))
    for k in range(robot.n):
        np.testing.assert_allclose(kin[k].V_A, data.v[k + 1].vector, atol=1e-12)


def test_velocity_feedback_enters_only_through_the_error():
    """F*_r = Yθ + K(V_r − V): with required ≠ actual the difference is exactly K·(V_r − V)."""
    robot = load_robot("mrm3")
    q, qd = np.array([0.1, 0.2, 0.3]), np.array([0.3, 0.2, 0.1])
    qd_r = qd + np.array([0.01, -0.02, 0.03])
    kin = propagate_velocities(robot, q, qd, qd_r, np.zeros(3))
    th = robot.nominal_theta
    K = np.arange(1.0, 7.0)
    F0 = link_required_forces(th[1, 0], th[1, 1], kin[1])
    F1 = link_required_forces(th[1, 0], th[1, 1], kin[1], K_a=K, K_b=np.diag(K))
    np.testing.assert_allclose(F1[0] - F0[0], K * (kin[1].Vr_A - kin[1].V_A), atol=1e-15)
    np.testing.assert_allclose(F1[1] - F0[1], K * (kin[1].Vr_C - kin[1].V_C), atol=1e-15)


def test_force_propagation_power_balance():
    """Virtual power is frame-independent: Σ over links of Vᵀ F* = Σ q̇ τ for the chain."""
    robot = load_robot("mrm6")
    rng = np.random.default_rng(2)
    q, qd = rng.uniform(-2, 2, 6), rng.uniform(-1, 1, 6)
    kin = propagate_velocities(robot, q, qd, qd, np.zeros(6))
    F_a, F_b = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
    _, tau = propagate_forces(robot, q, F_a, F_b)
    power_links = sum(kin[k].V_A @ F_a[k] + kin[k].V_C @ F_b[k] for k in range(6))
    assert power_links == pytest.approx(qd @ tau, rel=1e-12)


def test_rejects_wrong_shapes_and_nan():
    with pytest.raises(InputError, match="qd"):
        inverse_dynamics("mrm3", np.zeros(3), np.zeros(2), np.zeros(3))
    with pytest.raises(InputError, match="q"):
        inverse_dynamics("mrm3", [0.0, np.nan, 0.0], np.zeros(3), np.zeros(3))


@pytest.mark.parametrize("name", ["mrm3", "odd"])
def test_gravity_sent_to_the_nodes_is_pinocchios_in_every_C_frame(name):
    """The master's Comm D gravity (upward, in {C_k}) is the world's z in pinocchio's frame of
    Link b, base pose and twists included."""
    from mrm_cosim.master.cycle import Master

    robot = _robot(name)
    model = robot.pinocchio_model()
    data = model.createData()
    master = Master(robot, "vdc", lambda t: (robot.home,) * 3, robot.counts_per_rev)
    rng = np.random.default_rng(4)
    for _ in range(5):
        q = rng.uniform(-2.0, 2.0, robot.n)
        pin.framesForwardKinematics(model, data, q)
        g = master.gravity_in_C(q)
        for k in range(robot.n):
            R = data.oMf[model.getFrameId(f"link{k + 1}b")].rotation
            np.testing.assert_allclose(g[k], R.T @ [0.0, 0.0, 9.81], atol=1e-12)
