"""Float virtual decomposition control (VDC) of one module: the slave node's link dynamics.

This is the float oracle the node's fixed-point VDC unit is measured against: its bit-exact
reference :class:`~mrm_cosim.hdl.node.vdc_ref.VdcModel` (and so the gateware) must stay within
the error budget of docs/node.md of it. It is a reference like the others: it imports no
gateware. It computes, from what a slave node receives and measures, the required net
force/moment of the module's two links (DESIGN.md "VDC in equations"; Zhu 2010, App. A):

* Frames (docs/robot.md): Link b is proximal with frame {C}, Link a distal with frame {A};
  both at the joint origin, ``ᶜR_A = Rz(q)``, ``ᶜr_CA = 0``, so ``ᶜU_A = diag(R, R)``.
* Velocities across the joint: ``V_A = ᶜU_Aᵀ V_C + z q̇`` and ``V_rA = ᶜU_Aᵀ V_rC + z q̇_r``
  with ``z = [0, 0, 0, 0, 0, 1]`` (:func:`link_a_velocity`).
* Required net force of a link: ``F*_r = Y(ω, V_r, dV_r/dt, g) θ̂ + K (V_r − V)``
  (:func:`required_net_force`), ``Y`` the 6×13 regressor of :mod:`models.spatial`, ``K``
  diagonal positive (6 gains per link).
* Adaptation with the projection function (:func:`projection_update`):
  ``s = Yᵀ(V_r − V)``, ``θ̂ ← clip(θ̂ + ρ T κ, θ̲, θ̄)`` with ``κ = 0`` when ``θ̂ ≤ θ̲, s ≤ 0`` or
  ``θ̂ ≥ θ̄, s ≥ 0``, else ``κ = s``.

What the node knows (docs/node.md, "Comm B and the required accelerations"): each period it
receives ``q̇_r``, ``V_C`` and ``V_rC`` (Comm B) and uses its own encoder snapshot ``q, q̇`` taken
at the period start (the values it reported in Comm A, so master and node agree on them). It
does not receive accelerations: :class:`ModuleVDC` derives ``dV_rC/dt`` and ``q̈_r`` by backward
differences over one period of the received ``V_rC`` and ``q̇_r``, and carries them across the
joint with the exact derivative of the velocity mapping (:func:`link_a_acceleration`, with the
actual ``q̇`` rotating the frame). The (upward) gravity vector ``g_C`` arrives in the previous
period's Comm D. The fixed-point unit uses exactly this information, so the two differ only by
number formats.

Vectors are ``[v; ω]`` and ``[f; m]``, linear part first, SI units (m/s, rad/s, N, N·m).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mrm_cosim.protocol.vdc_program import N_PARAMS

__all__ = ["rz", "link_regressor", "link_a_velocity", "link_a_acceleration", "required_net_force",
           "adaptation_signal", "projection_update", "ModuleGains", "ModuleVDC"]

_Z6 = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0])


def rz(q: float) -> np.ndarray:
    """``Rz(q)`` (3×3): orientation of {A} in {C} at joint angle ``q`` (rad)."""
    c, s = np.cos(q), np.sin(q)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _skew(w) -> np.ndarray:
    x, y, z = w
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


_Q_BASIS = []   # symmetric basis matrices of Q for θ₅..θ₁₀, with their trace weight
for (_i, _j) in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)):
    _B = np.zeros((3, 3))
    _B[_i, _j] = _B[_j, _i] = 1.0
    _Q_BASIS.append((_B, 1.0 if _i == _j else 0.0))


def link_regressor(omega, V_r, dV_r, g) -> np.ndarray:
    """The 6×13 regressor ``Y(ω, V_r, dV_r/dt, g)`` assembled block by block.

    Same matrix as :func:`models.spatial.regressor` (tested), written out for speed: with
    ``a = v̇_r + ω × v_r + g``, ``f = θ₁ a + (ω̇_r×) h + (ω×)(ω_r×) h`` and
    ``n = h × a + J ω̇_r + ω × (I_d ω_r) + I_d (ω × ω_r) + (Q ω) × ω_r``,
    ``J = I_d + (θ₅+θ₆+θ₇) E − Q`` (DESIGN.md "VDC in equations").

    Parameters
    ----------
    omega : array_like, shape (3,), rad/s
        Actual angular velocity of the link, in its frame.
    V_r, dV_r : array_like, shape (6,)
        Required velocity ``[v; ω]`` and its time derivative, in the link frame.
    g : array_like, shape (3,), m/s²
        Upward gravity in the link frame.
    """
    w = np.asarray(omega, dtype=float)
    V_r = np.asarray(V_r, dtype=float)
    dV_r = np.asarray(dV_r, dtype=float)
    v_r, w_r, dw = V_r[:3], V_r[3:], dV_r[3:]
    W, Wr = _skew(w), _skew(w_r)
    a = dV_r[:3] + W @ v_r + np.asarray(g, dtype=float)
    Y = np.zeros((6, N_PARAMS))
    Y[:3, 0] = a
    Y[:3, 1:4] = _skew(dw) + W @ Wr
    Y[3:, 1:4] = -_skew(a)
    for c, (B, tr) in enumerate(_Q_BASIS):
        Y[3:, 4 + c] = tr * dw - B @ dw - Wr @ (B @ w)
    w_x_wr = W @ w_r
    for j in range(3):
        col = W[:, j] * w_r[j]
        col[j] += dw[j] + w_x_wr[j]
        Y[3:, 10 + j] = col
    return Y


def _rotate_t(q: float, V) -> np.ndarray:
    """``diag(R, R)ᵀ V`` with ``R = Rz(q)``: a 6-vector of {C} re-expressed in {A}'s axes."""
    Rt = rz(q).T
    V = np.asarray(V, dtype=float)
    return np.concatenate([Rt @ V[:3], Rt @ V[3:]])


