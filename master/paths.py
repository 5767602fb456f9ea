"""Planar Cartesian paths of the motion-primitive paper's comparison (Liu et al., seeds/000
§4, Fig. 7–8): half "8", circle, line and sinusoid, as plans the IK chain takes.

The paper shows its four end-effector paths only as figures, so their shapes and sizes here are
ours (docs/dmp.md says so): each is drawn in a plane through the tool's start position, spanned
by two unit vectors ``e1, e2`` of the base frame, with the tool's orientation held at its start.
The path parameter ``u`` runs from 0 to 1 along a rest-to-rest time law with zero velocity,
acceleration and jerk at both ends (the septic ``u = 35τ⁴ − 84τ⁵ + 70τ⁶ − 20τ⁷``, ``τ = t/T``),
so the joint references start and end at rest and are jerk-continuous.

======== ===================================================== ==========================
shape    p(u) − p(0) in the plane (e1, e2)                      size parameters
======== ===================================================== ==========================
line     (L u, 0)                                               ``length`` L
circle   (r (cos 2πu − 1), r sin 2πu)                           ``radius`` r
half8    (a (cos πu − 1), (a/2) sin 2πu)  (Gerono's figure      ``size`` a
         eight from one far end through the crossing to the
         other: half of the "8")
sinusoid (L u, A sin 2πu)                                       ``length`` L, ``amplitude`` A
======== ===================================================== ==========================
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mrm_cosim.errors import InputError, require_positive
from mrm_cosim.master.trig_planner import CartesianSamples

__all__ = ["SHAPES", "PathPlan", "time_law"]

SHAPES = ("half8", "circle", "line", "sinusoid")
#: The size parameters of each shape (metres).
SIZES = {"line": ("length",), "circle": ("radius",), "half8": ("size",),
         "sinusoid": ("length", "amplitude")}


def time_law(t, duration: float) -> tuple[np.ndarray, ...]:
    """``u`` and its first three time derivatives for the septic rest-to-rest law."""
    T = duration
    tau = np.clip(np.asarray(t, dtype=float) / T, 0.0, 1.0)
    u = tau**4 * (35 - 84 * tau + 70 * tau**2 - 20 * tau**3)
    ud = 140 * tau**3 * (1 - tau) ** 3 / T
    udd = 420 * tau**2 * (1 - tau) ** 2 * (1 - 2 * tau) / T**2
    uddd = 840 * tau * (1 - tau) * (1 - 5 * tau + 5 * tau**2) / T**3
    return u, ud, udd, uddd


def _shape(shape: str, size: dict, u: np.ndarray) -> tuple[np.ndarray, ...]:
    """In-plane offsets ``(a, b)`` from the start and their first three ``u`` derivatives,
    each shape (n, 2)."""
    def pair(a, b):
        return np.stack([np.broadcast_to(a, u.shape), np.broadcast_to(b, u.shape)], axis=1)

    w = 2 * math.pi
    if shape == "line":
        L = size["length"]
        z = np.zeros_like(u)
        return pair(L * u, z), pair(L + z, z), pair(z, z), pair(z, z)
    if shape == "circle":
        r = size["radius"]
        c, s = np.cos(w * u), np.sin(w * u)
        return (pair(r * (c - 1), r * s), pair(-r * w * s, r * w * c),
                pair(-r * w**2 * c, -r * w**2 * s), pair(r * w**3 * s, -r * w**3 * c))
    if shape == "half8":
        a, h = size["size"], math.pi
        c1, s1 = np.cos(h * u), np.sin(h * u)
        c2, s2 = np.cos(w * u), np.sin(w * u)
        return (pair(a * (c1 - 1), a / 2 * s2), pair(-a * h * s1, a / 2 * w * c2),
                pair(-a * h**2 * c1, -a / 2 * w**2 * s2), pair(a * h**3 * s1, -a / 2 * w**3 * c2))
    L, A = size["length"], size["amplitude"]
    z = np.zeros_like(u)
    s, c = np.sin(w * u), np.cos(w * u)
    return (pair(L * u, A * s), pair(L + z, A * w * c), pair(z, -A * w**2 * s),
            pair(z, -A * w**3 * c))


@dataclass(frozen=True)
class PathPlan:
    """A planar path with the tool's orientation held (module docstring); what
    :func:`master.cartesian.joint_reference` takes.

    Attributes
    ----------
    shape : str
        One of :data:`SHAPES`.
    start : ndarray, shape (4, 4)
        The tool's start pose (its orientation is kept).
    e1, e2 : ndarray, shape (3,)
        Orthonormal in-plane directions in the base frame.
    size : dict
        The shape's size parameters, m (:data:`SIZES`).
    duration : float, s
    """

    shape: str
    start: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    size: dict
    duration: float

    @classmethod
    def build(cls, shape: str, start, e1, e2, size: dict, duration: float,
              field: str = "path") -> PathPlan:
        """Check and build a plan; ``InputError`` names ``field``'s bad entry."""
        if shape not in SHAPES:
            raise InputError(f"{field}.shape", f"must be one of {', '.join(SHAPES)}, "
                                               f"not {shape!r}")
        T = np.asarray(start, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError(f"{field}.start", "must be a finite 4×4 pose")
        vecs = []
        for name, v in (("e1", e1), ("e2", e2)):
            v = np.asarray(v, dtype=float)
            if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) < 1e-9:
                raise InputError(f"{field}.{name}", "must be a non-zero 3-vector")
            vecs.append(v / np.linalg.norm(v))
        if abs(float(vecs[0] @ vecs[1])) > 1e-6:
            raise InputError(f"{field}.e2", "must be orthogonal to e1")
        want = SIZES[shape]
        extra = sorted(set(size) - set(want))
        if extra:
            raise InputError(f"{field}.{extra[0]}", f"is not a size of a {shape} "
                                                    f"(it has {', '.join(want)})")
        sizes = {}
        for k in want:
            if k not in size:
                raise InputError(f"{field}.{k}", f"is required for a {shape}")
            sizes[k] = require_positive(size[k], f"{field}.{k}")
        duration = require_positive(duration, f"{field}.duration")
        return cls(shape, T, vecs[0], vecs[1], sizes, duration)

    def sample(self, t) -> CartesianSamples:
        """Pose and its derivatives at times ``t`` (s), shape (n,)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        u, ud, udd, uddd = time_law(t, self.duration)
        f, f1, f2, f3 = _shape(self.shape, self.size, u)
        E = np.stack([self.e1, self.e2])                  # (2, 3)
        ud_, udd_, uddd_ = ud[:, None], udd[:, None], uddd[:, None]
        pos = self.start[:3, 3] + f @ E
        vel = (f1 * ud_) @ E
        acc = (f2 * ud_**2 + f1 * udd_) @ E
        jerk = (f3 * ud_**3 + 3 * f2 * ud_ * udd_ + f1 * uddd_) @ E
        from mrm_cosim.master import quaternion as quat

        q = np.tile(quat.from_matrix(self.start[:3, :3]), (len(t), 1))
        z = np.zeros((len(t), 3))
        return CartesianSamples(t, pos, q, vel, acc, jerk, z, z.copy(), z.copy())
