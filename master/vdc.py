"""The master's share of virtual decomposition control, in float: kinematics base → tip and
required force propagation tip → base (DESIGN.md "VDC in equations", MRM paper steps 2 and 6).

Per module k the frames are {C_k} (Link b, proximal) and {A_k} (Link a, distal), sharing the
joint origin with ``ᶜR_A = Rz(q_k)``; {C_k+1} is fixed in {A_k} by the robot's mount transform.
Velocities are ``V = [v; ω]`` in the frame they belong to, forces ``F = [f; m]``.

* Across a rigid mount (pose ``(R, r)`` of the child in the parent): ``V_c = Uᵀ V_p`` and, as U
  is constant, ``V̇_c = Uᵀ V̇_p`` (body-coordinate derivatives).
* Across joint k with ``U_q = diag(Rz(q), Rz(q))`` (no offset): ``V_A = U_qᵀ V_C + z q̇`` and
  ``V̇_A = U_qᵀ V̇_C − q̇ Z U_qᵀ V_C + z q̈`` with ``Z = diag(ẑ×, ẑ×)`` (``d Rzᵀ/dt = −q̇ ẑ× Rzᵀ``).
  Required quantities use q̇_r, q̈_r in place of q̇, q̈ but the actual q̇ in the rotating term.
* Gravity enters as an upward acceleration of the base, ``V̇_0 = [0, 0, 9.81, 0, 0, 0]``
  (RNEA's ``a₀ = −g``), so link dynamics need no separate gravity vector.
* Each link's required net force ``F*`` (:func:`link_required_forces`); the force a module's
  subtree needs at {A_k} is ``F_A,k = F*_a,k + U_mount F_C,k+1`` and at {C_k}
  ``F_C,k = F*_b,k + U_q F_A,k``; the joint's required load torque is ``τ_Lr,k = zᵀ F_A,k``.

:func:`inverse_dynamics` runs the chain with required = actual and no feedback; it equals
pinocchio's ``rnea`` (tests/test_vdc_master.py), which is how the bookkeeping of frames and
forces is known to be right, and how users check a new robot description.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mrm_cosim.models.robot import load_robot
from mrm_cosim.models.spatial import rigid_body_wrench
from mrm_cosim.errors import InputError

__all__ = ["ModuleKinematics", "required_velocities", "propagate_velocities", "velocity_chain",
           "link_required_forces", "propagate_forces", "force_chain", "joint_rotations",
           "inverse_dynamics", "BASE_ACCELERATION"]

BASE_ACCELERATION = np.array([0.0, 0.0, 9.81, 0.0, 0.0, 0.0])


def _mount_U(T) -> np.ndarray:
    R, r = T[:3, :3], T[:3, 3]
    rx = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
    U = np.zeros((6, 6))
    U[:3, :3] = R
    U[3:, :3] = rx @ R
    U[3:, 3:] = R
    return U


def _mount_U_of(robot, k: int) -> np.ndarray:
    """``_mount_U(robot.mount_transform(k))``, memoised on the transform's value (read it, do
    not write it)."""
    T = robot.mount_transform(k)
    key = T.tobytes()
    memo = robot.__dict__.setdefault("_mount_Us", {})
    hit = memo.get(k)
    if hit is None or hit[0] != key:
        hit = memo[k] = (key, _mount_U(T))
    return hit[1]


def mounts(robot) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Every mount's transform and its 6×6 velocity transform:
    ``([robot.mount_transform(k)], [_mount_U_of(robot, k)])`` for k = 0 … n−1, memoised on
    what the mounts are made of (the base's value, the modules: frozen), so the master's
    chains look them up once a call (read them, do not write them)."""
    base, modules = robot.base.tobytes(), robot.modules
    hit = robot.__dict__.get("_mounts_all")
    if hit is None or hit[0] != base or len(hit[1]) != len(modules) or \
            any(a is not b for a, b in zip(hit[1], modules, strict=True)):
        Ts = [robot.mount_transform(k) for k in range(robot.n)]
        hit = robot.__dict__["_mounts_all"] = (base, tuple(modules), Ts,
                                               [_mount_U(T) for T in Ts])
    return hit[2], hit[3]


@dataclass
class ModuleKinematics:
    """Actual and required 6-D velocities (and required accelerations) of one module's frames.

    Attributes (all shape (6,), body coordinates of the named frame)
    ----------
    V_C, V_A : actual velocities of {C_k} and {A_k}
    Vr_C, Vr_A : required velocities
    dVr_C, dVr_A : time derivatives of the required velocities, gravity included
    """

    V_C: np.ndarray
    V_A: np.ndarray
    Vr_C: np.ndarray
    Vr_A: np.ndarray
    dVr_C: np.ndarray
    dVr_A: np.ndarray


