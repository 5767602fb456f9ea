"""Forward/inverse kinematics against pinocchio."""

import numpy as np
import pinocchio as pin
import pytest

from mrm_cosim.master.kinematics import (
    UnreachablePose, forward, inverse, jacobian, pose_error, rotation_log,
)
from mrm_cosim.models.robot import load_robot, robot_from_dict
from mrm_cosim.errors import InputError


@pytest.mark.parametrize("name", ["mrm3", "mrm6", "odd"])
def test_jacobian_matches_pinocchio(name):
    from .test_vdc_master import ODD

    robot = robot_from_dict(ODD) if name == "odd" else load_robot(name)
    model = robot.pinocchio_model()
    data = model.createData()
    fid = model.getFrameId("tool")
    rng = np.random.default_rng(0)
    for _ in range(10):
        q = rng.uniform(-robot.joint_limits, robot.joint_limits)
        J_pin = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(jacobian(robot, q), J_pin, atol=1e-12)
        np.testing.assert_allclose(forward(robot, q), data.oMf[fid].homogeneous, atol=1e-12)


def test_mrm6_has_full_rank_jacobian_away_from_singularities():
    robot = load_robot("mrm6")
    rng = np.random.default_rng(1)
    ranks = [np.linalg.matrix_rank(jacobian(robot, rng.uniform(-2.5, 2.5, 6)), tol=1e-6)
             for _ in range(50)]
    assert all(r == 6 for r in ranks)
    assert np.linalg.matrix_rank(jacobian(robot, robot.home), tol=1e-3) == 6


def test_mrm3_has_rank_three_position_jacobian():
    robot = load_robot("mrm3")
    q = np.array([0.3, 0.4, -0.6])
    assert np.linalg.matrix_rank(jacobian(robot, q)[:3], tol=1e-6) == 3


@pytest.mark.parametrize("seed", range(6))
def test_mrm6_inverse_kinematics_round_trip(seed):
    robot = load_robot("mrm6")
    rng = np.random.default_rng(100 + seed)
    q_true = robot.home + rng.uniform(-0.6, 0.6, 6)
    T = forward(robot, q_true)
    q = inverse(robot, T, robot.home, seed=seed)
    err = pose_error(T, forward(robot, q))
    assert np.linalg.norm(err[:3]) < 1e-6 and np.linalg.norm(err[3:]) < 1e-6
    assert np.all(np.abs(q) <= robot.joint_limits)


def test_mrm3_position_only_inverse_kinematics():
    robot = load_robot("mrm3")
    T = forward(robot, [0.2, 0.3, 0.4])
    q = inverse(robot, T, position_only=True)
    np.testing.assert_allclose(forward(robot, q)[:3, 3], T[:3, 3], atol=1e-6)


def test_unreachable_pose_fails_clearly():
    robot = load_robot("mrm6")
    T = np.eye(4)
    T[:3, 3] = [3.0, 0.0, 0.3]  # the arm is about 1.7 m long
    with pytest.raises(UnreachablePose) as info:
        inverse(robot, T, restarts=3)
    assert info.value.field == "pose" and "unreachable" in str(info.value)


def test_inverse_rejects_malformed_input():
    with pytest.raises(InputError, match="pose"):
        inverse("mrm3", np.full((4, 4), np.nan))
    with pytest.raises(InputError, match="q"):
        forward("mrm3", [0.0, 0.0])


@pytest.mark.parametrize("angle", [0.0, 1e-8, 0.5, 2.0, np.pi - 1e-6, np.pi])
def test_rotation_log_matches_pinocchio(angle):
    axis = np.array([0.3, -0.5, 0.8])
    axis /= np.linalg.norm(axis)
    R = pin.exp3(angle * axis)
    np.testing.assert_allclose(pin.exp3(rotation_log(R)), R, atol=1e-9)
    if angle < np.pi - 1e-3:
        np.testing.assert_allclose(rotation_log(R), pin.log3(R), atol=1e-9)


@pytest.mark.parametrize("name", ["mrm3", "mrm6"])
def test_tip_points_are_forward_and_jacobian_row_by_row(name):
    """:func:`tip_points` (stacks of frames, for run summaries) gives each sample's
    ``forward(q)[:3, 3]`` and ``‖jacobian(q)[:3] q̇‖`` to rounding."""
    from mrm_cosim.master.kinematics import tip_points

    robot = load_robot(name)
    rng = np.random.default_rng(2)
    Q = rng.uniform(-3.0, 3.0, (40, robot.n))
    QD = rng.normal(0.0, 2.0, (40, robot.n))
    tips, speeds = tip_points(robot, Q, QD)
    assert np.array_equal(tip_points(robot, Q), tips)
    for q, qd, tip, speed in zip(Q, QD, tips, speeds, strict=True):
        np.testing.assert_allclose(tip, forward(robot, q)[:3, 3], rtol=1e-12, atol=1e-15)
        assert speed == pytest.approx(np.linalg.norm(jacobian(robot, q)[:3] @ qd), rel=1e-12)
    with pytest.raises(InputError):
        tip_points(robot, Q[:, :2])
    with pytest.raises(InputError):
        tip_points(robot, Q, QD[:3])
