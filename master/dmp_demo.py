"""Demonstrations for ``mrm dmp learn``: a joint trajectory or a Cartesian path as CSV, and the
Cartesian path turned into joint angles through the project's IK.

A demo file is CSV with a header row and one row per sample, uniformly spaced in time:

- **joint trajectory**: a time column ``t`` (or ``t_s``, s) and one column per joint (rad);
  every other column is a joint unless ``columns`` picks some (the samples ``mrm plan quintic
  --samples`` writes are a demo with ``columns=["q1_rad", …]``);
- **Cartesian path**: columns ``t``, ``x``, ``y``, ``z`` (m; ``x_m`` … accepted) and the
  orientation as a unit quaternion in (w, x, y, z) order, ``qw``, ``qx``, ``qy``, ``qz``;
  other columns are ignored, so ``mrm plan line --samples`` writes a Cartesian demo.

Checks, each an :class:`~mrm_cosim.errors.InputError` naming the file argument ``field`` and
the line or column: the header, numbers and finiteness of every value, at least 3 rows, time
increasing with one step (each step within 10⁻⁶ of the mean step, relative).

:func:`joints_from_poses` solves the path on one branch: the first pose by
:func:`master.kinematics.inverse` seeded from the robot's home posture, every later pose by the
damped least squares of :mod:`master.cartesian` seeded from the linear continuation of the two
previous solutions. A pose it cannot reach (residual above 10⁻⁹), a solution more than
:data:`BRANCH_STEP` from the continuation (another branch), a joint outside its range and a
posture near a singularity (:data:`master.cartesian.MAX_CONDITION`) are refused with the row.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mrm_cosim.errors import InputError
from mrm_cosim.master import quaternion as quat

__all__ = ["Demo", "read_demo", "joints_from_poses", "CARTESIAN_COLUMNS", "BRANCH_STEP",
           "MAX_BYTES", "STEP_TOLERANCE"]

#: The largest demo file read (64 MiB: a six-joint demo at 1 ms for an hour is ~50 MiB).
MAX_BYTES = 64 << 20
#: Largest relative difference of a time step from the file's mean step.
STEP_TOLERANCE = 1e-6
#: Columns of a Cartesian path, each with the names accepted for it.
CARTESIAN_COLUMNS = {"x": ("x", "x_m"), "y": ("y", "y_m"), "z": ("z", "z_m"),
                     "qw": ("qw",), "qx": ("qx",), "qy": ("qy",), "qz": ("qz",)}
_TIME = ("t", "t_s")
#: Largest distance (rad, any joint) of a Cartesian demo's IK solution from the linear
#: continuation of the two previous ones; further is a jump to another branch.
BRANCH_STEP = 0.1
_UNIT_NORM = 1e-6


@dataclass(frozen=True)
class Demo:
    """A uniformly sampled demo.

    Attributes
    ----------
    t : ndarray, shape (n_samples,), s
    values : ndarray, shape (n_samples, n_columns)
        The chosen columns, time-major.
    names : tuple of str
        Their header names.
    dt : float, s
        The sample step.
    lines : ndarray of int, shape (n_samples,)
        The file's line number of each sample (for messages).
    """

    t: np.ndarray
    values: np.ndarray
    names: tuple[str, ...]
    dt: float
    lines: np.ndarray


def _read_text(path, field: str) -> str:
    from mrm_cosim.tomlfile import read_text

    return read_text(path, field, kind="CSV", max_bytes=MAX_BYTES, encoding="utf-8-sig")


def read_demo(path, *, columns=None, cartesian: bool = False, field: str = "TRAJ",
              columns_field: str = "columns") -> Demo:
    """Read and check a demo CSV.

    Parameters
    ----------
    path : str or Path
    columns : sequence of str, optional
        Joint columns to take (joint trajectory only); all but the time column by default.
    cartesian : bool
        Take ``x, y, z, qw, qx, qy, qz`` (in this order) instead of joint columns.
    field, columns_field : str
        Names of the file argument and of ``columns`` in the errors.

    Returns
    -------
    Demo
    """
    text = _read_text(Path(path), field)
    rows = [(n, row) for n, row in enumerate(csv.reader(io.StringIO(text)), start=1)
            if any(cell.strip() for cell in row)]
    if not rows:
        raise InputError(field, "is empty; it needs a header row (t, then one column per "
                         "joint) and at least 3 samples")
    head_line, header = rows[0]
    header = [h.strip() for h in header]
    where = f"{field} line {head_line}"
    if header[0] not in _TIME:
        raise InputError(where, f"the header must start with the time column t (or t_s), "
                         f"not {header[0]!r}")
    for i, name in enumerate(header):
        if not name:
            raise InputError(where, f"column {i + 1} has no name")
        if header.index(name) != i:
            raise InputError(where, f"column {name!r} appears twice")
    if cartesian:
        if columns is not None:
            raise InputError(columns_field, "picks joint columns; a Cartesian path has fixed "
                             "ones (x, y, z, qw, qx, qy, qz)")
        picked = []
        for key, names in CARTESIAN_COLUMNS.items():
            found = [h for h in header if h in names]
            if not found:
                raise InputError(where, f"a Cartesian path needs the columns t, x, y, z, qw, "
                                 f"qx, qy, qz (quaternion in w, x, y, z order); {key} is "
                                 "missing")
            picked.append(found[0])
    elif columns is not None:
        picked = list(columns)
        if not picked:
            raise InputError(columns_field, "names no column")
        for name in picked:
            if name not in header[1:]:
                raise InputError(columns_field, f"{field} has no joint column {name!r} (it "
                                 f"has {', '.join(header[1:]) or 'only ' + header[0]})")
            if picked.count(name) > 1:
                raise InputError(columns_field, f"names {name!r} twice")
    else:
        picked = header[1:]
        if not picked:
            raise InputError(where, "has only the time column; give one column per joint")
    index = [0] + [header.index(name) for name in picked]
    data, lines = [], []
    for n, row in rows[1:]:
        if len(row) != len(header):
            raise InputError(f"{field} line {n}", f"has {len(row)} values, the header "
                             f"{len(header)}")
        values = []
        for i in index:
            cell = row[i].strip()
            try:
                x = float(cell)
            except ValueError:
                raise InputError(f"{field} line {n} column {header[i]}",
                                 f"must be a number, not {cell!r}") from None
            if not math.isfinite(x):
                raise InputError(f"{field} line {n} column {header[i]}",
                                 f"must be finite, not {cell!r}")
            values.append(x)
        data.append(values)
        lines.append(n)
    if len(data) < 3:
        raise InputError(field, f"has {len(data)} samples; a DMP needs at least 3")
    table = np.array(data)
    t = table[:, 0]
    steps = np.diff(t)
    dt = float((t[-1] - t[0]) / (len(t) - 1))
    for k, step in enumerate(steps):
        if not step > 0.0:
            raise InputError(f"{field} line {lines[k + 1]}", f"t = {float(t[k + 1])!r} s "
                             f"does not increase (previous line t = {float(t[k])!r} s)")
    off = np.abs(steps - dt) > STEP_TOLERANCE * dt
    if off.any():
        k = int(np.argmax(off))
        raise InputError(f"{field} line {lines[k + 1]}", f"t is not uniformly sampled: step "
                         f"{steps[k]:.9g} s from the line before, the file's mean step is "
                         f"{dt:.9g} s (tolerance {STEP_TOLERANCE:g} relative)")
    return Demo(t, table[:, 1:], tuple(picked), dt, np.array(lines))


def joints_from_poses(robot, demo: Demo, field: str = "TRAJ") -> np.ndarray:
    """Joint angles (rad, shape (n_samples, 6)) that put ``robot``'s tool on the Cartesian
    demo's poses, on one continuous IK branch starting from the robot's home posture.

    ``demo.values`` holds x, y, z (m) and qw, qx, qy, qz per sample (:func:`read_demo` with
    ``cartesian=True``). Errors name ``field`` with the line and time of the sample.
    """
    from mrm_cosim.master.cartesian import (MAX_CONDITION, BranchJump, JointLimitError,
                                            SingularPath, TaskDimensionError, _Chain, _solve)
    from mrm_cosim.master.kinematics import UnreachablePose, inverse
    from mrm_cosim.models.robot import load_robot

    robot = load_robot(robot)
    if robot.n != 6:
        raise TaskDimensionError("robot", f"a Cartesian path fixes 6 coordinates (position and "
                                 f"orientation); {robot.name} has {robot.n} joints, so it "
                                 "needs exactly 6")
    chain = _Chain(robot)
    lim = robot.joint_limits
    n = len(demo.t)
    Q = np.zeros((n, 6))
    for k in range(n):
        where = f"{field} line {demo.lines[k]} (t = {demo.t[k]:.9g} s)"
        q4 = demo.values[k, 3:7]
        norm = float(np.linalg.norm(q4))
        if abs(norm - 1.0) > _UNIT_NORM:
            raise InputError(where, f"the quaternion (qw, qx, qy, qz) has norm {norm:.9g}, "
                             "not 1")
        T = np.eye(4)
        T[:3, :3] = quat.to_matrix(q4 / norm)
        T[:3, 3] = demo.values[k, :3]
        if k == 0:
            try:
                q = inverse(robot, T, robot.home)
            except UnreachablePose as exc:
                raise UnreachablePose(where, f"the pose is unreachable by {robot.name}: "
                                      f"{exc.message.split(': ', 1)[-1]}") from None
            q, res = _solve(chain, T, q)
        else:
            pred = Q[k - 1] if k == 1 else 2.0 * Q[k - 1] - Q[k - 2]
            q, res = _solve(chain, T, pred)
            if res > 1e-9:
                raise UnreachablePose(where, f"the pose is unreachable by {robot.name} on the "
                                      f"demo's branch (IK residual {res:.3g} from the previous "
                                      "sample's posture)")
            miss = np.abs(q - pred)
            if miss.max() > BRANCH_STEP:
                j = int(np.argmax(miss))
                raise BranchJump(where, f"the IK solution jumps to another branch: joint "
                                 f"{j + 1} lands {miss[j]:.3g} rad from the continuation of "
                                 f"the previous samples (more than {BRANCH_STEP} rad); sample "
                                 "the path more finely")
        over = np.abs(q) - lim
        if over.max() > 0.0:
            j = int(np.argmax(over))
            raise JointLimitError(where, f"joint {j + 1} at {math.degrees(q[j]):.2f}° is "
                                  f"outside its range ±{math.degrees(lim[j]):g}°")
        cond = chain.condition(chain.jacobian(q))
        if not cond <= MAX_CONDITION:
            raise SingularPath(where, f"the pose is near a singular posture of {robot.name} "
                               f"(condition number {cond:.3g} > {MAX_CONDITION:g})")
        Q[k] = q
    return Q