def link_a_velocity(q: float, qd: float, V_C) -> np.ndarray:
    """Velocity of {A} (Link a) from that of {C} (Link b) across the joint.

    ``V_A = ᶜU_Aᵀ V_C + z q̇`` with ``ᶜU_A = diag(Rz(q), Rz(q))`` (common origin).

    Parameters
    ----------
    q : float, rad
        Joint angle.
    qd : float, rad/s
        Joint velocity (actual, or required ``q̇_r`` for required velocities).
    V_C : array_like, shape (6,)
        ``[v; ω]`` of {C} in {C}, m/s and rad/s.

    Returns
    -------
    ndarray, shape (6,)
        ``[v; ω]`` of {A} in {A}.
    """
    return _rotate_t(q, V_C) + qd * _Z6


def link_a_acceleration(q: float, qd: float, qdd: float, V_C, dV_C) -> np.ndarray:
    """Exact time derivative of :func:`link_a_velocity` (body components).

    ``d/dt (Rᵀ x) = Rᵀ ẋ − q̇ (ẑ×) Rᵀ x`` per 3-D block (``Ṙ = q̇ (ẑ×) R`` for ``R = Rz(q)``), plus
    ``z q̈``. ``qd`` is the same joint velocity that multiplies ``z`` in the velocity, i.e. the
    rate of ``q``.

    Parameters
    ----------
    q, qd, qdd : float
        Joint angle (rad), velocity (rad/s), acceleration (rad/s²).
    V_C, dV_C : array_like, shape (6,)
        Velocity of {C} and its time derivative, in {C}.

    Returns
    -------
    ndarray, shape (6,)
    """
    dV = _rotate_t(q, dV_C)
    W = _rotate_t(q, V_C)
    zx = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    dV[:3] -= qd * (zx @ W[:3])
    dV[3:] -= qd * (zx @ W[3:])
    return dV + qdd * _Z6


def required_net_force(theta, V, V_r, dV_r, g, K) -> np.ndarray:
    """``F*_r = Y(ω, V_r, dV_r/dt, g) θ̂ + K (V_r − V)``: a link's required net force/moment.

    Parameters
    ----------
    theta : array_like, shape (13,)
        Parameter estimate in the link frame (MRM Table 1 order).
    V, V_r, dV_r : array_like, shape (6,)
        Actual and required velocity of the link frame and the time derivative of the required
        one, all in the link frame.
    g : array_like, shape (3,), m/s²
        Upward gravity in the link frame (``ᴬR_I [0, 0, 9.81]``).
    K : array_like, shape (6,)
        Diagonal of the velocity-error gain, N·s/m (rows 0-2) and N·m·s/rad (rows 3-5).

    Returns
    -------
    ndarray, shape (6,), ``[f; m]`` in N and N·m.
    """
    V = np.asarray(V, dtype=float)
    V_r = np.asarray(V_r, dtype=float)
    Y = link_regressor(V[3:], V_r, dV_r, g)
    return Y @ np.asarray(theta, dtype=float) + np.asarray(K, dtype=float) * (V_r - V)


def adaptation_signal(V, V_r, dV_r, g) -> np.ndarray:
    """``s = Yᵀ (V_r − V)``, shape (13,): the gradient that drives adaptation."""
    V = np.asarray(V, dtype=float)
    V_r = np.asarray(V_r, dtype=float)
    return link_regressor(V[3:], V_r, dV_r, g).T @ (V_r - V)


def projection_update(theta, s, rho_T, lower, upper) -> np.ndarray:
    """One discrete adaptation step with the projection function, per parameter.

    ``κ = 0`` when ``θ̂ ≤ θ̲`` and ``s ≤ 0``, or ``θ̂ ≥ θ̄`` and ``s ≥ 0``; else ``κ = s``;
    then ``θ̂ ← clip(θ̂ + ρT κ, θ̲, θ̄)``.

    Parameters
    ----------
    theta, s, rho_T, lower, upper : array_like, shape (13,)
        Estimate, adaptation signal, adaptation gain times period, bounds.
    """
    theta = np.asarray(theta, dtype=float)
    s = np.asarray(s, dtype=float)
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    frozen = ((theta <= lower) & (s <= 0.0)) | ((theta >= upper) & (s >= 0.0))
    kappa = np.where(frozen, 0.0, s)
    stepped = np.clip(theta + np.asarray(rho_T, dtype=float) * kappa, lower, upper)
    return np.where(frozen, theta, stepped)


