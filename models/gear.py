"""The harmonic drive's torsional compliance: Harmonic Drive's piecewise-linear stiffness curve,
its hysteresis (lost motion), structural damping, and the stability bound of the plant step.

Ref: Harmonic Drive AG, *CHA series engineering data* 1018854 12/2015 V01, §3.3.5 Table 50.3
("Torsional stiffness", CHA-14A: a size-14, ratio > 50 Harmonic Drive gear, taken for the
FHA-14C's — an assumption, the FHA-C mini manual's own table was not found) and §4.2
"Calculation of the torsion angle" (equations 68.1-68.4), e.g. as reproduced at
easymanua.ls/harmonic-drive/cha/manual?p=50 and manualshive.com/en/manual/harmonic-drive/cha/
3953713?page=68. The size-11 values are assumptions (``docs/plant.md``).

Torque–torsion curve at the output, for a deflection ``φ ≥ 0`` (odd in ``φ``)::

    φ ≤ φ1:        T = K1 φ                       φ1 = T1 / K1
    φ1 < φ ≤ φ2:   T = T1 + K2 (φ − φ1)           φ2 = φ1 + (T2 − T1) / K2
    φ > φ2:        T = T2 + K3 (φ − φ2)

which is the catalogue's equation 68.1-68.3 solved for the torque.

Hysteresis (``hysteresis = "dahl"``, the default): a harmonic drive has no backlash; its
"hysteresis loss" is the width at zero torque of the loop between the loading and unloading
curves, from friction inside the flexspline and wave generator. The gear torque is the curve
of the whole deflection ``δ`` plus a Dahl friction torque ``z``::

    τ = T(δ) + z,     dz/dδ = σ (1 − z / F_h · sgn δ̇)         (Dahl, exponent 1)

``|z| ≤ F_h`` always and the tangent stiffness ``dT/dδ + dz/dδ`` lies in ``[K, K + 2σ]``: the
link is never disconnected. On a monotone branch ``z → ± F_h``, so the loading and unloading
curves are ``T(δ) ± F_h`` and cross zero torque at ``δ = ∓ T⁻¹(F_h)``: with ``F_h = T(a)``,
``a`` half the catalogue's hysteresis loss, the loop's width at zero torque is the catalogue's
``2a``. ``σ = c · K1`` sets how fast ``z`` turns after a reversal (rate-independent: ``z`` is a
function of the deflection path, not of time); :func:`dahl` integrates it exactly over a
deflection increment. Passive: with the storage ``z² / 2σ`` the element dissipates
``|δ̇| z² / F_h ≥ 0``.

``hysteresis = "play"`` keeps the earlier model as a named option (not the catalogue's
physics: the elastic deflection ``y`` follows ``δ`` through a dead zone of width ``2a``,
``y ← clamp(y, δ − a, δ + a)``, inside which the gear transmits no torque).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mrm_cosim.errors import InputError

__all__ = ["GearSpec", "GEARS", "GearConfig", "ARCMIN", "STEP_MARGIN", "DAHL_SIGMA",
           "HYSTERESIS", "gear_torque", "play", "dahl", "dahl_loop_area", "deflection",
           "step_bound", "check_step"]

ARCMIN = math.pi / (180.0 * 60.0)
"""One arc minute in rad."""


@dataclass(frozen=True)
class GearSpec:
    """The torsional data of one harmonic drive gear at its output.

    Attributes
    ----------
    t1, t2 : float, N·m
        Limit torques of the curve's segments.
    k1, k2, k3 : float, N·m/rad
        Stiffness below ``t1``, between ``t1`` and ``t2``, above ``t2``.
    hysteresis : float, rad
        Hysteresis loss: width of the torque–torsion loop at zero torque.
    source : str
    """

    t1: float
    t2: float
    k1: float
    k2: float
    k3: float
    hysteresis: float
    source: str = ""

    def __post_init__(self):
        for key in ("t1", "t2", "k1", "k2", "k3"):
            v = getattr(self, key)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"gear {key} must be positive, not {v!r}")
        if not self.t2 > self.t1:
            raise ValueError(f"gear t2 {self.t2!r} must exceed t1 {self.t1!r}")
        if not (math.isfinite(self.hysteresis) and self.hysteresis >= 0.0):
            raise ValueError(f"gear hysteresis must be non-negative, not {self.hysteresis!r}")

    @property
    def phi1(self) -> float:
        """Deflection at ``t1``, rad."""
        return self.t1 / self.k1

    @property
    def phi2(self) -> float:
        """Deflection at ``t2``, rad."""
        return self.phi1 + (self.t2 - self.t1) / self.k2

    @property
    def k_max(self) -> float:
        """The largest segment stiffness, N·m/rad (what bounds the step)."""
        return max(self.k1, self.k2, self.k3)

    def scaled(self, factor: float) -> GearSpec:
        """The same curve with every stiffness times ``factor`` (the limit torques stay)."""
        return GearSpec(self.t1, self.t2, self.k1 * factor, self.k2 * factor, self.k3 * factor,
                        self.hysteresis, self.source)

    def deflection(self, torque: float) -> float:
        """The catalogue's torsion angle for an output torque (equations 68.1-68.3), rad."""
        return deflection(torque, self.t1, self.t2, self.k1, self.k2, self.k3)


