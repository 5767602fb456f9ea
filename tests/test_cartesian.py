"""A planned Cartesian line to joint references (master/cartesian.py) and the tool errors."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from mrm_cosim.cosim.line_report import markdown_table, profile_references, profile_rows
from mrm_cosim.errors import InputError
from mrm_cosim.master import quaternion as quat
from mrm_cosim.master.cartesian import (
    BranchJump, JointLimitError, SingularPath, TaskDimensionError, UnreachablePose,
    joint_reference, se3_log, tool_errors,
)
from mrm_cosim.master.ruckig_profile import plan_line_ruckig
from mrm_cosim.master.trig_planner import AxisLimits, LineLimits, plan_line
from mrm_cosim.models.robot import load_robot
from mrm_cosim.master.line_file import load_line_file

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "line.toml"
SLOW = LineLimits(AxisLimits(0.2, 0.8, 6.0), AxisLimits(2.0, 8.0, 60.0))


@pytest.fixture(scope="module")
def robot():
    return load_robot("mrm6")


@pytest.fixture(scope="module")
def plan():
    return plan_line(*load_line_file(str(EXAMPLE)))


@pytest.fixture(scope="module")
def ref(robot, plan):
    return joint_reference(robot, plan)


def _pose(robot, q):
    return robot.tip_pose(np.asarray(q, dtype=float))


def test_fk_of_ik_samples_equals_the_planned_poses(robot, plan, ref):
    cs = plan.sample(ref.t)
    for k in range(len(ref.t)):
        T = _pose(robot, ref.q[k])
        np.testing.assert_allclose(T[:3, 3], cs.position[k], rtol=0, atol=1e-9)
        np.testing.assert_allclose(T[:3, :3], quat.to_matrix(cs.quaternion[k]), rtol=0,
                                   atol=1e-9)
    assert ref.ik_residual < 1e-12
    np.testing.assert_allclose(ref.q[0], robot.home, atol=1e-9)   # the example starts at home


def test_one_continuous_branch(robot, ref):
    step = np.abs(np.diff(ref.q, axis=0)).max(axis=0)
    # never more than the joint's speed allows in one sample
    assert np.all(step <= robot.max_speeds * (ref.t[1] - ref.t[0]))
    assert np.all(np.abs(ref.q) <= robot.joint_limits)


def test_derivatives_are_those_of_the_tool_motion(robot, plan, ref):
    """Between samples too: J q̇ is the planned twist, FK(q) the planned pose."""
    t = ref.t[:-1] + 0.37e-3
    q, qd, qdd, qddd = ref.evaluate(t)
    cs = plan.sample(t)
    model = robot.pinocchio_model()
    data = model.createData()
    frame = model.getFrameId("tool")
    for k in range(0, len(t), 7):
        J = pin.computeFrameJacobian(model, data, q[k], frame, pin.LOCAL_WORLD_ALIGNED)
        twist = np.concatenate([cs.velocity[k], cs.angular_velocity[k]])
        np.testing.assert_allclose(J @ qd[k], twist, rtol=0, atol=1e-8)
        np.testing.assert_allclose(_pose(robot, q[k])[:3, 3], cs.position[k], atol=1e-12)
    # the reference is C³: finite differences of each level give the next (to O(h) where the
    # trig profile's snap jumps: at 0, T/2 and T)
    tf = np.linspace(0.0, ref.duration, 8001)
    h = tf[1] - tf[0]
    levels = ref.evaluate(tf)
    for lower, upper in zip(levels[:-1], levels[1:], strict=True):
        fd = (lower[2:] - lower[:-2]) / (2 * h)
        assert np.abs(fd - upper[1:-1]).max() <= 1e-3 * np.abs(upper).max()


def test_reference_interface_for_the_closed_loop(ref):
    q, qd, qdd, qddd = ref.evaluate(np.array([-1.0, 0.0, ref.t[-1], 99.0]))
    assert q.shape == (4, 6)
    np.testing.assert_array_equal(q[0], ref.q[0])
    np.testing.assert_array_equal(q[3], ref.q[-1])
    assert not qd[0].any() and not qdd[3].any() and not qddd[3].any()
    q1, qd1, qdd1 = ref.trajectory()(0.5005)
    np.testing.assert_array_equal(q1, ref.evaluate(0.5005)[0][0])
    assert qd1.shape == qdd1.shape == (6,)


def test_trig_jerk_is_continuous_and_a_ruckig_jerk_jump_is_reported(robot, plan, ref):
    """Ruckig's jerk is piecewise constant: the joint jerk jumps by J⁻¹ times the Cartesian
    jerk jump at a phase boundary, at any sample step; the trig plan's jump shrinks with dt."""
    trig = ref.jerk_jump()
    ruckig = plan_line_ruckig(plan)
    rref = joint_reference(robot, ruckig)
    jump = rref.jerk_jump()
    assert jump["jump_rad_s3"] > 100 * trig["jump_rad_s3"]
    # the reported time is the sample just after a Ruckig phase boundary
    bounds = np.concatenate([ruckig.translation.t_start, ruckig.rotation.t_start])
    assert np.min(np.abs(bounds - jump["t_s"])) < jump["dt_s"]
    # the size: the joint jerk's step equals J⁻¹ times the Cartesian jerk's step there
    k = int(round(jump["t_s"] / jump["dt_s"]))
    cs = ruckig.sample(rref.t[k - 1:k + 1])
    dj = np.concatenate([cs.jerk[1] - cs.jerk[0], cs.angular_jerk[1] - cs.angular_jerk[0]])
    model = robot.pinocchio_model()
    J = pin.computeFrameJacobian(model, model.createData(), rref.q[k], model.getFrameId("tool"),
                                 pin.LOCAL_WORLD_ALIGNED)
    expected = np.abs(np.linalg.solve(J, dj)).max()
    assert jump["jump_rad_s3"] == pytest.approx(expected, rel=0.05)
    # continuous jerk: halving dt halves the trig jump; Ruckig's stays
    fine = joint_reference(robot, plan, dt=5e-4).jerk_jump()["jump_rad_s3"]
    assert fine == pytest.approx(trig["jump_rad_s3"] / 2, rel=0.1)
    assert joint_reference(robot, ruckig, dt=5e-4).jerk_jump()["jump_rad_s3"] == \
        pytest.approx(jump["jump_rad_s3"], rel=0.2)


