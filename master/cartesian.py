"""From a planned Cartesian line to joint references the closed loop can follow.

The planner (:mod:`master.trig_planner`, :mod:`master.ruckig_profile`) gives the tool pose and
its first three derivatives at every sample. This module turns them into joint references:

1. **Inverse kinematics, one branch.** The first pose is solved from a seed posture (the
   robot's home unless given, with :func:`master.kinematics.inverse`); every later sample by
   damped least squares seeded from the
   second-order Taylor prediction ``q + q̇ dt + q̈ dt²/2`` of the previous sample. On one
   continuous branch the solution differs from the prediction by about ``|q⃛| dt³/6``
   (2·10⁻⁷ rad at 1000 rad/s³ and 1 ms); a solution further than ``branch_tolerance``
   (10⁻³ rad) is refused as a branch jump (:class:`BranchJump`). The damping (Chiaverini's,
   on the length-scaled Jacobian) is zero while its σ_min ≥ 0.005; below that the condition
   check refuses the path anyway, and the damping only keeps the iteration bounded so that
   the refusal names the right sample. On accepted paths the iterations are therefore
   Newton's and converge quadratically to ‖e‖ ≈ 10⁻¹⁶ (stopping below 10⁻¹³ or when rounding
   stops the decrease); a residual above 10⁻⁹ means the path left the workspace.
2. **Exact differential kinematics at every sample** (world-aligned twist at the tool point,
   ``[v; ω] = J q̇``, pinocchio's ``LOCAL_WORLD_ALIGNED`` frame Jacobian)::

       q̇ = J⁻¹ [v; ω]
       q̈ = J⁻¹ ([a; α] − c(q, q̇))                c = J̇ q̇, the classical-acceleration drift
       q⃛ = J⁻¹ ([j; α̇] − D(q, q̇, q̈))            D = d/dt (J q̈ + c) at fixed q̈

   ``c`` is pinocchio's frame classical acceleration at ``q̈ = 0``; ``D`` is its directional
   derivative along ``(q̇, q̈)``, by Richardson-extrapolated central differences (steps 10⁻⁴
   and 2·10⁻⁴ s; truncation O(h⁴), rounding about 10⁻¹² relative).
3. **A C³ reference.** Between samples the reference is the septic Hermite polynomial that
   matches q, q̇, q̈ and q⃛ at both ends, so the joint jerk is continuous everywhere and equals
   the exact joint jerk at every sample; q, q̇, q̈ at the samples are exact (not fitted).
   A spline through the IK positions alone would be smoother than the data only by luck: its
   derivatives are those of the fit, not of the motion, and its end conditions are guesses.
   Here nothing is guessed: the planner's jerk continuity carries over wherever J is
   invertible, and a planner jerk jump (Ruckig's piecewise-constant jerk) shows as a jump of
   the joint jerk between two samples, reported by :meth:`JointReference.jerk_jump`.

Checks, each an :class:`~mrm_cosim.errors.InputError` naming the sample time and the limit:
the path leaves the workspace (:class:`UnreachablePose`), comes near a singularity
(:class:`SingularPath`: the condition number of the length-scaled Jacobian
``diag(I/L, I) J``, L the sum of the module lengths, above ``max_condition`` = 200), leaves a
joint's range or needs more than its ``max_speed`` (:class:`JointLimitError`), or the robot
has not six joints for a six-dimensional line (:class:`TaskDimensionError`).

Imports no gateware: pinocchio (through :meth:`models.robot.Robot.pinocchio_model`) and numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mrm_cosim.errors import InputError, require_positive
from mrm_cosim.master import quaternion as quat
from mrm_cosim.master.kinematics import UnreachablePose, inverse, rotation_log
from mrm_cosim.master.trig_planner import sample_times
from mrm_cosim.models.robot import Robot, load_robot

__all__ = ["JointReference", "joint_reference", "TaskDimensionError", "SingularPath",
           "JointLimitError", "BranchJump", "UnreachablePose", "ToolErrors", "tool_errors",
           "se3_log", "MAX_CONDITION", "BRANCH_TOLERANCE", "IK_TOLERANCE"]

#: Largest condition number of the length-scaled Jacobian a path may reach.
MAX_CONDITION = 200.0
#: Largest distance (rad, any joint) between an IK solution and its Taylor prediction.
BRANCH_TOLERANCE = 1e-3
#: Convergence of the per-sample IK: ‖[p_d − p; log(R_d Rᵀ)]‖ (m and rad).
IK_TOLERANCE = 1e-13
_DAMPING_SIGMA = 5e-3        # σ₀ of the damped least squares (length-scaled Jacobian)
_DAMPING_MAX = 1e-2          # λ² at σ_min = 0
_MAX_ITER = 50
_JERK_STEP = 1e-4            # s, central-difference step of D(q, q̇, q̈)


class TaskDimensionError(InputError):
    """The task has more (or fewer) dimensions than the robot has joints."""


class SingularPath(InputError):
    """The path comes too close to a singular posture (joint speeds would grow unbounded)."""


class JointLimitError(InputError):
    """The path needs a joint beyond its range or faster than its maximum speed."""


class BranchJump(InputError):
    """The IK solution of a sample is not the continuation of the previous sample's branch."""


