"""The modules' holding brakes: spring-applied, electrically released, on the motor shaft.

Each joint's actuator carries a holding brake on its motor shaft, as the larger Harmonic
Drive FHA-C actuators offer one as an option (the FHA-C mini catalogue of our FHA-11C/14C lists
none: ``docs/plant.md`` "Brake" says which numbers are assumptions). The node drives it
(IEC 61800-5-2's SBC, safe brake control): its ``brake`` output high engages the brake (the
coil is de-energised and the spring applies it), low releases it.

Model, per joint (:class:`BrakeConfig`, ``[plant.brake]``):

* dead time: the brake's torque appears ``engage_time`` after the command to engage (the
  armature's air gap closes) and disappears ``release_time`` after the command to release
  (the coil's current builds up); a command that is taken back before it has acted is
  forgotten;
* engaged, the brake is a friction element on the motor shaft: a joint at rest stays locked
  while the torque needed to hold it is at most the *holding torque* (static), a joint that
  moves (or is pushed beyond the holding torque) slips against the *kinetic* torque
  ``slip_ratio × holding``. The plants add it to the joint's friction level, which their
  set-valued friction solve handles exactly (``models.plant``, ``models.compliant``).

Torques are given at the motor shaft (as a brake catalogue gives them) and act at the joint
times the gear ratio (the rigid plant's joint; the compliant plant's output-referred motor
side).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mrm_cosim.errors import InputError

__all__ = ["BrakeConfig", "HOLDING_OVER_PEAK"]

#: Default holding torque over the motor's peak torque (both at the motor shaft). [ASSUMED,
#: docs/plant.md "Brake"] Sized so that the brake, even slipping (``slip_ratio`` 0.8: 1.2 ×
#: peak), beats the motor at its peak torque: the node's hold loop still runs while the brake
#: engages, and at 1.2 × peak (0.96 × peak slipping) a saturated loop dragged joint 1 of mrm3
#: 1.3 mrad through an engaged brake after a stop at the quintic's peak speed (0.45 mrad at 1.5).
HOLDING_OVER_PEAK = 1.5


@dataclass(frozen=True)
class BrakeConfig:
    """Settings of the joints' holding brakes (``[plant.brake]``).

    Attributes
    ----------
    holding_torque : float or None, N·m at the motor shaft
        Static holding torque of every joint's brake; ``None``: :data:`HOLDING_OVER_PEAK`
        times each actuator's peak torque over its gear ratio (the motor's peak torque).
    slip_ratio : float
        Kinetic (slipping) over holding torque, in (0, 1]. [ASSUMED 0.8]
    engage_time : float, s
        From the command to engage to the full holding torque. [ASSUMED 15 ms]
    release_time : float, s
        From the command to release to no brake torque. [ASSUMED 25 ms]
    """

    holding_torque: float | None = None
    slip_ratio: float = 0.8
    engage_time: float = 0.015
    release_time: float = 0.025

    def __post_init__(self):
        h = self.holding_torque
        if h is not None:
            if isinstance(h, bool) or not isinstance(h, int | float) or not math.isfinite(h) \
                    or h <= 0.0:
                raise InputError("plant.brake.holding_torque",
                                 f"must be a positive number of N·m, not {h!r}")
            object.__setattr__(self, "holding_torque", float(h))
        s = self.slip_ratio
        if isinstance(s, bool) or not isinstance(s, int | float) or not 0.0 < s <= 1.0:
            raise InputError("plant.brake.slip_ratio", f"must be in (0, 1], not {s!r}")
        object.__setattr__(self, "slip_ratio", float(s))
        for name in ("engage_time", "release_time"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) \
                    or not 0.0 <= v <= 1.0:
                raise InputError(f"plant.brake.{name}", f"must be in [0, 1] s, not {v!r}")
            object.__setattr__(self, name, float(v))

    def holding_at_joint(self, actuators) -> list[float]:
        """Each joint's holding torque at the joint (N·m): the motor shaft's times the gear
        ratio. ``actuators``: the joints' :class:`models.actuators.ActuatorSpec`."""
        out = []
        for a in actuators:
            motor = (HOLDING_OVER_PEAK * a.peak_torque / a.gear_ratio
                     if self.holding_torque is None else self.holding_torque)
            out.append(motor * a.gear_ratio)
        return out

    def steps(self, dt: float) -> tuple[int, int]:
        """``(engage, release)`` times in whole plant steps of ``dt`` (rounded up, ≥ 1: a
        command acts from the step after the one it was given in at the earliest)."""
        return (max(1, math.ceil(self.engage_time / dt - 1e-9)),
                max(1, math.ceil(self.release_time / dt - 1e-9)))