def deflection(torque: float, t1: float, t2: float, k1: float, k2: float, k3: float) -> float:
    """The catalogue's torsion angle for an output torque (equations 68.1-68.3), rad."""
    t = abs(torque)
    if t <= t1:
        phi = t / k1
    elif t <= t2:
        phi = t1 / k1 + (t - t1) / k2
    else:
        phi = t1 / k1 + (t2 - t1) / k2 + (t - t2) / k3
    return math.copysign(phi, torque)


_CHA = ("Harmonic Drive AG, CHA series engineering data 1018854 12/2015 V01, Table 50.3 "
        "(CHA-14A, ratio > 50) and Table 50.1 (hysteresis loss < 1 arcmin, ratio > 50)")

GEARS: dict[str, GearSpec] = {
    # size 14, ratio 100: the catalogue's size-14 gear of ratio > 50 (CHA-14A), taken for the
    # FHA-14C's (assumed the same gear size and family: docs/plant.md)
    "FHA-14C-100": GearSpec(t1=2.0, t2=6.9, k1=4.7e3, k2=6.1e3, k3=7.1e3,
                            hysteresis=1.0 * ARCMIN, source=_CHA),
    # size 11, ratio 100: ASSUMED — no catalogue table was found for size 11; the limit torques
    # scale with the actuators' maximum torque (11 / 28) and the stiffness with the cube of the
    # size ((11 / 14)³ = 0.485), the catalogue's hysteresis loss kept (docs/plant.md)
    "FHA-11C-100": GearSpec(t1=2.0 * 11.0 / 28.0, t2=6.9 * 11.0 / 28.0,
                            k1=4.7e3 * (11.0 / 14.0) ** 3, k2=6.1e3 * (11.0 / 14.0) ** 3,
                            k3=7.1e3 * (11.0 / 14.0) ** 3, hysteresis=1.0 * ARCMIN,
                            source="assumption: size 14 scaled, docs/plant.md"),
}
"""Gear torsional data by actuator name."""


def gear_torque(y: float, t1: float, t2: float, k1: float, k2: float, k3: float) -> float:
    """Elastic torque of the curve at the elastic deflection ``y``, N·m (odd in ``y``).

    Python floats, the same operations as the compiled kernel (``models.compliant_kernel_src``).
    """
    phi1 = t1 / k1
    phi2 = phi1 + (t2 - t1) / k2
    x = y if y >= 0.0 else -y
    if x <= phi1:
        t = k1 * x
    elif x <= phi2:
        t = t1 + k2 * (x - phi1)
    else:
        t = t2 + k3 * (x - phi2)
    return t if y >= 0.0 else -t


def play(y: float, delta: float, a: float) -> float:
    """The play operator: ``y`` moved the least to lie within ``[delta − a, delta + a]``."""
    lo = delta - a
    hi = delta + a
    if y < lo:
        return lo
    if y > hi:
        return hi
    return y


def dahl(z: float, step: float, fh: float, sigma: float) -> float:
    """The Dahl friction torque after the deflection moved by ``step``, N·m: the exact
    solution of ``dz/dδ = σ (1 − z / F_h · sgn step)`` over a monotone increment,
    ``z⁺ = s − (s − z) e^{−σ |step| / F_h}`` with ``s = ± F_h`` (unconditionally stable, keeps
    ``|z| ≤ F_h``, independent of how fast the step was taken). ``fh = 0``: no hysteresis, ``z``
    is returned unchanged (0).

    Python floats, the same operations as the compiled kernel (``models.compliant_kernel_src``).
    """
    if fh == 0.0 or step == 0.0:
        return z
    if step > 0.0:
        s = fh
        e = math.exp(-sigma * step / fh)
    else:
        s = -fh
        e = math.exp(sigma * step / fh)
    return s - (s - z) * e


