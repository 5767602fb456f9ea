"""Unit quaternions for orientation planning, in (w, x, y, z) order throughout.

What the trigonometric Cartesian planner (Li et al., seeds/002 §III, eqs. 7–10) needs:
rotation matrix ↔ quaternion, the Hamilton product, the rotation angle between two
orientations along the *shortest* path (eq. 10 with |q1·q2|), spherical linear interpolation
driven by a scalar path parameter, projection of a nearly orthonormal matrix onto SO(3), and the
angular velocity of a moving quaternion.

Conventions: ``R @ v`` rotates a vector from the body frame into the base frame; quaternion
``q`` and ``-q`` are the same rotation; :func:`from_matrix` returns the one with ``w >= 0``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["from_matrix", "to_matrix", "multiply", "conjugate", "normalize",
           "rotation_angle", "relative_axis_angle", "slerp", "project_to_so3",
           "orthonormality_error", "angular_velocity"]


def from_matrix(R) -> np.ndarray:
    """Quaternion of a rotation matrix (Shepperd's method; exact for any angle up to π).

    The paper's eq. (9) divides by ``4s`` with ``s = √(1 + trace)/2``, which fails near a
    half-turn (s → 0); Shepperd's method picks the largest of the four candidates instead.

    Parameters
    ----------
    R : array_like, shape (3, 3)
        Rotation matrix (orthonormal, det +1).

    Returns
    -------
    q : ndarray, shape (4,)
        Unit quaternion (w, x, y, z) with ``w >= 0``.
    """
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3):
        raise ValueError(f"R must have shape (3, 3), not {R.shape}")
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    candidates = (tr, R[0, 0], R[1, 1], R[2, 2])
    k = int(np.argmax(candidates))
    if k == 0:
        r = np.sqrt(1.0 + tr)
        q = np.array([0.5 * r, (R[2, 1] - R[1, 2]) / (2 * r), (R[0, 2] - R[2, 0]) / (2 * r),
                      (R[1, 0] - R[0, 1]) / (2 * r)])
    elif k == 1:
        r = np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = np.array([(R[2, 1] - R[1, 2]) / (2 * r), 0.5 * r, (R[0, 1] + R[1, 0]) / (2 * r),
                      (R[0, 2] + R[2, 0]) / (2 * r)])
    elif k == 2:
        r = np.sqrt(1.0 - R[0, 0] + R[1, 1] - R[2, 2])
        q = np.array([(R[0, 2] - R[2, 0]) / (2 * r), (R[0, 1] + R[1, 0]) / (2 * r), 0.5 * r,
                      (R[1, 2] + R[2, 1]) / (2 * r)])
    else:
        r = np.sqrt(1.0 - R[0, 0] - R[1, 1] + R[2, 2])
        q = np.array([(R[1, 0] - R[0, 1]) / (2 * r), (R[0, 2] + R[2, 0]) / (2 * r),
                      (R[1, 2] + R[2, 1]) / (2 * r), 0.5 * r])
    q = q / np.linalg.norm(q)
    return -q if q[0] < 0.0 else q


def to_matrix(q) -> np.ndarray:
    """Rotation matrix of a unit quaternion.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Quaternion(s) (w, x, y, z); normalised first.

    Returns
    -------
    R : ndarray, shape (..., 3, 3)
    """
    q = normalize(q)
    w, x, y, z = np.moveaxis(q, -1, 0)
    R = np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], axis=-1)
    return R.reshape(q.shape[:-1] + (3, 3))


def multiply(p, q) -> np.ndarray:
    """Hamilton product ``p ⊗ q`` (broadcasts over leading axes), shape (..., 4), (w, x, y, z)."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    pw, pv = p[..., :1], p[..., 1:]
    qw, qv = q[..., :1], q[..., 1:]
    w = pw * qw - np.sum(pv * qv, axis=-1, keepdims=True)
    v = pw * qv + qw * pv + np.cross(pv, qv)
    return np.concatenate([w, v], axis=-1)


def conjugate(q) -> np.ndarray:
    """Conjugate (the inverse of a unit quaternion), shape (..., 4), (w, x, y, z)."""
    q = np.asarray(q, dtype=float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def normalize(q) -> np.ndarray:
    """Unit quaternion(s) along ``q``, shape (..., 4)."""
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def relative_axis_angle(q1, q2) -> tuple[np.ndarray, float]:
    """Shortest rotation taking orientation ``q1`` to ``q2``, as a base-frame axis and angle.

    Parameters
    ----------
    q1, q2 : array_like, shape (4,)
        Unit quaternions (w, x, y, z).

    Returns
    -------
    axis : ndarray, shape (3,)
        Unit axis in the base frame (``q2 = exp(angle/2 · axis) ⊗ q1``); zeros if the angle
        is 0.
    angle : float, rad
        In [0, π]: ``2·arccos(|q1·q2|)`` (seeds/002 eq. 10 with the absolute value the
        shortest path needs), computed as ``2·atan2(|v|, |w|)`` to stay accurate near 0.
    """
    d = multiply(q2, conjugate(q1))   # base-frame relative rotation
    if d[0] < 0.0:
        d = -d
    sin_half = float(np.linalg.norm(d[1:]))
    angle = 2.0 * float(np.arctan2(sin_half, d[0]))
    if sin_half == 0.0:
        return np.zeros(3), 0.0
    return d[1:] / sin_half, angle


def rotation_angle(q1, q2) -> float:
    """Angle of the shortest rotation between two orientations, rad, in [0, π]."""
    return relative_axis_angle(q1, q2)[1]


def slerp(q1, q2, k) -> np.ndarray:
    """Spherical linear interpolation along the shortest path.

    Parameters
    ----------
    q1, q2 : array_like, shape (4,)
        Unit quaternions (w, x, y, z). If ``q1·q2 < 0``, ``-q2`` (the same orientation) is the
        end point, so the result at ``k = 1`` is ``-q2`` bit for bit.
    k : float or array_like, shape (n,)
        Path parameter; 0 gives ``q1`` and 1 the end point exactly.

    Returns
    -------
    q : ndarray, shape (n, 4)
    """
    q1 = np.asarray(q1, dtype=float)
    q2 = np.asarray(q2, dtype=float)
    k = np.atleast_1d(np.asarray(k, dtype=float))[:, None]
    if float(q1 @ q2) < 0.0:
        q2 = -q2
    half = 0.5 * rotation_angle(q1, q2)
    if half < 1e-8:   # sin(kθ/2)/sin(θ/2) → k: normalised linear interpolation is exact to 1e-17
        return normalize((1.0 - k) * q1 + k * q2)
    s = np.sin(half)
    return np.sin((1.0 - k) * half) / s * q1 + np.sin(k * half) / s * q2


def orthonormality_error(M) -> float:
    """Frobenius norm ``‖MᵀM − I‖`` of a 3×3 matrix (0 for a rotation)."""
    M = np.asarray(M, dtype=float)
    return float(np.linalg.norm(M.T @ M - np.eye(3)))


def project_to_so3(M) -> np.ndarray:
    """Nearest rotation matrix (Frobenius norm) to ``M``: ``U Vᵀ`` from the SVD ``M = U S Vᵀ``.

    Parameters
    ----------
    M : array_like, shape (3, 3)
        A matrix with positive determinant (a rotation up to rounding of its entries).

    Returns
    -------
    R : ndarray, shape (3, 3)
        Orthonormal with det +1.
    """
    M = np.asarray(M, dtype=float)
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def angular_velocity(q, q_dot) -> np.ndarray:
    """Base-frame angular velocity ``ω = 2 vec(q̇ ⊗ q*)`` of a moving unit quaternion.

    Parameters
    ----------
    q, q_dot : array_like, shape (..., 4)
        Quaternion (w, x, y, z) and its time derivative (1/s).

    Returns
    -------
    omega : ndarray, shape (..., 3), rad/s
    """
    return 2.0 * multiply(q_dot, conjugate(q))[..., 1:]