class _Chain:
    """Pinocchio kinematics of the tool point, world-aligned (``[v; ω]`` convention)."""

    def __init__(self, robot: Robot):
        import pinocchio as pin

        self.pin = pin
        self.model = robot.pinocchio_model()
        self.data = self.model.createData()
        self.frame = self.model.getFrameId("tool")
        self.frame_type = pin.LOCAL_WORLD_ALIGNED
        reach = sum(m.type.length_a + m.type.length_b for m in robot.modules)
        self.scale = np.concatenate([np.full(3, 1.0 / reach), np.ones(3)])
        self.zero = np.zeros(robot.n)

    def pose(self, q) -> np.ndarray:
        self.pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self.frame].homogeneous

    def jacobian(self, q) -> np.ndarray:
        return self.pin.computeFrameJacobian(self.model, self.data, q, self.frame,
                                             self.frame_type)

    def acceleration(self, q, qd, qdd) -> np.ndarray:
        """``[p̈; ω̇]`` of the tool point (world axes) for joint motion (q, q̇, q̈)."""
        pin = self.pin
        pin.forwardKinematics(self.model, self.data, q, qd, qdd)
        pin.updateFramePlacement(self.model, self.data, self.frame)
        return pin.getFrameClassicalAcceleration(self.model, self.data, self.frame,
                                                 self.frame_type).vector

    def condition(self, J) -> float:
        s = np.linalg.svd(self.scale[:, None] * J, compute_uv=False)
        return math.inf if s[-1] == 0.0 else float(s[0] / s[-1])


def _pose_error(T_goal, T) -> np.ndarray:
    return np.concatenate([T_goal[:3, 3] - T[:3, 3], rotation_log(T_goal[:3, :3] @ T[:3, :3].T)])


def _solve(chain: _Chain, T_goal, q) -> tuple[np.ndarray, float]:
    """Damped least squares from ``q`` to ``T_goal``; returns (q, final error norm)."""
    err = _pose_error(T_goal, chain.pose(q))
    for _ in range(_MAX_ITER):
        if np.linalg.norm(err) < IK_TOLERANCE:
            break
        J = chain.jacobian(q)
        Js = chain.scale[:, None] * J
        sigma = np.linalg.svd(Js, compute_uv=False)[-1]
        lam2 = _DAMPING_MAX * max(0.0, 1.0 - (sigma / _DAMPING_SIGMA) ** 2)
        step = Js.T @ np.linalg.solve(Js @ Js.T + lam2 * np.eye(6), chain.scale * err)
        q_new = q + step
        err_new = _pose_error(T_goal, chain.pose(q_new))
        if np.linalg.norm(err_new) >= np.linalg.norm(err) and np.linalg.norm(err) < 1e-9:
            break                      # at the rounding floor
        q, err = q_new, err_new
    return q, float(np.linalg.norm(err))