def dahl_loop_area(amplitude: float, fh: float, sigma: float) -> float:
    """Energy a Dahl element dissipates per cycle of the deflection between ``± amplitude``
    once the loop is periodic, J (the area of its torque–deflection loop; the curve ``T``
    encloses none).

    On the rising branch from ``−A`` (``z = −z_m``) ``z = F − (F + z_m) e^{−σ(δ + A)/F}``;
    periodicity gives ``z_m = F (1 − E) / (1 + E)``, ``E = e^{−2σA/F}``; by symmetry the area
    is twice the integral of the rising branch: ``2 [2 F A − (F + z_m)(F/σ)(1 − E)]``.
    """
    F, A = fh, amplitude
    E = math.exp(-2.0 * sigma * A / F)
    zm = F * (1.0 - E) / (1.0 + E)
    return 2.0 * (2.0 * F * A - (F + zm) * (F / sigma) * (1.0 - E))


def step_bound(k: np.ndarray, d: np.ndarray, motor_inertia: np.ndarray,
               link_mass_matrix: np.ndarray) -> tuple[float, float, float]:
    """The largest stable step of the plant's gear coupling, s, with the mode's data.

    The gear's relative coordinate ``x = θ − q`` obeys ``ẍ = −W (K x + D ẋ) + …`` with
    ``W = B⁻¹ + M(q)⁻¹``. The plant's midpoint scheme (drift h/2, kick h with the damping on
    the step's start velocities, drift h/2) has, on each mode ``ẍ = −ω² x − c ẋ``, the
    amplification matrix of trace ``2 − h²ω² − hc`` and determinant ``1 − hc``: it is stable
    iff ``h²ω² + 2hc ≤ 4`` (and ``hc ≤ 2``), i.e. ``h ≤ (√(c² + 4ω²) − c) / ω²``. Bounded over
    the modes by ``ω² = λmax(W^½ K W^½)`` and ``c = λmax(W^½ D W^½)``.

    Parameters
    ----------
    k, d : ndarray, shape (n,)
        Largest stiffness (N·m/rad) and damping (N·m·s/rad) of each gear.
    motor_inertia : ndarray, shape (n,), kg·m² (output-referred)
    link_mass_matrix : ndarray, shape (n, n), kg·m²

    Returns
    -------
    (h_max, omega, c) : floats, s, rad/s, 1/s
    """
    W = np.diag(1.0 / motor_inertia) + np.linalg.inv(link_mass_matrix)
    lw, vw = np.linalg.eigh(0.5 * (W + W.T))
    Wh = vw @ np.diag(np.sqrt(lw)) @ vw.T
    omega2 = float(np.linalg.eigvalsh(Wh @ np.diag(k) @ Wh).max())
    c = float(np.linalg.eigvalsh(Wh @ np.diag(d) @ Wh).max())
    return (math.sqrt(c * c + 4.0 * omega2) - c) / omega2, math.sqrt(omega2), c


def check_step(dt: float, k, d, motor_inertia, link_mass_matrix, margin: float,
               stiffness_field: str, damping_field: str, hysteresis_stiffness=None,
               hysteresis_field: str = "") -> float:
    """Refuse a gear the plant step cannot integrate stably (``h_max / margin < dt``).

    ``k`` is each gear's largest stiffness; ``hysteresis_stiffness`` (optional, per gear) the
    Dahl element's ``σ``, whose tangent stiffness reaches ``2σ`` just after a reversal, so the
    bound uses ``k + 2σ``. Names ``damping_field`` when the damping term dominates
    (``c h > ω² h²``), else ``hysteresis_field`` when the step would be stable without the
    Dahl element, else ``stiffness_field``; the message gives the largest step allowed.
    Returns ``h_max``.
    """
    k = np.asarray(k, float)
    dahl_breaks = False
    if hysteresis_stiffness is not None:
        extra = 2.0 * np.asarray(hysteresis_stiffness, float)
        without = step_bound(k, np.asarray(d, float), np.asarray(motor_inertia, float),
                             np.asarray(link_mass_matrix, float))[0]
        dahl_breaks = dt <= without / margin        # stable without the Dahl element
        k = k + extra
    h_max, omega, c = step_bound(np.asarray(k, float), np.asarray(d, float),
                                 np.asarray(motor_inertia, float),
                                 np.asarray(link_mass_matrix, float))
    allowed = h_max / margin
    if dt > allowed:
        field = damping_field if c * dt > omega * omega * dt * dt else \
            hysteresis_field if dahl_breaks and hysteresis_field else stiffness_field
        raise InputError(field, f"makes the gear mode (ω = {omega:.4g} rad/s, damping rate "
                         f"{c:.4g} 1/s) unstable at plant.dt = {dt:g} s: the largest step it "
                         f"allows is {allowed:.3g} s (bound {h_max:.3g} s / safety {margin:g})")
    return h_max


