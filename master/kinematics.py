"""Forward and inverse kinematics of any N-module assembly.

Forward kinematics composes the robot description's frames (:meth:`models.robot.Robot.link_frames`).
The Jacobian is geometric, at the tool point, in world-aligned axes: ``[v; ω] = J q̇``.
Inverse kinematics is damped least squares (Levenberg–Marquardt with an adaptive damping, the
error measured as the translation and the rotation vector ``log(R_goal Rᵀ)``), within joint limits,
from the given seed and then from seeded random restarts; it fails loudly with
:class:`UnreachablePose` when no solution is within tolerance.
"""

from __future__ import annotations

import math

import numpy as np

from mrm_cosim.models.robot import Robot, load_robot
from mrm_cosim.errors import InputError

__all__ = ["forward", "jacobian", "inverse", "pose_error", "UnreachablePose", "rotation_log",
           "tip_points"]


class UnreachablePose(InputError):
    """No joint configuration within the limits reaches the requested pose."""


def forward(robot, q) -> np.ndarray:
    """World pose (4×4) of the tool point.

    Parameters
    ----------
    robot : Robot or str
    q : array_like, shape (n,), rad
    """
    robot = load_robot(robot)
    return robot.tip_pose(_joint_vector(robot, q))


def jacobian(robot, q) -> np.ndarray:
    """Geometric Jacobian at the tool point, world-aligned, shape (6, n): rows ``[v; ω]``."""
    robot = load_robot(robot)
    q = _joint_vector(robot, q)
    frames = robot.link_frames(q)
    p_tip = (frames[-1][1] @ robot.tool_transform())[:3, 3]
    J = np.empty((6, robot.n))
    for k, (_, T_A) in enumerate(frames):
        z = T_A[:3, 2]
        J[:3, k] = np.cross(z, p_tip - T_A[:3, 3])
        J[3:, k] = z
    return J


def tip_points(robot, Q, QD=None):
    """Tool-point positions (and linear speeds) of many joint vectors at once: what
    ``forward(robot, q)[:3, 3]`` and ``‖jacobian(robot, q)[:3] @ q̇‖`` give row by row, the
    same frames composed on stacks of matrices (equal to them to rounding: tested within 1e-12
    relative). For run summaries over thousands of samples.

    Parameters
    ----------
    robot : Robot or str
    Q : array_like, shape (m, n), rad
    QD : array_like, shape (m, n), rad/s, optional

    Returns
    -------
    tips : ndarray, shape (m, 3), m
    speeds : ndarray, shape (m,), m/s (only with ``QD``)
    """
    robot = load_robot(robot)
    Q = np.asarray(Q, dtype=float)
    if Q.ndim != 2 or Q.shape[1] != robot.n:
        raise InputError("Q", f"must have shape (samples, {robot.n}), not {Q.shape}")
    m = Q.shape[0]
    T = np.broadcast_to(np.eye(4), (m, 4, 4))
    Rz = np.zeros((m, 4, 4))
    Rz[:, 2, 2] = Rz[:, 3, 3] = 1.0
    origins, axes = [], []
    for k in range(robot.n):
        c, s = np.cos(Q[:, k]), np.sin(Q[:, k])
        Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1] = c, -s, s, c
        T = (T @ robot.mount_transform(k)) @ Rz
        origins.append(T[:, :3, 3])
        axes.append(T[:, :3, 2])
    tips = (T @ robot.tool_transform())[:, :3, 3]
    if QD is None:
        return tips
    QD = np.asarray(QD, dtype=float)
    if QD.shape != Q.shape:
        raise InputError("QD", f"must have the shape of Q, {Q.shape}, not {QD.shape}")
    v = np.zeros((m, 3))
    for k in range(robot.n):
        v += np.cross(axes[k], tips - origins[k]) * QD[:, k:k + 1]
    return tips, np.linalg.norm(v, axis=1)


