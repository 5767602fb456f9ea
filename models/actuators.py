"""Harmonic Drive FHA-C mini actuators of the MRM modules: datasheet values with their sources.

Each :class:`ActuatorSpec` holds one actuator's nominal data, all referred to the joint (the
actuator's output shaft): torques in N·m, speeds in rad/s, inertia in kg·m². Values come from

* [MRM]  Zhu, Lamarche, Dupuis, Martin, *Modular Robot Manipulators with Precision Control*,
  Table 1 (``seeds/003_*.txt``): peak / continuous torque, gear ratio, encoder pulses;
* [FHA]  Harmonic Drive, *FHA-C mini series AC servo actuator manual*, §1-4 "Specifications",
  100/200 VAC version with the 2000-pulse incremental encoder (the MRM's encoder), e.g. as
  reproduced at manualshive.com/en/manual/harmonic-drive/fha-c-mini-series/3976629?page=13;
* [ASSUMED] our assumptions where no datasheet gives the number (friction, current-loop
  bandwidth), with the reasoning in ``docs/plant.md``.

The friction numbers here are *nominal* values of the plant only. No controller may read them:
the plant perturbs them (``models.plant``) and the controller must compensate friction it does
not know (estimate or adapt it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["ActuatorSpec", "ACTUATORS", "RPM"]

RPM = 2.0 * math.pi / 60.0
"""One revolution per minute in rad/s."""


@dataclass(frozen=True)
class ActuatorSpec:
    """Nominal data of one actuator, referred to its output shaft (the joint).

    Attributes
    ----------
    name : str
        Harmonic Drive model name, e.g. ``"FHA-11C-100"``.
    gear_ratio : int
        Harmonic Drive reduction ratio (motor revolutions per output revolution).
    peak_torque : float, N·m
        Maximum output torque; the amplifier saturates the torque here.
    continuous_torque : float, N·m
        Allowable continuous output torque (thermal; not enforced by the plant).
    max_speed : float, rad/s
        Maximum output speed.
    torque_constant : float, N·m/A
        Output torque per motor phase current.
    max_current : float, A
        Motor current at peak torque.
    output_inertia : float, kg·m²
        Moment of inertia of the rotating actuator parts referred to the output (GD²/4):
        rotor, wave generator and encoder disc times ``gear_ratio²``. This is the reflected
        rotor inertia (armature) of the joint.
    encoder_lines : int
        Incremental encoder pulses (lines) per motor revolution.
    phase_resistance : float, Ω
    phase_inductance : float, H
    emf_constant : float, V·s/rad
        Back-EMF constant referred to the output shaft.
    mass : float, kg
        Actuator mass (already part of the link masses of Table 1; informative only).
    coulomb_friction : float, N·m
        Kinetic (Coulomb) friction at the output. [ASSUMED]
    static_friction : float, N·m
        Break-away (static) friction at the output, ≥ ``coulomb_friction``. [ASSUMED]
    stribeck_velocity : float, rad/s
        Output speed over which friction falls from static to Coulomb. [ASSUMED]
    viscous_friction : float, N·m·s/rad
        Viscous friction coefficient at the output. [ASSUMED]
    current_bandwidth : float, Hz
        −3 dB bandwidth of the amplifier's closed current loop (first-order lag). [ASSUMED]
    sources : dict of str to str
        Where each value comes from, keyed by attribute name.
    """

    name: str
    gear_ratio: int
    peak_torque: float
    continuous_torque: float
    max_speed: float
    torque_constant: float
    max_current: float
    output_inertia: float
    encoder_lines: int
    phase_resistance: float
    phase_inductance: float
    emf_constant: float
    mass: float
    coulomb_friction: float
    static_friction: float
    stribeck_velocity: float
    viscous_friction: float
    current_bandwidth: float
    sources: dict[str, str] = field(default_factory=dict, compare=False)

    def __post_init__(self):
        for key in ("peak_torque", "continuous_torque", "max_speed", "torque_constant",
                    "max_current", "output_inertia", "phase_resistance", "phase_inductance",
                    "emf_constant", "mass", "stribeck_velocity", "current_bandwidth"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{self.name}: {key} must be positive, not {value!r}")
        for key in ("coulomb_friction", "static_friction", "viscous_friction"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{self.name}: {key} must be non-negative, not {value!r}")
        if self.static_friction < self.coulomb_friction:
            raise ValueError(f"{self.name}: static_friction {self.static_friction!r} is below "
                             f"coulomb_friction {self.coulomb_friction!r}")
        if self.gear_ratio <= 0 or self.encoder_lines <= 0:
            raise ValueError(f"{self.name}: gear_ratio and encoder_lines must be positive")

    @property
    def rotor_inertia(self) -> float:
        """Inertia of the rotating parts on the motor side, kg·m² (``output_inertia / N²``)."""
        return self.output_inertia / self.gear_ratio**2

    @property
    def counts_per_rev(self) -> int:
        """Quadrature encoder counts per output revolution: lines × 4 × gear ratio."""
        return 4 * self.encoder_lines * self.gear_ratio

    @property
    def current_time_constant(self) -> float:
        """Time constant of the current loop, s: ``1 / (2π · current_bandwidth)``."""
        return 1.0 / (2.0 * math.pi * self.current_bandwidth)

    @property
    def electrical_time_constant(self) -> float:
        """Open-loop L/R time constant of a motor phase, s."""
        return self.phase_inductance / self.phase_resistance

    @property
    def max_count_rate(self) -> float:
        """Quadrature counts per second at ``max_speed``."""
        return self.max_speed * self.counts_per_rev / (2.0 * math.pi)


_FHA = ("Harmonic Drive FHA-C mini manual §1-4 Specifications, 100/200 VAC incremental-encoder "
        "version")
_MRM = "MRM paper Table 1"
_ASSUMED = "assumption, docs/plant.md"
_COMMON_SOURCES = {
    "gear_ratio": f"{_MRM}; {_FHA}",
    "peak_torque": f"{_MRM} ('peak torque'); {_FHA} ('maximum torque')",
    "continuous_torque": f"{_MRM}; {_FHA} ('allowable continuous torque')",
    "max_speed": f"{_FHA}: 58 r/min",
    "torque_constant": _FHA,
    "max_current": _FHA,
    "output_inertia": f"{_FHA}: inertia moment GD²/4 at the output",
    "encoder_lines": f"{_MRM} ('encoder pulse'); {_FHA}: 2000 pulses, 800,000 counts/rev output",
    "phase_resistance": f"{_FHA} (20 °C)",
    "phase_inductance": _FHA,
    "emf_constant": f"{_FHA}: EMF constant in V/(r/min) of the output, converted",
    "mass": _FHA,
    "coulomb_friction": _ASSUMED,
    "static_friction": _ASSUMED,
    "stribeck_velocity": _ASSUMED,
    "viscous_friction": _ASSUMED,
    "current_bandwidth": _ASSUMED,
}

ACTUATORS: dict[str, ActuatorSpec] = {
    "FHA-11C-100": ActuatorSpec(
        name="FHA-11C-100", gear_ratio=100,
        peak_torque=11.0, continuous_torque=4.2, max_speed=58.0 * RPM,
        torque_constant=13.0, max_current=1.1, output_inertia=0.067, encoder_lines=2000,
        phase_resistance=3.7, phase_inductance=3.2e-3, emf_constant=1.6 / RPM, mass=0.62,
        coulomb_friction=0.5, static_friction=0.7, stribeck_velocity=0.01,
        viscous_friction=0.08, current_bandwidth=1000.0,
        sources=dict(_COMMON_SOURCES)),
    "FHA-14C-100": ActuatorSpec(
        name="FHA-14C-100", gear_ratio=100,
        peak_torque=28.0, continuous_torque=6.8, max_speed=58.0 * RPM,
        torque_constant=15.0, max_current=2.4, output_inertia=0.20, encoder_lines=2000,
        phase_resistance=1.4, phase_inductance=1.8e-3, emf_constant=1.70 / RPM, mass=1.2,
        coulomb_friction=1.0, static_friction=1.4, stribeck_velocity=0.01,
        viscous_friction=0.16, current_bandwidth=1000.0,
        sources=dict(_COMMON_SOURCES)),
}
"""Nominal actuator data by model name."""