DAHL_SIGMA = 0.5 * math.log(20.0)
"""Default Dahl stiffness over K1 (``σ = DAHL_SIGMA · K1`` ≈ 1.50 K1) [ASSUMED]: after a
reversal the friction torque covers 95 % of its swing from ``−F_h`` to ``+F_h`` within one
hysteresis loss of travel (``2 F_h e^{−σ·2a/F_h} = 0.05 · 2 F_h`` with ``F_h = K1 a``), the
travel over which the play took it up; the catalogue gives no figure for the loop's corner."""

HYSTERESIS = ("dahl", "play", "off")
"""The hysteresis models of ``[plant.gear] hysteresis`` (true means "dahl", false "off")."""

STEP_MARGIN = 4.0
"""Safety factor on the step bound of :func:`step_bound`: the bound is computed at the home
configuration (the link inertia changes along a motion) with the nominal gear (assumption,
``docs/plant.md``)."""


@dataclass(frozen=True)
class GearConfig:
    """Settings of the compliant joints (``[plant.gear]``; used when ``joints = "compliant"``).

    Attributes
    ----------
    stiffness_scale : float
        Every gear's K1, K2, K3 times this (1: the catalogue; a sweep varies it).
    stiffness_spread : float
        Relative half-width of the true stiffness around the scaled catalogue value (uniform,
        one factor per joint from the plant seed), 0 … 0.5.
    damping_ratio : float
        Structural damping: ``d = 2 ζ √(K1 · B)`` per gear with ``B`` the motor-side inertia
        (damping ratio of the motor against a locked link). [ASSUMED 0.05]
    hysteresis : str
        The catalogue's hysteresis loss: "dahl" (default; a Dahl friction torque on the
        curve, loop width at zero torque = the loss, the link never disconnected), "play" (a
        dead zone of that width: the earlier model, kept as a named option) or "off" (the
        one-valued curve). ``true`` / ``false`` mean "dahl" / "off".
    hysteresis_stiffness : float
        Dahl stiffness ``σ`` over each gear's K1 (how sharply the loop turns after a
        reversal). [ASSUMED ``DAHL_SIGMA`` = ln 20 / 2 ≈ 1.50]
    ripple : float
        Wave-generator torque ripple amplitude, fraction of the actuator's peak torque, at twice
        the motor's revolution frequency. [ASSUMED 0.005]
    current_noise : float
        Current-sensor noise, rms, fraction of the peak torque, white over each plant step.
        [ASSUMED 0.002]
    """

    stiffness_scale: float = 1.0
    stiffness_spread: float = 0.1
    damping_ratio: float = 0.05
    hysteresis: str = "dahl"
    hysteresis_stiffness: float = DAHL_SIGMA
    ripple: float = 0.005
    current_noise: float = 0.002

    def __post_init__(self):
        for name in ("stiffness_scale", "damping_ratio", "hysteresis_stiffness"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) \
                    or v <= 0.0:
                raise InputError(f"plant.gear.{name}", f"must be a positive number (zero or "
                                 f"less has no gear, or one that gains energy), not {v!r}")
            object.__setattr__(self, name, float(v))
        for name, top in (("stiffness_spread", 0.5), ("ripple", 0.2), ("current_noise", 0.2)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) \
                    or not 0.0 <= v <= top:
                raise InputError(f"plant.gear.{name}", f"must be in [0, {top}], not {v!r}")
            object.__setattr__(self, name, float(v))
        h = self.hysteresis
        if isinstance(h, bool):
            h = "dahl" if h else "off"
        if h not in HYSTERESIS:
            raise InputError("plant.gear.hysteresis", f"must be one of "
                             f"{', '.join(map(repr, HYSTERESIS))} (or true / false), not "
                             f"{self.hysteresis!r}")
        object.__setattr__(self, "hysteresis", h)
