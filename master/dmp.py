"""Discrete dynamic movement primitives learned by locally weighted regression.

Transformation and phase systems (Liu et al., seeds/000 eqs. 1–2, with Ijspeert et al.'s
amplitude scaling), one per degree of freedom, all sharing one phase ``s``::

    τ v̇ = α (β (g − x) − v) + s f(s) (g − x0)
    τ ẋ = v
    τ ṡ = −α_s s,            s(0) = 1

    f(s) = Σ ψ_i(s) w_i / Σ ψ_i(s),   ψ_i(s) = exp(−(s − c_i)² / (2 σ_i²))      (eqs. 5–6)

Weights by locally weighted regression (eqs. 7–9, with the regressor ``ξ = s (g − x0)`` that
the gated, scaled forcing term needs)::

    w_i = Σ_k ψ_i(s_k) ξ_k F_k / Σ_k ψ_i(s_k) ξ_k²

The rollout is the explicit recurrence (semi-implicit Euler, exact phase decay) that a
fixed-point joint generator can run unchanged::

    F_k     = s_k f(s_k) (g − x0)
    v_{k+1} = v_k + (Δt/τ) (α (β (g − x_k) − v_k) + F_k)
    x_{k+1} = x_k + (Δt/τ) v_{k+1}
    s_{k+1} = s_k · exp(−α_s Δt/τ)

The forcing targets ``F_k`` are obtained by inverting this recurrence on the demonstration
samples, so a perfect function approximator would reproduce the demonstration exactly at its
own sample step. docs/trajectories.md derives all of it and states the accuracy protocol.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from mrm_cosim.errors import InputError, require_finite, require_positive

__all__ = ["Dmp", "DmpRollout", "learn_dmp", "forcing_targets"]

#: A degree of freedom whose demo has |g − x0| below this fraction of its range (or exactly 0)
#: is learned and rolled out without the (g − x0) factor (it would divide by ~0).
AMPLITUDE_RATIO_MIN = 1e-3


@dataclass(frozen=True)
class DmpRollout:
    """A rolled-out DMP, time-major.

    Attributes
    ----------
    t : ndarray, shape (n_steps + 1,), s
    x, xd, xdd : ndarray, shape (n_steps + 1, n_dof)
        Position, velocity ``v/τ`` and acceleration ``v̇/τ`` (units of the demo per s, s²).
    s : ndarray, shape (n_steps + 1,)
        Phase.
    """

    t: np.ndarray
    x: np.ndarray
    xd: np.ndarray
    xdd: np.ndarray
    s: np.ndarray


@dataclass(frozen=True)
class Dmp:
    """Learned parameters of a multi-DOF discrete DMP (one transformation system per DOF).

    Attributes
    ----------
    weights : ndarray, shape (n_dof, n_basis)
    centers : ndarray, shape (n_basis,)
        Basis centres ``c_i`` on the phase (1 → exp(−α_s)).
    widths : ndarray, shape (n_basis,)
        Standard deviations ``σ_i`` of the Gaussians on the phase (eq. 6).
    alpha, beta : float
        Spring and damping gains (1/τ² and 1/τ units); ``β = α/4`` is critical damping.
    alpha_s : float
        Phase decay rate.
    tau : float, s
        Time constant; the demo's duration when learned. Doubling it plays the same path in
        twice the time.
    x0, g : ndarray, shape (n_dof,)
        Start and goal.
    xd0 : ndarray, shape (n_dof,)
        Initial velocity ``ẋ(0)`` (units/s), ``v(0) = τ ẋ(0)``; zeros for a start at rest.
    goal_scaling : ndarray of bool, shape (n_dof,)
        Whether the forcing term carries the factor ``(g − x0)``; False for a DOF whose demo
        ended where it started (no amplitude to scale by).
    """

    weights: np.ndarray
    centers: np.ndarray
    widths: np.ndarray
    alpha: float
    beta: float
    alpha_s: float
    tau: float
    x0: np.ndarray
    g: np.ndarray
    xd0: np.ndarray
    goal_scaling: np.ndarray

    @property
    def n_dof(self) -> int:
        """Number of degrees of freedom."""
        return int(self.weights.shape[0])

    @property
    def n_basis(self) -> int:
        """Number of basis functions per DOF."""
        return int(self.weights.shape[1])

    def basis(self, s) -> np.ndarray:
        """Gaussian activations ``ψ_i(s)``, shape (n, n_basis), for phases ``s`` shape (n,)."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        return np.exp(-0.5 * ((s[:, None] - self.centers) / self.widths) ** 2)

    def forcing_scale(self) -> np.ndarray:
        """Per-DOF factor ``(g − x0)`` (1 where ``goal_scaling`` is False), shape (n_dof,)."""
        return np.where(self.goal_scaling, self.g - self.x0, 1.0)

    def forcing(self, s) -> np.ndarray:
        """Gated forcing term ``s f(s) (g − x0)``, shape (n, n_dof), for phases shape (n,)."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        # f is a ratio of sums of Gaussians: scaled by the largest one, so that it does not
        # become 0/0 where every ψ_i underflows (late in a rollout, s → 0 far below the last
        # centre); the node's generator normalises the same way
        a = -0.5 * ((s[:, None] - self.centers) / self.widths) ** 2
        psi = np.exp(a - a.max(axis=1, keepdims=True))
        f = psi @ self.weights.T / np.sum(psi, axis=1, keepdims=True)
        return s[:, None] * f * self.forcing_scale()

    def with_goal(self, g) -> Dmp:
        """The same primitive aimed at a new goal ``g`` (shape (n_dof,)); the shape scales by
        ``(g − x0)/(g_demo − x0)`` on DOFs with ``goal_scaling``."""
        return replace(self, g=_vector(g, self.n_dof, "g"))

    def with_start(self, x0) -> Dmp:
        """The same primitive from a new start ``x0`` (shape (n_dof,))."""
        return replace(self, x0=_vector(x0, self.n_dof, "x0"))

    def with_tau(self, tau: float) -> Dmp:
        """The same primitive with time constant ``tau`` (s): duration scales with it."""
        return replace(self, tau=require_positive(tau, "tau"))

    def check_step(self, dt: float) -> float:
        """Return ``k = Δt/τ`` if the recurrence is stable at this step, else raise.

        The homogeneous recurrence has the matrix ``[[1 − k²αβ, k(1 − kα)], [−kαβ, 1 − kα]]``
        on (x, v): determinant ``1 − kα`` and trace ``2 − kα − k²αβ``. Both eigenvalues lie
        inside the unit circle iff ``kα < 2`` and ``k²αβ < 4 − 2kα`` (Jury); with ``β = α/4``
        that is ``kα < 4(√2 − 1) ≈ 1.657``.
        """
        dt = require_positive(dt, "dt")
        k = dt / self.tau
        ka = k * self.alpha
        if not (ka < 2.0 and k * k * self.alpha * self.beta < 4.0 - 2.0 * ka):
            raise InputError("dt", f"{dt!r} s is too long for τ = {self.tau} s and α = "
                                   f"{self.alpha}: the recurrence would diverge")
        return k

    def step(self, x, v, s, dt: float) -> tuple[np.ndarray, np.ndarray, float]:
        """One step of the explicit recurrence.

        Parameters
        ----------
        x, v : ndarray, shape (n_dof,)
            Position and scaled velocity ``v = τ ẋ``.
        s : float
            Phase.
        dt : float, s

        Returns
        -------
        x, v, s
            The state ``dt`` later.
        """
        k = self.check_step(dt)
        vdot = self.alpha * (self.beta * (self.g - x) - v) + self.forcing(s)[0]
        v = v + k * vdot
        x = x + k * v
        return x, v, s * math.exp(-self.alpha_s * k)

    def rollout(self, dt: float, duration: float | None = None) -> DmpRollout:
        """Integrate from ``(x0, τ·xd0, s = 1)`` for ``duration`` (default ``τ``) at step ``dt``.

        Parameters
        ----------
        dt : float, s
            Integration step (e.g. 0.005 or 0.001, as the joint generator would run).
        duration : float, s, optional
            Length of the rollout; ``round(duration/dt)`` steps are taken.

        Returns
        -------
        DmpRollout
        """
        dt = require_positive(dt, "dt")
        duration = self.tau if duration is None else require_positive(duration, "duration")
        n = int(round(duration / dt))
        if n < 1:
            raise InputError("dt", f"is longer than the rollout ({duration} s)")
        if n > 10_000_000:
            raise InputError("dt", f"gives {n} steps; choose a larger step")
        k = self.check_step(dt)
        decay = math.exp(-self.alpha_s * k)
        s = np.empty(n + 1)
        s[0] = 1.0
        for i in range(n):                       # same product as step(): bit-identical
            s[i + 1] = s[i] * decay
        forcing = self.forcing(s)                # the phase does not depend on the state
        x = np.empty((n + 1, self.n_dof))
        v = np.empty((n + 1, self.n_dof))
        vdot = np.empty((n + 1, self.n_dof))
        x[0] = self.x0
        v[0] = self.tau * self.xd0
        a, b, g = self.alpha, self.beta, self.g
        for i in range(n + 1):
            vdot[i] = a * (b * (g - x[i]) - v[i]) + forcing[i]
            if i < n:
                v[i + 1] = v[i] + k * vdot[i]
                x[i + 1] = x[i] + k * v[i + 1]
        return DmpRollout(np.arange(n + 1) * dt, x, v / self.tau, vdot / self.tau**2, s)


def _vector(value, n: int, field: str) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(value, dtype=float))
    if arr.shape != (n,):
        raise InputError(field, f"must have shape ({n},), not {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(field, "must be finite")
    return arr


def forcing_targets(y: np.ndarray, dt: float, *, tau: float, alpha: float, beta: float,
                    alpha_s: float, xd0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forcing values that make the rollout recurrence reproduce the demo exactly.

    Inverting ``x_{k+1} = x_k + (Δt/τ) v_{k+1}`` gives ``v_{k+1} = τ (y_{k+1} − y_k)/Δt``
    (``v_0 = τ ẋ(0)``), and inverting the velocity update gives
    ``F_k = τ (v_{k+1} − v_k)/Δt − α (β (g − y_k) − v_k)`` with ``g = y_{-1}``.

    Parameters
    ----------
    y : ndarray, shape (n_samples, n_dof)
        Demo at ``t_k = k Δt``.
    dt : float, s
    tau, alpha, beta, alpha_s : float
    xd0 : ndarray, shape (n_dof,)
        Initial velocity, units/s.

    Returns
    -------
    F : ndarray, shape (n_samples − 1, n_dof)
        Forcing targets for steps k = 0 … n_samples − 2.
    s : ndarray, shape (n_samples − 1,)
        Phase at those steps (the recurrence's ``s_k``, bit for bit).
    """
    k = dt / tau
    g = y[-1]
    v = np.empty_like(y)
    v[0] = tau * xd0
    v[1:] = np.diff(y, axis=0) / k
    target = (v[1:] - v[:-1]) / k - alpha * (beta * (g - y[:-1]) - v[:-1])
    decay = math.exp(-alpha_s * k)
    s = np.empty(y.shape[0] - 1)
    s[0] = 1.0
    for i in range(1, s.size):
        s[i] = s[i - 1] * decay
    return target, s