@dataclass
class ModuleGains:
    """Gains and adaptation settings of one module's two links (index 0: Link a, 1: Link b).

    Attributes
    ----------
    K : ndarray, shape (2, 6)
        Velocity-error gains, N·s/m and N·m·s/rad.
    rho : ndarray, shape (2, 13)
        Adaptation gains ρ (units of θ per unit of s per second); zero disables adaptation.
    lower, upper : ndarray, shape (2, 13)
        Projection bounds of the estimates.
    """

    K: np.ndarray
    rho: np.ndarray = field(default_factory=lambda: np.zeros((2, N_PARAMS)))
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None

    def __post_init__(self):
        self.K = np.array(self.K, dtype=float).reshape(2, 6)
        self.rho = np.array(self.rho, dtype=float).reshape(2, N_PARAMS)
        if np.any(self.K < 0.0) or np.any(self.rho < 0.0):
            raise ValueError("gains K and rho must be non-negative")


class ModuleVDC:
    """VDC link dynamics of one module with the node's information, one call per period.

    Parameters
    ----------
    theta : array_like, shape (2, 13)
        Initial estimates: ``[0]`` Link a in {A}, ``[1]`` Link b in {C}.
    gains : ModuleGains
    period : float, s
        Control period ``T`` of the backward differences and of the adaptation step.

    Notes
    -----
    The first call after construction or :meth:`reset` has no previous required velocity: its
    ``dV_rC/dt`` and ``q̈_r`` are zero (the node starts its derivative history there too).
    """

    def __init__(self, theta, gains: ModuleGains, period: float = 1e-3):
        theta = np.array(theta, dtype=float).reshape(2, N_PARAMS)
        if not period > 0.0:
            raise ValueError(f"period must be positive, not {period!r}")
        self.theta = theta
        self.gains = gains
        self.period = float(period)
        self.lower = theta.copy() if gains.lower is None else np.array(gains.lower, dtype=float)
        self.upper = theta.copy() if gains.upper is None else np.array(gains.upper, dtype=float)
        self._prev: tuple[float, np.ndarray] | None = None

    def reset(self) -> None:
        """Forget the derivative history (next call has zero ``dV_rC/dt`` and ``q̈_r``)."""
        self._prev = None

    def step(self, q: float, qd: float, qd_r: float, V_C, V_rC, g_C,
             adapt: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """One period: required net forces of Link a and Link b, then adaptation.

        Parameters
        ----------
        q, qd : float
            Joint angle (rad) and velocity (rad/s), the node's snapshot at the period start.
        qd_r : float, rad/s
            Required joint velocity (Comm B).
        V_C, V_rC : array_like, shape (6,)
            Actual and required velocity of {C} in {C} (Comm B).
        g_C : array_like, shape (3,), m/s²
            Upward gravity in {C} (previous period's Comm D).
        adapt : bool
            Update the estimates after computing the forces (the forces of this period use the
            estimates from before the update).

        Returns
        -------
        F_a, F_b : ndarray, shape (6,)
            Required net force/moment of Link a in {A} and of Link b in {C}.
        """
        V_C = np.asarray(V_C, dtype=float)
        V_rC = np.asarray(V_rC, dtype=float)
        g_C = np.asarray(g_C, dtype=float)
        V_A = link_a_velocity(q, qd, V_C)
        V_rA = link_a_velocity(q, qd_r, V_rC)
        g_A = rz(q).T @ g_C
        if self._prev is None:
            self._prev = (qd_r, V_rC)
        qdd_r = (qd_r - self._prev[0]) / self.period
        dV_rC = (V_rC - self._prev[1]) / self.period
        dV_rA = link_a_acceleration(q, qd, qdd_r, V_rC, dV_rC)
        self._prev = (qd_r, V_rC)
        links = ((V_A, V_rA, dV_rA, g_A), (V_C, V_rC, dV_rC, g_C))
        forces = []
        for i, (V, V_r, dV_r, g) in enumerate(links):
            forces.append(required_net_force(self.theta[i], V, V_r, dV_r, g, self.gains.K[i]))
        if adapt:
            for i, (V, V_r, dV_r, g) in enumerate(links):
                s = adaptation_signal(V, V_r, dV_r, g)
                self.theta[i] = projection_update(self.theta[i], s,
                                                  self.gains.rho[i] * self.period,
                                                  self.lower[i], self.upper[i])
        return forces[0], forces[1]