@dataclass(frozen=True)
class JointReference:
    """Joint references through IK samples of a Cartesian move, C³ between samples.

    Implements the joint-profile interface of the closed loop: :meth:`evaluate` like
    :class:`master.quintic.QuinticProfile`, :meth:`trajectory` for the loop's per-cycle call.

    Attributes
    ----------
    t : ndarray, shape (m,), s
        Sample times (uniform, from 0; the last one at rest at the end pose).
    q, qd, qdd, qddd : ndarray, shape (m, n)
        Joint positions (rad) and their exact first three derivatives at the samples.
    condition : ndarray, shape (m,)
        Condition number of the length-scaled Jacobian at each sample.
    ik_residual : float
        Largest IK pose-error norm over the samples (m and rad mixed, ≤ 10⁻⁹ by construction).
    duration : float, s
        The planned move's duration (the last sample lies at or after it, at rest).
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    qddd: np.ndarray
    condition: np.ndarray
    ik_residual: float
    duration: float

    def evaluate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, acceleration and jerk at times ``t``.

        Parameters
        ----------
        t : float or ndarray, shape (k,), s
            Before 0 the reference rests at the first sample, after the last at the last.

        Returns
        -------
        q, qd, qdd, qddd : ndarray, shape (k, n)
            rad, rad/s, rad/s², rad/s³.
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if t.ndim != 1 or not np.all(np.isfinite(t)):
            raise InputError("t", "must be a finite scalar or 1-D array")
        m = len(self.t)
        if m == 1:
            z = np.zeros((len(t), self.q.shape[1]))
            return self.q[[0] * len(t)], z, z.copy(), z.copy()
        h = self.t[1] - self.t[0]
        tc = np.clip(t, self.t[0], self.t[-1])
        i = np.clip(((tc - self.t[0]) / h).astype(int), 0, m - 2)
        u = ((tc - self.t[i]) / h)[:, None]
        c = _hermite7(self, i, h)                       # (k, 8, n) in powers of u
        out = []
        for order in range(4):
            coeff = c[:, order:, :] * _FALLING[order][None, order:, None]
            value = np.zeros_like(c[:, 0, :])
            for k in range(coeff.shape[1] - 1, -1, -1):
                value = value * u + coeff[:, k, :]
            out.append(value / h**order)
        inside = ((t >= self.t[0]) & (t <= self.t[-1]))[:, None]
        return out[0], *(np.where(inside, x, 0.0) for x in out[1:])

    def trajectory(self):
        """``t -> (q, q̇, q̈)``, each shape (n,): what the closed loop calls every cycle."""
        def trajectory(t):
            q, qd, qdd, _ = self.evaluate(np.array([t]))
            return q[0], qd[0], qdd[0]
        return trajectory

    def jerk_jump(self) -> dict:
        """Largest change of joint jerk between neighbouring samples.

        A jerk continuous in time changes by at most ``max|q⁗| dt`` per step, so the figure
        falls with the sample step; a jerk jump (a planner with piecewise-constant jerk, or a
        jump of the Cartesian jerk) stays the same size at any step.

        Returns
        -------
        dict
            ``jump_rad_s3`` (largest |Δq⃛|), ``joint`` (1-based), ``t_s`` (the later sample),
            ``dt_s`` and ``peak_jerk_rad_s3`` (largest |q⃛| for scale).
        """
        if len(self.t) < 2:
            return {"jump_rad_s3": 0.0, "joint": 1, "t_s": 0.0, "dt_s": 0.0,
                    "peak_jerk_rad_s3": 0.0}
        d = np.abs(np.diff(self.qddd, axis=0))
        k, j = np.unravel_index(int(np.argmax(d)), d.shape)
        return {"jump_rad_s3": float(d[k, j]), "joint": int(j) + 1,
                "t_s": float(self.t[k + 1]), "dt_s": float(self.t[1] - self.t[0]),
                "peak_jerk_rad_s3": float(np.abs(self.qddd).max())}

    def summary(self) -> dict:
        """Peaks per joint and the checks' figures (JSON-ready, SI units)."""
        return {"duration_s": self.duration,
                "samples": len(self.t),
                "dt_s": float(self.t[1] - self.t[0]) if len(self.t) > 1 else 0.0,
                "peak_speed_rad_s": np.abs(self.qd).max(axis=0).tolist(),
                "peak_acceleration_rad_s2": np.abs(self.qdd).max(axis=0).tolist(),
                "peak_jerk_rad_s3": np.abs(self.qddd).max(axis=0).tolist(),
                "jerk_jump": self.jerk_jump(),
                "max_condition": float(self.condition.max()),
                "ik_residual": self.ik_residual}