def test_singular_path_is_refused_naming_the_sample_time(robot):
    # q4 = 0 with these angles puts joint 6 on joint 1's axis (a singular posture)
    q_sing = np.radians([118.8, 122.6, 80.5, 0.0, -156.9, -118.8])
    q_a = q_sing + np.radians([0.0, 0.0, 10.0, 0.0, 0.0, 0.0])
    plan = plan_line(_pose(robot, q_a).tolist(), _pose(robot, q_sing).tolist(), SLOW)
    with pytest.raises(SingularPath) as exc:
        joint_reference(robot, plan, q_seed=q_a)
    assert exc.value.field.startswith("sample t = ")
    t = float(exc.value.field.split("= ")[1].split()[0])
    assert 0.0 < t < plan.duration
    assert "max_condition" in exc.value.message


def test_unreachable_pose_is_refused(robot):
    far = _pose(robot, robot.home)
    far[:3, 3] = [3.0, 0.0, 0.5]
    plan = plan_line(_pose(robot, robot.home).tolist(), far.tolist(), SLOW)
    with pytest.raises(UnreachablePose) as exc:
        joint_reference(robot, plan)
    assert exc.value.field == "end.pose"
    assert "workspace" in exc.value.message


def test_joint_limits_are_refused_naming_joint_and_time(robot, plan):
    """The example turned at twice the rotation speed needs joint 5 faster than allowed…"""
    limited = replace(robot.modules[4].type, max_speed=1.0)
    slow_robot = load_robot("mrm6")
    slow_robot.modules[4] = replace(slow_robot.modules[4], type=limited)
    with pytest.raises(JointLimitError) as exc:
        joint_reference(slow_robot, plan)
    assert exc.value.field.startswith("sample t = ")
    assert "joint 5" in exc.value.message and "max_speed" in exc.value.message
    # …and a longer move of the same kind runs joint 6 past ±170° (docs: examples/line.toml)
    start, end = np.array(plan.geometry.p_start), np.array(plan.geometry.p_end)
    T0, T1 = _pose(robot, robot.home), _pose(robot, robot.home)
    T1[:3, :3] = quat.to_matrix(plan.geometry.q_end)
    T1[:3, 3] = start + 2.0 * (end - start)
    with pytest.raises(JointLimitError, match="joint 6 .* outside its range"):
        joint_reference(robot, plan_line(T0.tolist(), T1.tolist(), SLOW))


