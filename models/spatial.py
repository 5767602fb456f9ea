"""Spatial algebra for virtual decomposition control (VDC).

Conventions (DESIGN.md "VDC in equations"; Zhu 2010, App. A):

* A 6-D velocity is ``V = [v; ω]`` (origin velocity, angular velocity) and a 6-D force is
  ``F = [f; m]``, both expressed in the frame they belong to, linear part first.
* ``ᴬU_B = [[R, 0], [(r×)R, R]]`` with ``R = ᴬR_B`` and ``r = ᴬr_AB`` (origin of B in A).
  Velocities go base → tip as ``ᴮV = ᴬU_Bᵀ ᴬV``; forces go tip → base as ``ᴬF = ᴬU_B ᴮF``.
* A rigid body is described in a frame {A} whose origin need not be its centre of mass by the
  13 parameters of the MRM paper's Table 1 (same order)::

      θ = [m, m rx, m ry, m rz, m rx², m ry², m rz²,
           m rx ry − Ixy, m rx rz − Ixz, m ry rz − Iyz, Ixx, Iyy, Izz]

  where ``I··`` are the entries of the inertia tensor about the centre of mass, in {A}'s axes.
  Its dynamics ``M_A dV/dt + C_A(ω) V + G_A = F*`` are linear in θ:
  ``Y_A(ω, V_r, dV_r/dt, g_A) θ``.
* Pinocchio's 10 dynamic parameters (``Inertia.toDynamicParameters()``) are
  ``[m, m cx, m cy, m cz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` about the frame origin; their relation
  to θ is :func:`theta_to_pinocchio`.

All functions take and return numpy arrays of float64; no function mutates its inputs.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "skew", "transform_U", "velocity_to", "force_to",
    "theta_from_physical", "physical_from_theta", "theta_to_pinocchio",
    "mass_matrix", "coriolis_matrix", "gravity_wrench", "regressor", "rigid_body_wrench",
    "transform_theta", "gravity_in_frame", "N_PARAMS",
]

N_PARAMS = 13


def skew(w) -> np.ndarray:
    """Cross-product matrix: ``skew(w) @ x == np.cross(w, x)``.

    Parameters
    ----------
    w : array_like, shape (3,)
    """
    x, y, z = w
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def transform_U(R, r) -> np.ndarray:
    """The 6×6 transformation matrix ``ᴬU_B = [[R, 0], [(r×)R, R]]``.

    Parameters
    ----------
    R : array_like, shape (3, 3)
        Orientation of frame B in frame A (``ᴬR_B``).
    r : array_like, shape (3,)
        Origin of frame B expressed in frame A (``ᴬr_AB``), m.
    """
    R = np.asarray(R, dtype=float)
    U = np.zeros((6, 6))
    U[:3, :3] = R
    U[3:, :3] = skew(r) @ R
    U[3:, 3:] = R
    return U


def velocity_to(R, r, V_A) -> np.ndarray:
    """Velocity of frame B from that of frame A on the same rigid body: ``ᴮV = ᴬU_Bᵀ ᴬV``.

    Parameters
    ----------
    R, r : see :func:`transform_U`
    V_A : array_like, shape (6,)
        ``[v; ω]`` of frame A expressed in A, m/s and rad/s.
    """
    return transform_U(R, r).T @ np.asarray(V_A, dtype=float)


def force_to(R, r, F_B) -> np.ndarray:
    """Force/moment of frame B expressed at frame A: ``ᴬF = ᴬU_B ᴮF``.

    Parameters
    ----------
    R, r : see :func:`transform_U`
    F_B : array_like, shape (6,)
        ``[f; m]`` acting at the origin of B, expressed in B, N and N·m.
    """
    return transform_U(R, r) @ np.asarray(F_B, dtype=float)


def theta_from_physical(mass: float, com, inertia_c) -> np.ndarray:
    """The 13 parameters from mass, centre of mass and inertia about the centre of mass.

    Parameters
    ----------
    mass : float
        kg.
    com : array_like, shape (3,)
        Centre of mass in the body frame, m.
    inertia_c : array_like, shape (3, 3)
        Inertia tensor about the centre of mass in the body frame's axes, kg·m².
    """
    m = float(mass)
    rx, ry, rz = np.asarray(com, dtype=float)
    Ic = np.asarray(inertia_c, dtype=float)
    return np.array([
        m, m * rx, m * ry, m * rz,
        m * rx * rx, m * ry * ry, m * rz * rz,
        m * rx * ry - Ic[0, 1], m * rx * rz - Ic[0, 2], m * ry * rz - Ic[1, 2],
        Ic[0, 0], Ic[1, 1], Ic[2, 2],
    ])


def _origin_inertia(theta) -> np.ndarray:
    """Inertia about the frame origin, ``J = I_d + (θ₅+θ₆+θ₇)E − Q``."""
    t = np.asarray(theta, dtype=float)
    Q = np.array([[t[4], t[7], t[8]], [t[7], t[5], t[9]], [t[8], t[9], t[6]]])
    return np.diag(t[10:13]) + (t[4] + t[5] + t[6]) * np.eye(3) - Q


def physical_from_theta(theta) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, centre of mass and inertia about the centre of mass from the 13 parameters.

    The body is the one whose identifiable combination (mass, first moment, inertia about the
    frame origin) the 13 parameters define; when θ₅..θ₇ are not exactly ``m r²`` (printed
    tables round them), the returned inertia absorbs the difference.

    Returns
    -------
    mass : float, kg
    com : ndarray, shape (3,), m
    inertia_c : ndarray, shape (3, 3), kg·m²
    """
    t = np.asarray(theta, dtype=float)
    m = float(t[0])
    if m <= 0.0:
        raise ValueError(f"mass must be positive, not {m!r}")
    c = t[1:4] / m
    J = _origin_inertia(t)
    Ic = J - m * (np.dot(c, c) * np.eye(3) - np.outer(c, c))
    return m, c, Ic