# Septic Hermite basis: p(u) = Σ c_k u^k on [0, 1] with p, p', p'', p''' given at both ends
# (derivatives in u, i.e. scaled by h, h², h³). c_0..c_3 follow from u = 0; c_4..c_7 solve
# the 4×4 system of the conditions at u = 1.
_FALLING = [np.array([math.perm(k, r) for k in range(8)], dtype=float) for r in range(4)]
_END = np.array([[math.perm(k, r) for k in range(4, 8)] for r in range(4)], dtype=float)
_END_INV = np.linalg.inv(_END)
_START_TAIL = np.array([[math.perm(k, r) for k in range(4)] for r in range(4)], dtype=float)


def _hermite7(ref: JointReference, i, h: float) -> np.ndarray:
    """Coefficients (k, 8, n) of the septic Hermite polynomials on intervals ``i``."""
    scale = np.array([1.0, h, h * h, h**3])[None, :, None]
    d0 = np.stack([ref.q[i], ref.qd[i], ref.qdd[i], ref.qddd[i]], axis=1) * scale
    d1 = np.stack([ref.q[i + 1], ref.qd[i + 1], ref.qdd[i + 1], ref.qddd[i + 1]], axis=1) * scale
    low = d0 / np.array([1.0, 1.0, 2.0, 6.0])[None, :, None]
    rest = d1 - np.einsum("rk,ikn->irn", _START_TAIL, low)
    high = np.einsum("kr,irn->ikn", _END_INV, rest)
    return np.concatenate([low, high], axis=1)


