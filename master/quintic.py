"""Rest-to-rest quintic (minimum-jerk) point-to-point trajectories.

Implements the MRM paper's test trajectory (Zhu et al., seeds/003, eq. 4)::

    q(t) = q0 + Δ (10 τ³ − 15 τ⁴ + 6 τ⁵),   τ = t / tf,   Δ = qf − q0

for many joints at once, with its derivatives up to jerk, and the exact (closed-form, not
sampled) peaks of velocity, acceleration and jerk:

    max |q̇| = (15/8) |Δ| / tf          at τ = 1/2
    max |q̈| = (10/√3) |Δ| / tf²        at τ = 1/2 ∓ √3/6
    max |q⃛| = 60 |Δ| / tf³             at τ = 0 and τ = 1

The paper prints max q̈ = (45/8) Δ/tf², which is q̈ evaluated at τ = 1/4 rather than at the
maximiser; see docs/trajectories.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mrm_cosim.errors import InputError, require_finite, require_positive

__all__ = ["QuinticProfile", "PEAK_VELOCITY_COEFF", "PEAK_ACCELERATION_COEFF",
           "PEAK_JERK_COEFF", "mrm_test_profile"]

#: max |q̇| = PEAK_VELOCITY_COEFF · |Δ| / tf
PEAK_VELOCITY_COEFF = 15.0 / 8.0
#: max |q̈| = PEAK_ACCELERATION_COEFF · |Δ| / tf²
PEAK_ACCELERATION_COEFF = 10.0 / math.sqrt(3.0)
#: max |q⃛| = PEAK_JERK_COEFF · |Δ| / tf³
PEAK_JERK_COEFF = 60.0


def _as_joint_vector(value, field: str) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(value, dtype=float))
    if arr.ndim != 1 or arr.size == 0:
        raise InputError(field, f"must be a number or a 1-D list of numbers, not {value!r}")
    if not np.all(np.isfinite(arr)):
        raise InputError(field, f"must be finite, not {value!r}")
    return arr


@dataclass(frozen=True)
class QuinticProfile:
    """A rest-to-rest quintic from ``q0`` to ``qf`` in ``tf`` seconds, for ``n_dof`` joints.

    Parameters
    ----------
    q0, qf : ndarray, shape (n_dof,), rad
        Start and end positions. A scalar is one joint; a scalar ``q0`` with a vector ``qf``
        is broadcast.
    tf : float, s
        Duration, > 0.

    Before ``t = 0`` the profile rests at ``q0`` and after ``tf`` at ``qf`` (all derivatives
    zero), so the master may evaluate it on any clock.
    """

    q0: np.ndarray
    qf: np.ndarray
    tf: float

    def __init__(self, q0, qf, tf: float):
        q0 = _as_joint_vector(q0, "q0")
        qf = _as_joint_vector(qf, "qf")
        if q0.size == 1 and qf.size > 1:
            q0 = np.full_like(qf, q0[0])
        if q0.shape != qf.shape:
            raise InputError("qf", f"has {qf.size} joints but q0 has {q0.size}")
        tf = require_positive(tf, "tf")
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            delta = qf - q0
            jerk = PEAK_JERK_COEFF * np.abs(delta) / tf**3
        if not np.all(np.isfinite(delta)):
            raise InputError("qf", "the move qf − q0 overflows a float")
        if not np.all(np.isfinite(jerk)):
            # the peaks (velocity ∝ 1/tf, acceleration 1/tf², jerk 1/tf³) would be infinite
            raise InputError("tf", f"{tf!r} s is too short for a move of "
                             f"{float(np.abs(delta).max())!r} rad: its peak jerk overflows a "
                             f"float")
        object.__setattr__(self, "q0", q0)
        object.__setattr__(self, "qf", qf)
        object.__setattr__(self, "tf", tf)
        # for :meth:`at`, the master's once-a-period call: the constants of its formulas
        object.__setattr__(self, "_at_consts", tuple(
            x.tolist() for x in (delta, delta / tf, delta / tf**2, delta / tf**3)))

    @property
    def n_dof(self) -> int:
        """Number of joints."""
        return int(self.q0.size)

    @property
    def delta(self) -> np.ndarray:
        """Displacement ``qf − q0``, shape (n_dof,), rad."""
        return self.qf - self.q0

    @property
    def peak_velocity(self) -> np.ndarray:
        """Exact max |q̇| per joint, shape (n_dof,), rad/s (reached at t = tf/2)."""
        return PEAK_VELOCITY_COEFF * np.abs(self.delta) / self.tf

    @property
    def peak_acceleration(self) -> np.ndarray:
        """Exact max |q̈| per joint, shape (n_dof,), rad/s² (at t = tf (1/2 ∓ √3/6))."""
        return PEAK_ACCELERATION_COEFF * np.abs(self.delta) / self.tf**2

    @property
    def peak_jerk(self) -> np.ndarray:
        """Exact max |q⃛| per joint, shape (n_dof,), rad/s³ (at t = 0 and t = tf)."""
        return PEAK_JERK_COEFF * np.abs(self.delta) / self.tf**3

    def evaluate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, acceleration and jerk at times ``t``.

        Parameters
        ----------
        t : float or ndarray, shape (n_samples,), s
            Times; values outside [0, tf] give the rest state at the nearer end. The jerk
            jumps at both ends; at exactly 0 and ``tf`` its one-sided value inside the move
            (``60 Δ/tf³``) is returned, so sampled maxima reach the exact peak.

        Returns
        -------
        q, qd, qdd, qddd : ndarray, shape (n_samples, n_dof)
            rad, rad/s, rad/s², rad/s³ (time-major; a scalar ``t`` gives n_samples = 1).
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if t.ndim != 1:
            raise InputError("t", f"must be a scalar or a 1-D array, not shape {t.shape}")
        if not np.all(np.isfinite(t)):
            raise InputError("t", "must be finite")
        tau = np.clip(t / self.tf, 0.0, 1.0)[:, None]
        moving = ((t >= 0.0) & (t <= self.tf))[:, None]   # jerk: one-sided values at 0, tf
        u = 1.0 - tau
        d = self.delta[None, :]
        # Factored forms: exact zeros at the ends, no cancellation near them.
        shape = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
        q = np.where(tau >= 1.0, self.qf[None, :], self.q0[None, :] + d * shape)
        qd = d / self.tf * 30.0 * tau**2 * u**2
        qdd = d / self.tf**2 * 60.0 * tau * u * (1.0 - 2.0 * tau)
        qddd = np.where(moving, d / self.tf**3 * (60.0 - 360.0 * tau + 360.0 * tau**2), 0.0)
        return q, qd, qdd, qddd

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`evaluate` at one finite time ``t``: ``(q, qd, qdd, qddd)``, shape (n_dof,)
        each.

        The master evaluates its reference once a period: there the array machinery of
        :meth:`evaluate` (a 1×n_dof broadcast, ``where``, ``clip``, an array operation per
        factor) costs more than the arithmetic. This is the same formulas, in the same order of
        operations, on a scalar ``τ`` and each joint's floats — elementwise, so the same floats
        (tests/test_quintic.py checks them bit for bit).
        """
        t = float(t)
        tf = self.tf
        d, d_tf, d_tf2, d_tf3 = self._at_consts            # Δ, Δ/tf, Δ/tf², Δ/tf³ per joint
        tau = min(max(t / tf, 0.0), 1.0)
        u = 1.0 - tau
        # numpy's array ** 2 is a product; its array ** 3 is its own vectorised pow(), which
        # is not float's (nor τ·τ·τ) to the last bit: take it from a one-element array
        tau2 = tau * tau
        tau3 = float((np.array([tau]) ** 3)[0])
        shape = tau3 * (10.0 - 15.0 * tau + 6.0 * tau2)
        if tau >= 1.0:
            q = self.qf.copy()
        else:
            q = np.array([q0 + dk * shape for q0, dk in zip(self.q0.tolist(), d, strict=True)])
        uu, v = u * u, 1.0 - 2.0 * tau
        qd = np.array([c * 30.0 * tau2 * uu for c in d_tf])
        qdd = np.array([c * 60.0 * tau * u * v for c in d_tf2])
        if 0.0 <= t <= tf:                     # the jerk's one-sided values at 0 and tf
            j = 60.0 - 360.0 * tau + 360.0 * tau2
            qddd = np.array([c * j for c in d_tf3])
        else:
            qddd = np.zeros(len(d))
        return q, qd, qdd, qddd

    def summary(self) -> dict:
        """Closed-form figures: ``duration_s`` and per-joint peaks (lists, SI units)."""
        return {
            "duration_s": self.tf,
            "peak_velocity": self.peak_velocity.tolist(),
            "peak_acceleration": self.peak_acceleration.tolist(),
            "peak_jerk": self.peak_jerk.tolist(),
        }


def mrm_test_profile(n_joints: int = 3, pf: float = 0.1571, tf: float = 1.0) -> QuinticProfile:
    """The MRM paper's experiment (seeds/003 eqs. 1–4): joint i moves ``i · q_d(t)``.

    Parameters
    ----------
    n_joints : int
        Number of joints (3 in the paper).
    pf : float, rad
        Terminal position of ``q_d`` (0.1571 rad = 20,000 encoder counts).
    tf : float, s
        Duration.
    """
    if isinstance(n_joints, bool) or not isinstance(n_joints, int) or n_joints < 1:
        raise InputError("n_joints", f"must be a positive integer, not {n_joints!r}")
    scale = np.arange(1, n_joints + 1, dtype=float)
    return QuinticProfile(np.zeros(n_joints), scale * require_finite(pf, "pf"), tf)