def theta_to_pinocchio(theta) -> np.ndarray:
    """Pinocchio's 10 dynamic parameters ``[m, h, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` (origin).

    Order and meaning as ``pinocchio.Inertia.toDynamicParameters()``:
    ``[θ₁, θ₂, θ₃, θ₄, θ₁₁+θ₆+θ₇, −θ₈, θ₁₂+θ₅+θ₇, −θ₉, −θ₁₀, θ₁₃+θ₅+θ₆]``.
    """
    t = np.asarray(theta, dtype=float)
    return np.array([
        t[0], t[1], t[2], t[3],
        t[10] + t[5] + t[6], -t[7], t[11] + t[4] + t[6], -t[8], -t[9], t[12] + t[4] + t[5],
    ])


def transform_theta(theta, R, r) -> np.ndarray:
    """Re-express a body's 13 parameters from frame B into frame A.

    Parameters
    ----------
    theta : array_like, shape (13,)
        Parameters referenced to frame B.
    R, r : see :func:`transform_U` (pose of B in A).
    """
    m, c_B, Ic_B = physical_from_theta(theta)
    R = np.asarray(R, dtype=float)
    return theta_from_physical(m, R @ c_B + np.asarray(r, dtype=float), R @ Ic_B @ R.T)


def gravity_in_frame(R_world_frame, g0: float = 9.81) -> np.ndarray:
    """``g_A = ᴬR_I [0, 0, g₀]ᵀ``: the (upward) gravity vector in a frame's axes.

    Parameters
    ----------
    R_world_frame : array_like, shape (3, 3)
        Orientation of the frame in the inertial frame (``ᴵR_A``); gravity pulls along −z_I.
    """
    return np.asarray(R_world_frame, dtype=float).T @ np.array([0.0, 0.0, g0])