def joint_reference(robot, plan, dt: float = 1e-3, q_seed=None, *,
                    max_condition: float = MAX_CONDITION,
                    branch_tolerance: float = BRANCH_TOLERANCE) -> JointReference:
    """Joint references that make ``robot``'s tool follow a planned Cartesian line.

    Parameters
    ----------
    robot : Robot or str
        Must have six joints (the line fixes position and orientation).
    plan : LinePlan or RuckigLinePlan
        Anything with ``duration`` and ``sample(t) -> CartesianSamples``.
    dt : float, s
        Sample step of the IK (the reference is C³ in between).
    q_seed : array_like, shape (6,), rad, optional
        Posture that selects the branch at the start pose (default: the robot's home).
    max_condition : float
        Largest condition number of the length-scaled Jacobian allowed on the path.
    branch_tolerance : float, rad
        Largest distance of an IK solution from its Taylor prediction.

    Returns
    -------
    JointReference

    Raises
    ------
    TaskDimensionError, UnreachablePose, SingularPath, JointLimitError, BranchJump
        One line naming the sample time and the limit.
    """
    robot = load_robot(robot)
    if robot.n != 6:
        raise TaskDimensionError(
            "robot", f"a Cartesian line fixes 6 coordinates (position and orientation); "
            f"{robot.name} has {robot.n} joints, so it needs exactly 6")
    dt = require_positive(dt, "dt")
    max_condition = require_positive(max_condition, "max_condition")
    branch_tolerance = require_positive(branch_tolerance, "branch_tolerance")
    chain = _Chain(robot)
    lim, vmax = robot.joint_limits, robot.max_speeds
    t = sample_times(plan.duration, dt)
    cs = plan.sample(t)
    twist = np.hstack([cs.velocity, cs.angular_velocity])
    accel = np.hstack([cs.acceleration, cs.angular_acceleration])
    jerk = np.hstack([cs.jerk, cs.angular_jerk])
    goals = np.zeros((len(t), 4, 4))
    goals[:, 3, 3] = 1.0
    goals[:, :3, 3] = cs.position
    for k, qk in enumerate(cs.quaternion):
        goals[k, :3, :3] = quat.to_matrix(qk)
    seed = robot.home if q_seed is None else np.asarray(q_seed, dtype=float)
    if seed.shape != (6,) or not np.all(np.isfinite(seed)):
        raise InputError("q_seed", f"must be 6 finite joint angles, not {q_seed!r}")
    for field, T in (("start.pose", goals[0]), ("end.pose", goals[-1])):
        try:
            q_end = inverse(robot, T, seed)
        except UnreachablePose as exc:
            raise UnreachablePose(field, f"outside the workspace of {robot.name}: "
                                  f"{exc.message.split(': ', 1)[-1]}") from None
        if field == "start.pose":
            q_start = q_end
    m, n = len(t), 6
    Q, QD, QDD, QDDD = (np.zeros((m, n)) for _ in range(4))
    cond = np.zeros(m)
    residual = 0.0
    for k in range(m):
        where = f"sample t = {t[k]:.6g} s"
        if k == 0:
            q, res = _solve(chain, goals[0], q_start)
        else:
            pred = Q[k - 1] + QD[k - 1] * dt + 0.5 * QDD[k - 1] * dt * dt
            q, res = _solve(chain, goals[k], pred)
            if res > 1e-9:
                raise UnreachablePose(
                    where, f"the path leaves the workspace of {robot.name} (IK residual "
                    f"{res:.3g} from the previous sample's branch; a posture too close to a "
                    "singularity to solve gives this too)")
            miss = np.abs(q - pred)
            if miss.max() > branch_tolerance:
                j = int(np.argmax(miss))
                raise BranchJump(
                    where, f"the IK solution jumps to another branch: joint {j + 1} lands "
                    f"{miss[j]:.3g} rad from the continuation of t = {t[k - 1]:.6g} s "
                    f"(branch_tolerance {branch_tolerance:g} rad); a finer dt or another "
                    "path avoids it")
        residual = max(residual, res)
        J = chain.jacobian(q)
        cond[k] = chain.condition(J)
        if not cond[k] <= max_condition:
            raise SingularPath(
                where, f"the path comes near a singular posture of {robot.name}: condition "
                f"number {cond[k]:.3g} of the length-scaled Jacobian > {max_condition:g} "
                f"(max_condition); joint speeds grow without bound there")
        over = np.abs(q) - lim
        if over.max() > 0.0:
            j = int(np.argmax(over))
            raise JointLimitError(
                where, f"joint {j + 1} at {math.degrees(q[j]):.2f}° is outside its range "
                f"±{math.degrees(lim[j]):g}° (joint_limit)")
        qd = np.linalg.solve(J, twist[k])
        fast = np.abs(qd) / vmax
        if fast.max() > 1.0:
            j = int(np.argmax(fast))
            raise JointLimitError(
                where, f"joint {j + 1} would turn at {abs(qd[j]):.3g} rad/s, faster than its "
                f"max_speed {vmax[j]:.3g} rad/s; slow the line's limits")
        qdd = np.linalg.solve(J, accel[k] - chain.acceleration(q, qd, chain.zero))
        qddd = np.linalg.solve(J, jerk[k] - _drift_rate(chain, q, qd, qdd))
        Q[k], QD[k], QDD[k], QDDD[k] = q, qd, qdd, qddd
    return JointReference(t, Q, QD, QDD, QDDD, cond, residual, float(plan.duration))


def _drift_rate(chain: _Chain, q, qd, qdd) -> np.ndarray:
    """``D = d/dt (J q̈ + J̇ q̇)`` at fixed q̈: Richardson-extrapolated central differences."""
    if not np.any(qd) and not np.any(qdd):
        return np.zeros(6)

    def central(h):
        up = chain.acceleration(q + h * qd, qd + h * qdd, qdd)
        down = chain.acceleration(q - h * qd, qd - h * qdd, qdd)
        return (up - down) / (2.0 * h)

    return (4.0 * central(_JERK_STEP) - central(2.0 * _JERK_STEP)) / 3.0


