"""Trigonometric and Ruckig profiles side by side on the same line and robot (issue 16 item 2).

For one move (a :class:`master.trig_planner.LinePlan`) and one six-joint robot, both profiles
go through :func:`master.cartesian.joint_reference`; the table gives what the references alone
decide — duration, peak joint speeds and accelerations, the largest joint-jerk jump — and
takes further columns (peak torques, tracking errors) from closed-loop runs of the same
references, which only a run can measure.
"""

from __future__ import annotations

import numpy as np

from mrm_cosim.errors import InputError
from mrm_cosim.master.cartesian import JointReference, joint_reference
from mrm_cosim.master.ruckig_profile import plan_line_ruckig
from mrm_cosim.master.trig_planner import LinePlan

__all__ = ["PROFILES", "profile_references", "profile_rows", "markdown_table"]

PROFILES = ("trig", "ruckig")


def profile_references(robot, plan: LinePlan, dt: float = 1e-3,
                       q_seed=None) -> dict[str, JointReference]:
    """Joint references of the trigonometric plan and of Ruckig's on the same move.

    Parameters
    ----------
    robot : Robot or str
    plan : LinePlan
        The trigonometric plan; Ruckig's is solved from its geometry and limits.
    dt : float, s
        IK sample step.
    q_seed : array_like, shape (6,), rad, optional
        Branch selection at the start pose (both profiles start there).

    Returns
    -------
    dict
        ``{"trig": JointReference, "ruckig": JointReference}``.
    """
    plans = {"trig": plan, "ruckig": plan_line_ruckig(plan)}
    return {name: joint_reference(robot, p, dt, q_seed) for name, p in plans.items()}


def profile_rows(references: dict[str, JointReference]) -> list[dict]:
    """One JSON-ready row per profile: duration, per-joint peaks, the jerk jump.

    Returns
    -------
    list of dict
        Keys ``profile``, ``duration_s``, ``peak_speed_rad_s`` and
        ``peak_acceleration_rad_s2`` (lists, one per joint), ``jerk_jump_rad_s3``,
        ``jerk_jump_t_s``, ``jerk_jump_joint`` and ``max_condition``.
    """
    rows = []
    for name, ref in references.items():
        s = ref.summary()
        rows.append({"profile": name, "duration_s": s["duration_s"],
                     "peak_speed_rad_s": s["peak_speed_rad_s"],
                     "peak_acceleration_rad_s2": s["peak_acceleration_rad_s2"],
                     "jerk_jump_rad_s3": s["jerk_jump"]["jump_rad_s3"],
                     "jerk_jump_t_s": s["jerk_jump"]["t_s"],
                     "jerk_jump_joint": s["jerk_jump"]["joint"],
                     "max_condition": s["max_condition"]})
    return rows


def markdown_table(rows: list[dict], run_columns: dict[str, dict[str, str]] | None = None) -> str:
    """The rows as a Markdown table, one line per profile.

    Parameters
    ----------
    rows : list of dict
        From :func:`profile_rows`.
    run_columns : dict, optional
        Further columns measured in closed-loop runs, ``{heading: {profile: text}}`` (for
        example ``{"peak torque (N·m)": {"trig": "3.1, …", "ruckig": "…"}}``); every heading
        must give a value for every profile in ``rows``.
    """
    run_columns = run_columns or {}
    names = [r["profile"] for r in rows]
    for heading, values in run_columns.items():
        missing = [n for n in names if n not in values]
        if missing:
            raise InputError(f"run_columns.{heading}", f"no value for {', '.join(missing)}")
    head = ["profile", "duration (s)", "peak joint speed (rad/s)",
            "peak joint acceleration (rad/s²)", "largest jerk jump (rad/s³, at t)",
            *run_columns]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["profile"], f"{r['duration_s']:.4f}", _joints(r["peak_speed_rad_s"]),
                 _joints(r["peak_acceleration_rad_s2"]),
                 f"{r['jerk_jump_rad_s3']:.3g} (joint {r['jerk_jump_joint']}, "
                 f"{r['jerk_jump_t_s']:.3f} s)",
                 *(values[r["profile"]] for values in run_columns.values())]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _joints(values) -> str:
    return ", ".join(f"{v:.3g}" for v in np.asarray(values, dtype=float))