def mass_matrix(theta) -> np.ndarray:
    """``M_A = [[mE, −m(r×)], [m(r×), I_c − m(r×)(r×)]]`` (6×6), from the 13 parameters."""
    t = np.asarray(theta, dtype=float)
    H = skew(t[1:4])
    M = np.zeros((6, 6))
    M[:3, :3] = t[0] * np.eye(3)
    M[:3, 3:] = -H
    M[3:, :3] = H
    M[3:, 3:] = _origin_inertia(t)
    return M


def coriolis_matrix(theta, omega) -> np.ndarray:
    """Skew-symmetric ``C_A(ω)`` (6×6) of the rigid-body equation, from the 13 parameters.

    ``C_A = [[m(ω×), −(ω×)(h×)], [(h×)(ω×), (ω×)I_d + I_d(ω×) + ((Qω)×) − ...]]`` assembled so that
    ``C_A(ω) V`` equals the velocity terms of :func:`regressor` (see its closed form).
    """
    t = np.asarray(theta, dtype=float)
    C = np.zeros((6, 6))
    for i in range(6):
        e = np.zeros(6)
        e[i] = 1.0
        C[:, i] = _wrench(t, omega, e, np.zeros(6), np.zeros(3))
    return C


def gravity_wrench(theta, g_A) -> np.ndarray:
    """``G_A = [m g_A; h × g_A]`` with ``h = m r``."""
    t = np.asarray(theta, dtype=float)
    g = np.asarray(g_A, dtype=float)
    return np.concatenate([t[0] * g, np.cross(t[1:4], g)])


def _wrench(t, omega, V_r, dV_r, g_A) -> np.ndarray:
    """Closed form of ``Y(ω, V_r, dV_r, g_A) θ`` (DESIGN.md, checked against pinocchio)."""
    w = np.asarray(omega, dtype=float)
    v_r, w_r = np.asarray(V_r[:3], dtype=float), np.asarray(V_r[3:], dtype=float)
    dv_r, dw_r = np.asarray(dV_r[:3], dtype=float), np.asarray(dV_r[3:], dtype=float)
    h = t[1:4]
    I_d = t[10:13]
    Q = np.array([[t[4], t[7], t[8]], [t[7], t[5], t[9]], [t[8], t[9], t[6]]])
    J = np.diag(I_d) + (t[4] + t[5] + t[6]) * np.eye(3) - Q
    a = dv_r + np.cross(w, v_r) + np.asarray(g_A, dtype=float)
    f = t[0] * a + np.cross(dw_r, h) + np.cross(w, np.cross(w_r, h))
    n = (np.cross(h, a) + J @ dw_r + np.cross(w, I_d * w_r) + I_d * np.cross(w, w_r)
         + np.cross(Q @ w, w_r))
    return np.concatenate([f, n])


def rigid_body_wrench(theta, omega, V_r, dV_r, g_A) -> np.ndarray:
    """``M_A dV_r/dt + C_A(ω) V_r + G_A``: the (required) net force/moment of a rigid body.

    Parameters
    ----------
    theta : array_like, shape (13,)
    omega : array_like, shape (3,)
        Actual angular velocity of the body, in its frame, rad/s.
    V_r, dV_r : array_like, shape (6,)
        (Required) 6-D velocity ``[v; ω]`` of the frame and its time derivative in body coordinates.
    g_A : array_like, shape (3,)
        :func:`gravity_in_frame` of the body frame, m/s².

    Returns
    -------
    ndarray, shape (6,)
        ``[f; m]`` in the body frame, N and N·m.
    """
    return _wrench(np.asarray(theta, dtype=float), omega, V_r, dV_r, g_A)


def regressor(omega, V_r, dV_r, g_A) -> np.ndarray:
    """The 6×13 regressor ``Y`` with ``Y θ = M_A dV_r/dt + C_A(ω) V_r + G_A``.

    Arguments as :func:`rigid_body_wrench`. Built column by column from the closed form, which
    is linear in θ.
    """
    Y = np.empty((6, N_PARAMS))
    for i in range(N_PARAMS):
        e = np.zeros(N_PARAMS)
        e[i] = 1.0
        Y[:, i] = _wrench(e, omega, V_r, dV_r, g_A)
    return Y