def required_velocities(q_d, qd_d, qdd_d, q, qd, lam: float, base_fb: float = 1.0):
    """The master's required joint velocities and accelerations for the link level, and the
    actual velocities it propagates: ``(q̇_r, q̈_r, q̇)``, each shape (n,).

    ``q̇_r = q̇_d + λ (q_d − q)``, ``q̈_r = q̈_d + λ (q̇_d − q̇)`` and ``q̇`` the measured one
    (the paper's VDC) — except joint 1 (the base joint) when ``base_fb`` (``w``, 0..1,
    ``Gains.vdc_base_fb``) is below 1: ``q̇_r,1 = q̇_d,1 + w λ (q_d,1 − q_1)``,
    ``q̈_r,1 = q̈_d,1 + w λ (q̇_d,1 − q̇_1)`` and the propagated ``q̇_1 = q̇_d,1 + w (q̇_1 −
    q̇_d,1)``, so every link's ``V_r − V`` (and the nodes' differenced ``V̇_r``) carries ``w``
    times joint 1's error. At ``w = 0`` the link level is a feedforward of joint 1's desired
    motion: joint 1's feedback is the node's joint law alone, every 1 µs, not through the
    master's 1 ms sample-and-hold (docs/experiments.md "Tuning")."""
    qd_r = qd_d + lam * (q_d - q)
    qdd_r = qdd_d + lam * (qd_d - qd)
    if base_fb == 1.0:
        return qd_r, qdd_r, qd
    w = base_fb
    qd_r, qdd_r, qd_p = qd_r.copy(), qdd_r.copy(), np.array(qd, dtype=float)
    qd_r[0] = qd_d[0] + w * lam * (q_d[0] - q[0])
    qdd_r[0] = qdd_d[0] + w * lam * (qd_d[0] - qd[0])
    qd_p[0] = qd_d[0] + w * (qd[0] - qd_d[0])
    return qd_r, qdd_r, qd_p


def propagate_velocities(robot, q, qd, qd_r, qdd_r) -> list[ModuleKinematics]:
    """Base → tip: actual and required velocities of every {C_k} and {A_k} (MRM step 2).

    Parameters
    ----------
    robot : Robot or str
    q, qd : array_like, shape (n,)
        Actual joint positions (rad) and velocities (rad/s).
    qd_r, qdd_r : array_like, shape (n,)
        Required joint velocities (rad/s) and accelerations (rad/s²).
    """
    robot = load_robot(robot)
    q, qd, qd_r, qdd_r = (_vec(robot, x, name) for x, name in
                          ((q, "q"), (qd, "qd"), (qd_r, "qd_r"), (qdd_r, "qdd_r")))
    return [ModuleKinematics(C[0], A[0], C[1], A[1], C[2], A[2])
            for C, A in velocity_chain(robot, q, qd.tolist(), qd_r.tolist(), qdd_r.tolist())]


