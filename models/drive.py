"""Joint drive models: harmonic-drive friction with stiction, amplifier current loop, spring.

Everything acts at the joint (actuator output); arrays have shape (n,), one entry per joint.

* Friction (Coulomb + viscous + Stribeck, e.g. Armstrong-Hélouvry, Dupont, Canudas de Wit,
  *Automatica* 30(7), 1994): a joint sliding at speed ``v`` feels
  ``f(v) = sgn(v) · (F_c + (F_s − F_c) · exp(−(v / v_s)²)) + b · v``; a joint at rest feels
  whatever torque in ``[−F_s, F_s]`` keeps it at rest (set-valued, so stiction really sticks).
* Amplifier: the torque command is clipped to ± peak torque and the motor torque follows it
  through the closed current loop, a first-order lag ``T dτ/dt = u − τ`` (exact discretization
  for a command held over the step).
* Type II counterbalance spring: ``τ_s(q) = A cos(q + φ)``, potential ``−A sin(q + φ)``.

The stick-slip step (:func:`solve_stick_slip`) is the time-stepping friction law used by
``models.plant``: it finds the velocity at the end of a step for which every joint's friction
torque is consistent — sliding joints feel their kinetic friction, stuck joints end the step at
exactly zero velocity with a friction torque inside their static bound.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dposv as _dposv

__all__ = ["FrictionParams", "CurrentLoop", "spring_torque", "spring_energy",
           "solve_stick_slip", "solve_stick_slip_bruteforce"]


def _vec(x, n: int | None = None) -> np.ndarray:
    a = np.array(x, dtype=float).reshape(-1)
    if n is not None and a.shape != (n,):
        raise ValueError(f"expected {n} values, not {a.shape}")
    return a


@dataclass(frozen=True, eq=False)
class FrictionParams:
    """Per-joint friction parameters at the joint.

    Attributes
    ----------
    coulomb : ndarray, shape (n,), N·m
        Kinetic friction ``F_c``.
    static : ndarray, shape (n,), N·m
        Break-away friction ``F_s ≥ F_c``.
    stribeck_velocity : ndarray, shape (n,), rad/s
        ``v_s > 0``.
    viscous : ndarray, shape (n,), N·m·s/rad
        ``b ≥ 0``.
    """

    coulomb: np.ndarray
    static: np.ndarray
    stribeck_velocity: np.ndarray
    viscous: np.ndarray

    def __post_init__(self):
        n = _vec(self.coulomb).size
        for name in ("coulomb", "static", "stribeck_velocity", "viscous"):
            a = _vec(getattr(self, name), n)
            a.flags.writeable = False
            object.__setattr__(self, name, a)
        if not (np.all(np.isfinite(self.static)) and np.all(self.coulomb >= 0.0)
                and np.all(self.static >= self.coulomb) and np.all(self.viscous >= 0.0)
                and np.all(self.stribeck_velocity > 0.0)):
            raise ValueError("friction needs 0 ≤ coulomb ≤ static, viscous ≥ 0 and "
                             "stribeck_velocity > 0")

    @property
    def n(self) -> int:
        return self.coulomb.size

    @classmethod
    def zero(cls, n: int) -> FrictionParams:
        """No friction at all (for friction-free checks)."""
        return cls(np.zeros(n), np.zeros(n), np.ones(n), np.zeros(n))

    def level(self, speed, out: np.ndarray | None = None) -> np.ndarray:
        """Coulomb + Stribeck level ``F_c + (F_s − F_c) exp(−(v/v_s)²)``, N·m, shape (n,).

        ``speed`` is ``|v|`` (rad/s); at rest this is the static friction ``F_s``.
        """
        x = np.divide(speed, self.stribeck_velocity, out=out)
        np.multiply(x, x, out=x)
        np.negative(x, out=x)
        np.exp(x, out=x)
        x *= self.static - self.coulomb
        x += self.coulomb
        return x

    def sliding(self, v) -> np.ndarray:
        """Friction torque opposing a joint that slides at velocity ``v`` (rad/s), N·m.

        ``sgn(v) · level(|v|) + b v``; zero at ``v = 0`` (a joint at rest feels whatever it
        needs up to ``static``, see :func:`solve_stick_slip`). This is the steady-state
        friction-versus-speed (Stribeck) curve.
        """
        v = np.asarray(v, dtype=float)
        return np.sign(v) * self.level(np.abs(v)) + self.viscous * v


class CurrentLoop:
    """Amplifier current loop: torque saturation then a first-order lag, exact for a held command.

    With the command ``u`` (N·m at the joint) clipped to ``±peak`` and held for a step ``h``, the
    motor torque obeys ``T dτ/dt = u − τ``, so
    ``τ(h) = u + (τ(0) − u) e^{−h/T}`` and its mean over the step is
    ``u + (τ(0) − u) (T/h)(1 − e^{−h/T})``. The mean is what the mechanics integrate (it gives the
    exact impulse of the torque over the step). ``T = 0`` is an ideal (instant) loop.

    Parameters
    ----------
    time_constant : array_like, shape (n,), s
        ``T = 1 / (2π f_bw)`` per joint; 0 for an ideal loop.
    peak_torque : array_like, shape (n,), N·m
    dt : float, s
        Step length ``h``.
    """

    def __init__(self, time_constant, peak_torque, dt: float):
        T = _vec(time_constant)
        self.peak_torque = _vec(peak_torque, T.size)
        if np.any(T < 0.0) or not np.all(np.isfinite(T)):
            raise ValueError(f"time constants must be finite and ≥ 0, not {T!r}")
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"dt must be positive, not {dt!r}")
        self.time_constant = T
        self.dt = float(dt)
        ideal = T == 0.0
        ratio = np.divide(dt, T, out=np.full(T.size, np.inf), where=~ideal)
        self.alpha = np.exp(-ratio)                       # end-of-step weight of τ(0) − u
        self.beta = np.where(ideal, 0.0,                  # mean-over-step weight of τ(0) − u
                             -np.expm1(-ratio) / np.where(ideal, 1.0, ratio))
        self._u = np.empty(T.size)
        self._d = np.empty(T.size)

    def advance(self, tau: np.ndarray, command: np.ndarray, mean_out: np.ndarray) -> None:
        """Advance one step in place.

        Parameters
        ----------
        tau : ndarray, shape (n,), N·m
            Motor torque at the start of the step; overwritten with the value at its end.
        command : ndarray, shape (n,), N·m
            Torque command held over the step (clipped to ± peak torque here).
        mean_out : ndarray, shape (n,), N·m
            Receives the mean motor torque over the step.
        """
        u, d = self._u, self._d
        np.clip(command, -self.peak_torque, self.peak_torque, out=u)
        np.subtract(tau, u, out=d)
        np.multiply(d, self.beta, out=mean_out)
        mean_out += u
        np.multiply(d, self.alpha, out=tau)
        tau += u


def spring_torque(q, amplitude, phase) -> np.ndarray:
    """Counterbalance spring torque on the joint, ``A cos(q + φ)``, N·m, shape (n,)."""
    return np.asarray(amplitude) * np.cos(np.asarray(q) + phase)


def spring_energy(q, amplitude, phase) -> np.ndarray:
    """Potential energy of the spring, ``−A sin(q + φ)``, J, shape (n,); ``τ_s = −dV/dq``."""
    return -np.asarray(amplitude) * np.sin(np.asarray(q) + phase)


def _kkt(M, rhs, v, limit, s):
    """End velocity for sign pattern ``s`` and the violations of that pattern.

    Returns ``(w, hold, bad_free, bad_stuck)``: ``hold = rhs − M Δv`` is the friction impulse
    the pattern needs (``limit ∘ σ``); a free joint is violated when it ends with the wrong
    sign (or at zero), a stuck joint when ``|hold|`` exceeds its bound.
    """
    free = s != 0
    if free.all():
        dv = _spd_solve(M, rhs - limit * s)
    else:
        stuck = ~free
        dv = -v * stuck
        if free.any():
            fi = free.nonzero()[0]
            b = rhs[fi] - limit[fi] * s[fi]
            if dv.any():
                si = stuck.nonzero()[0]
                b -= M[fi[:, None], si] @ dv[si]
            dv[fi] = _spd_solve(M[fi[:, None], fi], b)
    w = v + dv
    w[~free] = 0.0
    hold = rhs - M @ dv
    bad_free = free & (w * s <= 0.0) & (limit > 0.0)
    bad_stuck = ~free & (np.abs(hold) > limit * (1.0 + 1e-12))
    return w, hold, bad_free, bad_stuck


def _spd_solve(A, b):
    """Solve ``A x = b`` for symmetric positive definite ``A`` (Cholesky, LAPACK dposv)."""
    _, x, info = _dposv(A, b)
    if info != 0:
        raise np.linalg.LinAlgError(f"matrix is not positive definite (dposv info {info})")
    return x


def solve_stick_slip(M, rhs, v, limit, max_pivots: int | None = None,
                     sweeps: int = 100000) -> tuple[np.ndarray, np.ndarray]:
    """One time step of joints with set-valued (stick-slip) friction.

    Finds ``w = v + Δv`` with ``M Δv = rhs − limit ∘ σ``, ``σ_i ∈ ∂|w_i|`` (``σ_i = sgn w_i``
    when ``w_i ≠ 0``, any value in ``[−1, 1]`` when ``w_i = 0``). With ``rhs = h ρ`` (smooth
    torques times the step) and ``limit = h F`` (friction level times the step), this is the
    implicit friction law of a time-stepping scheme; it is the minimiser of the strictly convex
    ``½ Δvᵀ M Δv − rhsᵀ Δv + Σ limit_i |v_i + Δv_i|``, so the solution is unique.

    Stuck joints come out with ``w_i = 0.0`` exactly.

    Parameters
    ----------
    M : ndarray, shape (n, n)
        Symmetric positive definite (joint-space inertia), kg·m²; both triangles filled.
    rhs : ndarray, shape (n,)
        Impulse of the smooth torques over the step, N·m·s.
    v : ndarray, shape (n,)
        Velocity at the start of the step, rad/s.
    limit : ndarray, shape (n,)
        Friction impulse bound ``≥ 0``, N·m·s.

    Returns
    -------
    w : ndarray, shape (n,), rad/s
        Velocity at the end of the step.
    pattern : ndarray of int8, shape (n,)
        ``+1`` / ``−1`` for joints sliding forwards / backwards at the end of the step, 0 for
        stuck joints.

    Notes
    -----
    Active-set iteration warm-started from ``sgn(v)`` (joints at rest start stuck), changing
    the most violated joint at a time; if a pattern repeats or ``max_pivots`` is exceeded it
    falls back to exact cyclic coordinate descent (convergent for this strictly convex problem)
    and solves the linear system of the pattern it finds.
    """
    v = np.asarray(v, dtype=float)
    limit = np.asarray(limit, dtype=float)
    rhs = np.asarray(rhs, dtype=float)
    n = v.size
    s = np.sign(v).astype(np.int8)
    s[(limit == 0.0) & (s == 0)] = 1          # a joint without friction is never stuck
    seen = set()
    for _ in range(4 * n + 4 if max_pivots is None else max_pivots):
        key = s.tobytes()
        if key in seen:
            break
        seen.add(key)
        w, hold, bad_free, bad_stuck = _kkt(M, rhs, v, limit, s)
        if bad_stuck.any():
            i = int(np.argmax(np.where(bad_stuck, np.abs(hold) - limit, -np.inf)))
            s[i] = 1 if hold[i] > 0.0 else -1
        elif bad_free.any():
            i = int(np.argmax(np.where(bad_free, -w * s, -np.inf)))
            s[i] = 0
        else:
            return w, _pattern(w)
    return _coordinate_descent(M, rhs, v, limit, sweeps)


def _pattern(w: np.ndarray) -> np.ndarray:
    return np.sign(w).astype(np.int8)


def _coordinate_descent(M, rhs, v, limit, sweeps):
    """Exact cyclic coordinate descent on the strictly convex problem, then a pattern polish."""
    n = v.size
    dv = np.zeros(n)
    g = -rhs.copy()                                     # gradient of the smooth part: M Δv − rhs
    diag = np.diag(M).copy()
    scale = max(float(np.abs(v).max(initial=0.0)), float(np.abs(rhs / diag).max()), 1e-300)
    for _ in range(sweeps):
        biggest = 0.0
        for i in range(n):
            c = diag[i] * (v[i] + dv[i]) - g[i]          # M_ii w_i + limit_i σ_i = c
            w = 0.0 if abs(c) <= limit[i] else (c - math.copysign(limit[i], c)) / diag[i]
            step = w - v[i] - dv[i]
            if step != 0.0:
                dv[i] += step
                g += M[:, i] * step
                biggest = max(biggest, abs(step))
        if biggest <= 1e-15 * scale:
            break
    w = v + dv
    s = _pattern(w)
    s[(limit == 0.0) & (s == 0)] = 1
    w_exact, _, bad_free, bad_stuck = _kkt(M, rhs, v, limit, s)
    if not (bad_free.any() or bad_stuck.any()):
        return w_exact, _pattern(w_exact)
    w[s == 0] = 0.0
    return w, _pattern(w)


def solve_stick_slip_bruteforce(M, rhs, v, limit) -> np.ndarray:
    """Reference for tests: try all ``3ⁿ`` sign patterns and return the consistent one.

    Exponential in ``n``; only for small problems. Raises ``RuntimeError`` if no pattern is
    consistent (which cannot happen for a positive definite ``M``).
    """
    import itertools

    v = np.asarray(v, dtype=float)
    for combo in itertools.product((-1, 0, 1), repeat=v.size):
        s = np.array(combo, dtype=np.int8)
        if np.any((s == 0) & (np.asarray(limit) == 0.0)):
            continue
        w, _, bad_free, bad_stuck = _kkt(M, np.asarray(rhs, float), v,
                                         np.asarray(limit, float), s)
        if not (bad_free.any() or bad_stuck.any()):
            return w
    raise RuntimeError("no consistent stick-slip pattern")