# --------------------------------------------------------------------------- error reporting
@dataclass(frozen=True)
class ToolErrors:
    """Tool-pose errors of an actual joint trajectory against the desired one.

    Attributes
    ----------
    position_mm : ndarray, shape (k,)
        ‖p_a − p_d‖, mm.
    orientation_mrad : ndarray, shape (k,)
        Angle of R_dᵀ R_a, mrad.
    se3 : ndarray, shape (k,)
        ‖log(T_d⁻¹ T_a)‖ of the 6-vector [v (m); ω (rad)] (dimensionless mix, as in the
        motion-primitive paper's se(3) error).
    tool_desired, tool_actual : ndarray, shape (k, 3), m
        Tool positions (for a 3-D path plot).
    """

    position_mm: np.ndarray
    orientation_mrad: np.ndarray
    se3: np.ndarray
    tool_desired: np.ndarray
    tool_actual: np.ndarray

    def summary(self) -> dict:
        return {"max_position_error_mm": float(self.position_mm.max()),
                "rms_position_error_mm": float(np.sqrt(np.mean(self.position_mm**2))),
                "max_orientation_error_mrad": float(self.orientation_mrad.max()),
                "max_se3_error": float(self.se3.max())}


def se3_log(T) -> np.ndarray:
    """Logarithm of a rigid transform: the twist [v; ω] with exp([v; ω]^) = T.

    Parameters
    ----------
    T : array_like, shape (4, 4)

    Returns
    -------
    ndarray, shape (6,)
        ``v`` (m) first, then ``ω`` (rad) — pinocchio's ``log6(...).vector`` order.
        ``ω = log(R)``; ``v = V(ω)⁻¹ p`` with
        ``V⁻¹ = I − ½[ω]× + (1/θ²)(1 − θ sin θ / (2(1 − cos θ)))[ω]×²``.
    """
    T = np.asarray(T, dtype=float)
    w = rotation_log(T[:3, :3])
    theta = float(np.linalg.norm(w))
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if theta < 1e-5:       # series of the coefficient: 1/12 + θ²/720
        coef = 1.0 / 12.0 + theta * theta / 720.0
    else:
        coef = (1.0 - theta * math.sin(theta) / (2.0 * (1.0 - math.cos(theta)))) / theta**2
    V_inv = np.eye(3) - 0.5 * W + coef * (W @ W)
    return np.concatenate([V_inv @ T[:3, 3], w])


def tool_errors(robot, q_desired, q_actual) -> ToolErrors:
    """Cartesian errors of the tool over time from desired and actual joint trajectories.

    Parameters
    ----------
    robot : Robot or str
    q_desired, q_actual : array_like, shape (k, n), rad
        Time-major joint trajectories on the same time grid.

    Returns
    -------
    ToolErrors
    """
    robot = load_robot(robot)
    qd = np.asarray(q_desired, dtype=float)
    qa = np.asarray(q_actual, dtype=float)
    if qd.ndim != 2 or qd.shape[1] != robot.n or qd.shape != qa.shape:
        raise InputError("q_actual", f"desired and actual must both have shape (k, {robot.n}), "
                         f"not {qd.shape} and {qa.shape}")
    chain = _Chain(robot)
    k = len(qd)
    pos, ori, se3 = np.zeros(k), np.zeros(k), np.zeros(k)
    tip_d, tip_a = np.zeros((k, 3)), np.zeros((k, 3))
    for i in range(k):
        Td = chain.pose(qd[i]).copy()
        Ta = chain.pose(qa[i]).copy()
        tip_d[i], tip_a[i] = Td[:3, 3], Ta[:3, 3]
        pos[i] = 1e3 * np.linalg.norm(Ta[:3, 3] - Td[:3, 3])
        ori[i] = 1e3 * np.linalg.norm(rotation_log(Td[:3, :3].T @ Ta[:3, :3]))
        rel = np.eye(4)                              # T_d⁻¹ T_a of rigid transforms
        rel[:3, :3] = Td[:3, :3].T @ Ta[:3, :3]
        rel[:3, 3] = Td[:3, :3].T @ (Ta[:3, 3] - Td[:3, 3])
        se3[i] = np.linalg.norm(se3_log(rel))
    return ToolErrors(pos, ori, se3, tip_d, tip_a)
