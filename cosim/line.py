"""``mrm run line``: a planned Cartesian line through IK into the closed loop (issue 16).

The chain is: the planner's Cartesian samples (trigonometric, Li et al.; or Ruckig's
time-optimal profile on the same move) → :func:`master.cartesian.joint_reference` (IK on one
branch, exact q̇, q̈, q⃛ from the differential kinematics, C³ between samples, every limit
checked) → :func:`cosim.track.run_track` with that reference as the test trajectory, on any
backend and controller → the tool's errors over time (:func:`master.cartesian.tool_errors`):
position (mm), orientation (mrad) and the se(3) error ‖log(T_d⁻¹ T_a)‖.

The arm starts where the line starts: the robot is run with its home posture set to the
reference's first sample, so the plant starts there and the nodes' incremental encoders are
preset to it (as for any home posture, docs/robot.md). After the move the reference holds the
end pose for ``hold`` seconds, so the run shows the settling as Table 2's does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mrm_cosim.errors import InputError
from mrm_cosim.master.cartesian import JointReference, ToolErrors, joint_reference, tool_errors
from mrm_cosim.models.robot import Robot, load_robot

__all__ = ["LineRun", "PROFILES", "line_reference", "run_line", "robot_at"]

PROFILES = ("trig", "ruckig")
HOLD_S = 0.2          # the end pose held after the move, as the paper's quintic test does


@dataclass
class LineRun:
    """One closed-loop run of a Cartesian line.

    Attributes
    ----------
    profile : str
        ``"trig"`` or ``"ruckig"``.
    reference : JointReference
    result : LoopResult
        The loop's trace (:class:`cosim.closed_loop.LoopResult`).
    summary : dict
        :func:`cosim.track.run_track`'s summary with the line's figures added (``line``).
    errors : ToolErrors
        The tool's errors on the plant-step grid of ``result.t``.
    q_desired : ndarray, shape (k, n), rad
        The reference at ``result.t``.
    """

    profile: str
    reference: JointReference
    result: object
    summary: dict
    errors: ToolErrors
    q_desired: np.ndarray


def robot_at(robot: Robot, q0) -> Robot:
    """``robot`` with its home posture at ``q0``: the plant starts there and the nodes'
    encoders are preset to it."""
    return Robot(robot.name, robot.modules, base=robot.base, tool=robot.tool,
                 home=np.asarray(q0, dtype=float))


def line_reference(robot, plan, profile: str = "trig", dt: float = 1e-3) -> JointReference:
    """The joint reference of ``plan`` (a trigonometric :class:`master.trig_planner.LinePlan`)
    for ``profile``: the plan itself (``"trig"``) or Ruckig's time-optimal profile on the same
    move and limits (``"ruckig"``), through IK seeded at the robot's home posture."""
    if profile not in PROFILES:
        raise InputError("profile", f"must be one of {', '.join(PROFILES)}, not {profile!r}")
    robot = load_robot(robot)
    if profile == "ruckig":
        from mrm_cosim.master.ruckig_profile import plan_line_ruckig

        plan = plan_line_ruckig(plan)
    return joint_reference(robot, plan, dt, q_seed=robot.home)


def run_line(robot, plan, *, profile: str = "trig", controller: str = "vdc",
             backend: str = "model", seed: int = 0, gains=None, timing=None,
             plant_config=None, duration: float | None = None, hold: float = HOLD_S,
             progress=None, reference: JointReference | None = None,
             clocks=None) -> LineRun:
    """Run a planned Cartesian line in closed loop.

    Parameters
    ----------
    robot : Robot or str
        A six-joint robot (the line fixes the tool's position and orientation).
    plan : LinePlan
        The trigonometric plan (:func:`master.trig_planner.plan_line`); Ruckig's profile is
        solved from it with ``profile="ruckig"``.
    duration : float, s, optional
        Simulated seconds from period 0 (default: the move plus ``hold``).
    reference : JointReference, optional
        A reference computed before (e.g. by :func:`line_reference`, to check it before a run).
    gains, timing, plant_config, seed, controller, backend, progress, clocks
        As :func:`cosim.track.run_track`.

    Returns
    -------
    LineRun
    """
    from mrm_cosim.cosim.track import run_track

    robot = load_robot(robot)
    ref = reference if reference is not None else line_reference(robot, plan, profile)
    if duration is None:
        if not (isinstance(hold, int | float) and np.isfinite(hold) and hold >= 0):
            raise InputError("hold", f"must be a non-negative number of seconds, not {hold!r}")
        duration = float(ref.duration) + hold
    start_robot = robot_at(robot, ref.q[0])
    result, summary = run_track(start_robot, controller, backend, duration, seed, gains=gains,
                                timing=timing, plant_config=plant_config, progress=progress,
                                profile=ref, clocks=clocks)
    q_d = ref.evaluate(result.t)[0]
    errors = tool_errors(start_robot, q_d, result.q)
    reference_summary = ref.summary()
    summary["line"] = {
        "profile": profile,
        "move_duration_s": float(ref.duration),
        **errors.summary(),
        "peak_torque_Nm": np.abs(result.tau).max(axis=0).tolist(),
        "reference": reference_summary,
    }
    return LineRun(profile, ref, result, summary, errors, q_d)


def line_table(runs: dict[str, LineRun]) -> str:
    """Markdown table of runs of the same line with different profiles: the reference's
    duration, peak joint speeds, the jerk jump, and the run's peak torques and tool errors."""
    def joints(values, fmt="{:.3g}"):
        return " / ".join(fmt.format(v) for v in values)

    lines = ["| profile | move (s) | peak joint speed (rad/s) | largest jerk jump (rad/s³) "
             "| peak torque (N·m) | max position error (mm) | max orientation error (mrad) "
             "| max se(3) error |",
             "|---|---|---|---|---|---|---|---|"]
    for name, run in runs.items():
        line = run.summary["line"]
        ref = line["reference"]
        jump = ref.get("jerk_jump", {})
        lines.append(
            f"| {name} | {line['move_duration_s']:.4f} "
            f"| {joints(ref['peak_speed_rad_s'])} "
            f"| {jump.get('jump_rad_s3', float('nan')):.3g} "
            f"| {joints(line['peak_torque_Nm'])} "
            f"| {line['max_position_error_mm']:.4f} "
            f"| {line['max_orientation_error_mrad']:.4f} "
            f"| {line['max_se3_error']:.3g} |")
    return "\n".join(lines) + "\n"