def velocity_chain(robot, q, qd, qd_r, qdd_r) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`propagate_velocities` without its checks, for the master's once-a-period call:
    per module the rows ``(V_C, Vr_C, dVr_C)`` and ``(V_A, Vr_A, dVr_A)`` as two 3×6 arrays.

    ``q`` an array (rad), ``qd``, ``qd_r``, ``qdd_r`` sequences of floats, all of ``robot.n``
    finite values.
    """
    # The three chains (V, V_r, V̇_r) go through each mount as one 3×6 product (rows are the
    # vectors: ``S @ U = (Uᵀ Sᵀ)ᵀ``) and through each joint as a 6×3 product with Rz
    # (``diag(Rz, Rz)ᵀ`` on each [v; ω]), not as nine 6×6 ones. The products stay BLAS's
    # (which may fuse and order the sums its own way: the nodes get these floats), called
    # through ``ndarray.dot``, the same BLAS call as ``@`` with less of numpy around it.
    Rz = joint_rotations(q)
    S = np.zeros((3, 6))
    S[2] = BASE_ACCELERATION
    out = []
    for k, U in enumerate(mounts(robot)[1]):
        C = S.dot(U)                                    # rows V_C, Vr_C, dVr_C
        V, Vr, dVr = C.reshape(6, 3).dot(Rz[k]).reshape(3, 6).tolist()   # Uqᵀ of each row
        qd_k = qd[k]
        # − q̇ Z Uqᵀ Vr_C with Z Uqᵀ Vr_C = (−a1, a0, 0, −a4, a3, 0), a = Uqᵀ Vr_C
        dVr[0] -= qd_k * -Vr[1]
        dVr[1] -= qd_k * Vr[0]
        dVr[3] -= qd_k * -Vr[4]
        dVr[4] -= qd_k * Vr[3]
        V[5] += qd_k                                    # + z q̇, z q̇_r, z q̈_r
        Vr[5] += qd_r[k]
        dVr[5] += qdd_r[k]
        S = np.array((V, Vr, dVr))                      # rows V_A, Vr_A, dVr_A
        out.append((C, S))
    return out


def _rot_z(q: float) -> np.ndarray:
    c, s = np.cos(q), np.sin(q)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def joint_rotations(q) -> np.ndarray:
    """Every joint's ``Rz(q_k)``, as one (n, 3, 3) array: ``[_rot_z(q_k) for k]``, built with
    one ``cos`` and one ``sin`` over ``q`` (the same floats: each element is the same ufunc's
    result)."""
    c, s = np.cos(q), np.sin(q)
    R = np.zeros((len(c), 3, 3))
    R[:, 0, 0] = c
    R[:, 0, 1] = -s
    R[:, 1, 0] = s
    R[:, 1, 1] = c
    R[:, 2, 2] = 1.0
    return R


def link_required_forces(theta_a, theta_b, kin: ModuleKinematics, K_a=None, K_b=None):
    """Required net force/moment of Link a (in {A_k}) and Link b (in {C_k}) — the slave's step 4.

    ``F* = Y(ω, V_r, V̇_r) θ + K (V_r − V)`` with gravity carried by ``V̇_r``.

    Parameters
    ----------
    theta_a, theta_b : array_like, shape (13,)
        Parameter estimates of Link a ({A_k}) and Link b ({C_k}).
    kin : ModuleKinematics
    K_a, K_b : array_like, shape (6, 6) or (6,), optional
        Velocity-error feedback gains (zero when omitted).

    Returns
    -------
    F_a, F_b : ndarray, shape (6,)
    """
    zero = np.zeros(3)
    F_a = rigid_body_wrench(theta_a, kin.V_A[3:], kin.Vr_A, kin.dVr_A, zero)
    F_b = rigid_body_wrench(theta_b, kin.V_C[3:], kin.Vr_C, kin.dVr_C, zero)
    if K_a is not None:
        F_a = F_a + _gain(K_a) @ (kin.Vr_A - kin.V_A)
    if K_b is not None:
        F_b = F_b + _gain(K_b) @ (kin.Vr_C - kin.V_C)
    return F_a, F_b


def propagate_forces(robot, q, F_a, F_b):
    """Tip → base: required force at every {A_k} and the joints' required load torques (step 6).

    Parameters
    ----------
    robot : Robot or str
    q : array_like, shape (n,), rad
    F_a, F_b : array_like, shape (n, 6)
        Required net forces of Link a ({A_k}) and Link b ({C_k}) of every module.

    Returns
    -------
    F_A : ndarray, shape (n, 6)
        Required force/moment the subtree beyond joint k needs, at {A_k}.
    tau_Lr : ndarray, shape (n,)
        Its projection on the joint axis (what Comm D carries), N·m.
    """
    robot = load_robot(robot)
    q = _vec(robot, q, "q")
    F_a, F_b = np.asarray(F_a, dtype=float), np.asarray(F_b, dtype=float)
    F_A = force_chain(robot, joint_rotations(q), F_a, F_b)
    return F_A, F_A[:, 5].copy()


def force_chain(robot, Rz, F_a, F_b) -> np.ndarray:
    """:func:`propagate_forces`'s ``F_A`` without its checks, for the master's once-a-period
    call: ``Rz`` the joints' rotations (``joint_rotations(q)``), ``F_a``, ``F_b`` (n, 6) arrays."""
    Us = mounts(robot)[1]
    n = robot.n
    F_A = np.zeros((n, 6))
    F_C_next = None
    for k in reversed(range(n)):                # (BLAS's products, as velocity_chain's)
        F = F_a[k].copy()
        if F_C_next is not None:
            F += Us[k + 1].dot(F_C_next)
        F_A[k] = F
        # U_q F = [Rz f; Rz m]: the rows of F as 3-vectors times Rzᵀ
        F_C_next = F_b[k] + F.reshape(2, 3).dot(Rz[k].T).ravel()
    return F_A


def inverse_dynamics(robot, q, qd, qdd) -> np.ndarray:
    """Joint torques of the rigid bodies (no armature, friction or springs) by the VDC chain.

    Runs :func:`propagate_velocities` with required = actual, :func:`link_required_forces`
    with the nominal Table 1 parameters and no feedback, and :func:`propagate_forces`.
    Gravity is −9.81 m/s² along the world z axis.

    Parameters
    ----------
    robot : Robot, built-in name (``"mrm3"``) or path to an assembly TOML
    q, qd, qdd : array_like, shape (n,)
        rad, rad/s, rad/s².

    Returns
    -------
    tau : ndarray, shape (n,), N·m — equal to ``pinocchio.rnea`` on the same robot.
    """
    robot = load_robot(robot)
    kin = propagate_velocities(robot, q, qd, qd, qdd)
    theta = robot.nominal_theta
    forces = [link_required_forces(theta[k, 0], theta[k, 1], kin[k]) for k in range(robot.n)]
    F_a = np.array([f[0] for f in forces])
    F_b = np.array([f[1] for f in forces])
    return propagate_forces(robot, q, F_a, F_b)[1]


def _gain(K) -> np.ndarray:
    K = np.asarray(K, dtype=float)
    return np.diag(K) if K.shape == (6,) else K


def _vec(robot, x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.shape != (robot.n,):
        raise InputError(name, f"must have {robot.n} values, not shape {a.shape}")
    if not np.isfinite(a).all():             # (the method: no dispatch, called every period)
        raise InputError(name, "must be finite")
    return a