def test_branch_jump_is_refused(robot, plan):
    """A pose path that jumps 2 cm between two samples (while its velocity says it rests)
    would need the IK to leave the continued branch."""
    class Jumping:
        duration = plan.duration

        def sample(self, t):
            cs = plan.sample(t)
            pos = cs.position.copy()
            pos[t >= 0.5] += [0.0, 0.0, 0.02]
            return replace(cs, position=pos)

    with pytest.raises(BranchJump) as exc:
        joint_reference(robot, Jumping())
    assert exc.value.field == "sample t = 0.5 s"
    assert "branch_tolerance" in exc.value.message
    # samples too coarse to follow the motion are refused the same way
    with pytest.raises(BranchJump):
        joint_reference(robot, plan, dt=0.1)


def test_a_three_joint_robot_is_refused_for_a_six_dimensional_line(plan):
    with pytest.raises(TaskDimensionError) as exc:
        joint_reference("mrm3", plan)
    assert exc.value.field == "robot" and "3 joints" in exc.value.message


def test_bad_arguments_name_their_field(robot, plan):
    with pytest.raises(InputError, match="^dt:"):
        joint_reference(robot, plan, dt=0.0)
    with pytest.raises(InputError, match="^q_seed:"):
        joint_reference(robot, plan, q_seed=[0.0, 1.0])


def test_se3_log_equals_pinocchio_log6():
    rng = np.random.default_rng(0)
    for angle in [0.0, 1e-9, 1e-6, 1e-3, 0.5, 2.0, 3.0, np.pi - 1e-5]:
        for _ in range(5):
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            T = np.eye(4)
            T[:3, :3] = pin.exp3(angle * axis)
            T[:3, 3] = rng.normal(size=3)
            np.testing.assert_allclose(se3_log(T), pin.log6(pin.SE3(T)).vector, atol=2e-9)


def test_tool_errors(robot, ref):
    q_d = ref.q[::50]
    q_a = q_d.copy()
    q_a[:, 5] += 1e-3                       # joint 6 off by 1 mrad
    err = tool_errors(robot, q_d, q_a)
    # joint 6 turns the tool about its axis: the orientation error is exactly 1 mrad
    np.testing.assert_allclose(err.orientation_mrad, 1.0, rtol=1e-6)
    for k in range(len(q_d)):
        Td, Ta = _pose(robot, q_d[k]), _pose(robot, q_a[k])
        assert err.position_mm[k] == pytest.approx(1e3 * np.linalg.norm(Ta[:3, 3] - Td[:3, 3]))
        rel = pin.SE3(Td).actInv(pin.SE3(Ta))
        assert err.se3[k] == pytest.approx(np.linalg.norm(pin.log6(rel).vector), rel=1e-9)
    assert tool_errors(robot, q_d, q_d).se3.max() < 1e-15
    with pytest.raises(InputError, match="^q_actual:"):
        tool_errors(robot, q_d, q_a[:, :3])


def test_profiles_side_by_side(robot, plan):
    rows = profile_rows(profile_references(robot, plan))
    trig, ruckig = rows
    assert (trig["profile"], ruckig["profile"]) == ("trig", "ruckig")
    assert trig["duration_s"] == pytest.approx(1.298747, abs=1e-6)
    assert ruckig["duration_s"] < trig["duration_s"]
    assert ruckig["jerk_jump_rad_s3"] > 100 * trig["jerk_jump_rad_s3"]
    text = markdown_table(rows, {"max tip error (mm)": {"trig": "0.1", "ruckig": "0.2"}})
    assert text.count("\n") == 4 and "| trig | 1.2987 |" in text
    with pytest.raises(InputError, match="no value for ruckig"):
        markdown_table(rows, {"torque": {"trig": "1"}})