def learn_dmp(y, dt: float, n_basis: int = 10, *, alpha: float = 25.0,
              beta: float | None = None, alpha_s: float = 2.0, overlap: float = 0.2,
              tau: float | None = None, xd0=None,
              scaling_min: float = AMPLITUDE_RATIO_MIN) -> Dmp:
    """Learn a DMP from a uniformly sampled demonstration.

    Parameters
    ----------
    y : array_like, shape (n_samples,) or (n_samples, n_dof)
        Demonstrated positions at ``t_k = k·dt``, time-major; ``n_samples >= 3``.
    dt : float, s
        Sample period of the demo (the recurrence is inverted at this step).
    n_basis : int
        Gaussians per DOF, centred at phases of equally spaced times over the demo.
    alpha, beta : float
        Transformation-system gains; ``beta`` defaults to ``alpha/4`` (critical damping).
    alpha_s : float
        Phase decay; the phase is ``exp(−α_s)`` at the end of the demo.
    overlap : float
        Value of each Gaussian halfway to its neighbour's centre, in (0, 1); sets σ_i.
    tau : float, s, optional
        Time constant; defaults to the demo's duration ``(n_samples − 1)·dt``.
    xd0 : array_like, shape (n_dof,), optional
        Initial velocity of the demo (units/s); zeros (a start at rest) by default.
    scaling_min : float
        A DOF whose ``|g − x0|`` is at most this fraction of its demo's range is learned
        without the ``(g − x0)`` factor (``goal_scaling`` False). The default only avoids a
        division by ~0; a larger one (e.g. 0.2) keeps the weights of DOFs that end near their
        start small, as a fixed-point generator needs (Ijspeert's amplitude scaling blows the
        weights up by the ratio).

    Returns
    -------
    Dmp
    """
    y = np.asarray(y, dtype=float)
    if y.ndim == 1:
        y = y[:, None]
    if y.ndim != 2 or y.shape[0] < 3 or y.shape[1] < 1:
        raise InputError("y", f"must have shape (n_samples >= 3, n_dof), not {y.shape}")
    if not np.all(np.isfinite(y)):
        raise InputError("y", "must be finite")
    dt = require_positive(dt, "dt")
    if isinstance(n_basis, bool) or not isinstance(n_basis, int) or not 2 <= n_basis:
        raise InputError("n_basis", f"must be an integer >= 2, not {n_basis!r}")
    alpha = require_positive(alpha, "alpha")
    beta = alpha / 4.0 if beta is None else require_positive(beta, "beta")
    alpha_s = require_positive(alpha_s, "alpha_s")
    overlap = require_finite(overlap, "overlap")
    if not 0.0 < overlap < 1.0:
        raise InputError("overlap", f"must be in (0, 1), not {overlap!r}")
    n_samples, n_dof = y.shape
    duration = (n_samples - 1) * dt
    tau = duration if tau is None else require_positive(tau, "tau")
    xd0 = np.zeros(n_dof) if xd0 is None else _vector(xd0, n_dof, "xd0")

    x0, g = y[0].copy(), y[-1].copy()
    amplitude = g - x0
    span = np.ptp(y, axis=0)
    scaling_min = require_finite(scaling_min, "scaling_min")
    if not 0.0 <= scaling_min < 1.0:
        raise InputError("scaling_min", f"must be in [0, 1), not {scaling_min!r}")
    goal_scaling = np.abs(amplitude) > max(scaling_min, AMPLITUDE_RATIO_MIN) * span
    scale = np.where(goal_scaling, amplitude, 1.0)

    # Basis: centres at the phases of equally spaced times, σ from the spacing.
    centers = np.exp(-alpha_s * np.linspace(0.0, duration, n_basis) / tau)
    spacing = np.abs(np.diff(centers))
    spacing = np.append(spacing, spacing[-1])
    widths = spacing / (2.0 * math.sqrt(2.0 * math.log(1.0 / overlap)))

    target, s = forcing_targets(y, dt, tau=tau, alpha=alpha, beta=beta, alpha_s=alpha_s,
                                xd0=xd0)

    # Locally weighted regression (eq. 8) with regressor ξ = s (g − x0), per DOF and basis.
    psi = np.exp(-0.5 * ((s[:, None] - centers) / widths) ** 2)     # (n, n_basis)
    xi = s[:, None] * scale                                          # (n, n_dof)
    num = (xi * target).T @ psi                                      # (n_dof, n_basis)
    den = (xi * xi).T @ psi
    weights = np.divide(num, den, out=np.zeros_like(num), where=den > 0.0)
    return Dmp(weights, centers, widths, alpha, beta, alpha_s, tau, x0, g, xd0, goal_scaling)