def rotation_log(R) -> np.ndarray:
    """Rotation vector (axis × angle, rad) of a rotation matrix, robust near 0 and π."""
    R = np.asarray(R, dtype=float)
    cos = max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0))
    angle = math.acos(cos)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-6:
        return 0.5 * w
    if math.pi - angle < 1e-4:
        # Near π the skew part vanishes: take the axis from the symmetric part,
        # (R + Rᵀ)/2 = cos θ E + (1 − cos θ) a aᵀ.
        B = ((R + R.T) / 2.0 - cos * np.eye(3)) / (1.0 - cos)
        i = int(np.argmax(np.diag(B)))
        a = B[:, i] / math.sqrt(B[i, i])
        if np.dot(a, w) < 0.0:
            a = -a
        return angle * a
    return angle / (2.0 * math.sin(angle)) * w


def pose_error(T_goal, T) -> np.ndarray:
    """6-vector from pose ``T`` to ``T_goal``: ``[p_goal − p; log(R_goal Rᵀ)]`` (world axes)."""
    T_goal, T = np.asarray(T_goal, dtype=float), np.asarray(T, dtype=float)
    return np.concatenate([T_goal[:3, 3] - T[:3, 3], rotation_log(T_goal[:3, :3] @ T[:3, :3].T)])


def inverse(robot, T_goal, q0=None, *, tol_pos: float = 1e-6, tol_rot: float = 1e-6,
            max_iter: int = 200, restarts: int = 20, seed: int = 0,
            position_only: bool = False) -> np.ndarray:
    """Joint angles that place the tool point at ``T_goal``.

    Parameters
    ----------
    robot : Robot or str
    T_goal : array_like, shape (4, 4)
        Goal pose in the world frame (metres).
    q0 : array_like, shape (n,), optional
        First guess (the robot's home posture if omitted).
    tol_pos, tol_rot : float
        Tolerances on the position (m) and rotation (rad) error.
    max_iter : int
        Iterations per attempt.
    restarts : int
        Seeded random restarts within the joint limits after the first attempt fails.
    seed : int
        Seed of the restarts (same inputs and seed → same answer).
    position_only : bool
        Solve for the position alone (for arms with fewer than six joints).

    Returns
    -------
    ndarray, shape (n,), rad

    Raises
    ------
    UnreachablePose
        No attempt converged; the message gives the smallest residual found.
    """
    robot = load_robot(robot)
    T_goal = np.asarray(T_goal, dtype=float)
    if T_goal.shape != (4, 4) or not np.all(np.isfinite(T_goal)):
        raise InputError("pose", "must be a finite 4×4 homogeneous matrix")
    lim = robot.joint_limits
    q_start = robot.home.copy() if q0 is None else _joint_vector(robot, q0)
    rng = np.random.default_rng(seed)
    rows = slice(0, 3) if position_only else slice(0, 6)
    best = (math.inf, math.inf, None)
    for attempt in range(restarts + 1):
        q = np.clip(q_start if attempt == 0 else rng.uniform(-lim, lim), -lim, lim)
        lam = 1e-2
        err = pose_error(T_goal, robot.tip_pose(q))[rows]
        cost = float(err @ err)
        for _ in range(max_iter):
            e_pos = np.linalg.norm(err[:3])
            e_rot = 0.0 if position_only else np.linalg.norm(err[3:])
            if e_pos < tol_pos and e_rot < tol_rot:
                return q
            J = jacobian(robot, q)[rows]
            step = J.T @ np.linalg.solve(J @ J.T + lam * np.eye(J.shape[0]), err)
            q_new = np.clip(q + step, -lim, lim)
            err_new = pose_error(T_goal, robot.tip_pose(q_new))[rows]
            cost_new = float(err_new @ err_new)
            if cost_new < cost:
                q, err, cost = q_new, err_new, cost_new
                lam = max(lam / 3.0, 1e-9)
            else:
                lam = min(lam * 5.0, 1e3)
        e_pos = float(np.linalg.norm(err[:3]))
        e_rot = 0.0 if position_only else float(np.linalg.norm(err[3:]))
        if e_pos < tol_pos and e_rot < tol_rot:
            return q
        if e_pos + e_rot < best[0] + best[1]:
            best = (e_pos, e_rot, q)
    raise UnreachablePose(
        "pose", f"unreachable by {robot.name}: best residual {best[0]:.3g} m, "
        f"{best[1]:.3g} rad after {restarts + 1} attempts within the joint limits")


def _joint_vector(robot: Robot, q) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.shape != (robot.n,):
        raise InputError("q", f"must have {robot.n} joint angles, not shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise InputError("q", "must be finite")
    return q
