"""The node's safe stop on loss of the master: its parameters and their register words.

# Ref: IEC 61800-5-2:2016 §4.2.2 (safety sub-functions of power drive systems): STO (safe
# torque off), SS1 (safe stop 1: stop, then STO), SS2 (safe stop 2: stop, then monitored
# standstill).

When a node's watchdog trips (no valid packet for TIMEOUT cycles while armed) the node does
not drop its torque at once, which lets an arm fall under gravity; it runs an SS1-t sequence
(docs/node.md "Safe stop"):

1. **Stop and hold** (SS2's standstill, held by the node's own loop): for STOP_CYCLES the
   joint engine runs its PID program at every control tick on node-local references — the
   encoder count at the trip, zero velocity and acceleration, no feed-forward — with the PID
   gain words (``kp, ki, kd`` of the JOINT bank) as hold gains.
2. **Brake**: then the node asserts its ``brake`` output and keeps holding for BRAKE_CYCLES
   (the brake's engage time plus a margin).
3. **STO**: then the torque ramps to zero by RAMP per control tick; the brake stays engaged.

The hold gains are the PID words because a node in VDC or torque mode never reads them:
the master uploads hold gains there (:func:`hold_gains` at :attr:`SafeStopParams.hold_hz`);
a node in PID mode holds with its tracking gains. This module is pure Python: the master
(:func:`mrm_cosim.master.uploads.node_uploads`) converts the physical parameters with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mrm_cosim.errors import InputError, require_nonnegative, require_positive
from mrm_cosim.units import CLOCK_HZ

from .regs import Config

__all__ = ["SafeStopParams", "SAFE_STOP_CYCLES_MAX", "triple_pole_gains", "hold_gains",
           "safe_stop_config"]

#: Largest STOP_CYCLES / BRAKE_CYCLES value (the registers are 32 bits, unsigned).
SAFE_STOP_CYCLES_MAX = (1 << 32) - 1


@dataclass(frozen=True)
class SafeStopParams:
    """The safe stop's physical parameters (SI units).

    Attributes
    ----------
    stop_s : float, s
        Stop and hold before the brake is engaged (STOP_CYCLES). Assumption: 50 ms, enough
        for the hold loop at 15 Hz to stop a joint at the quintic's peak speed (its settling
        time ≈ 3/ω ≈ 32 ms).
    brake_s : float, s
        The brake's engage time plus a margin, during which the node still holds
        (BRAKE_CYCLES). Assumption: 50 ms (spring-applied holding brakes of this size engage
        in 10–40 ms; the plant's brake model states its own).
    hold_hz : float, Hz
        Triple pole of the hold loop for the joints whose node does not run its PID (VDC and
        torque modes): the PID words ``kp, ki, kd`` take :func:`hold_gains` for the joint's
        nominal inertia. A node in PID mode holds with its tracking gains. 15 Hz is the
        node PID's default bandwidth (``Gains.pid_fpga_hz``), stable on the compliant plant.
    """

    stop_s: float = 0.05
    brake_s: float = 0.05
    hold_hz: float = 15.0

    def __post_init__(self):
        for name in ("stop_s", "brake_s"):
            x = require_nonnegative(getattr(self, name), f"safe_stop.{name}")
            if x * CLOCK_HZ > SAFE_STOP_CYCLES_MAX:
                raise InputError(f"safe_stop.{name}", f"{x!r} s exceeds the node's 32-bit "
                                 f"cycle register ({SAFE_STOP_CYCLES_MAX / CLOCK_HZ:.4g} s)")
        require_positive(self.hold_hz, "safe_stop.hold_hz")


def triple_pole_gains(inertia, hz: float) -> dict:
    """PID gains placing a triple pole at ``−2π·hz`` for the inertia ``inertia`` (kg·m², a
    float or an array): ``kp`` N·m/rad, ``ki`` N·m/(rad·s), ``kd`` N·m·s/rad."""
    w = 2 * math.pi * hz
    return {"kp": 3 * inertia * w * w, "ki": inertia * w**3, "kd": 3 * inertia * w}


def hold_gains(params: SafeStopParams, inertia) -> dict:
    """The hold loop's PID gains (SI, :func:`triple_pole_gains` at ``params.hold_hz``) for a
    joint of nominal inertia ``inertia`` (kg·m²)."""
    return triple_pole_gains(inertia, params.hold_hz)


def safe_stop_config(params: SafeStopParams, clock_hz: float = float(CLOCK_HZ)) -> dict:
    """The CONFIG words ``{Config: int}`` of ``params``: STOP_CYCLES and BRAKE_CYCLES (the
    durations rounded to whole cycles of ``clock_hz``)."""
    return {Config.STOP_CYCLES: round(params.stop_s * clock_hz),
            Config.BRAKE_CYCLES: round(params.brake_s * clock_hz)}
