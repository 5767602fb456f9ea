"""The node's safe stop on loss of the master: its parameters and their register words.

# Ref: IEC 61800-5-2:2016 §4.2.2 (safety sub-functions of power drive systems): STO (safe
# torque off), SS1 (safe stop 1: stop, then STO; SS1-r / SS1-t: at standstill, or after a
# time), SS2 (safe stop 2: stop, then monitored standstill).

When a node's watchdog trips (no valid packet for TIMEOUT cycles while armed) the node does
not drop its torque at once, which lets an arm fall under gravity; it runs an SS1 sequence
whose brake waits for monitored standstill, with SS1-t's time limit as a fallback
(docs/node.md "Safe stop"):

1. **Stop and hold** (SS2's standstill, held by the node's own loop): the joint engine runs
   its PID program at every control tick on node-local references — the encoder count at
   the trip, zero velocity and acceleration, no feed-forward — with the PID gain words
   (``kp, ki, kd`` of the JOINT bank) as hold gains.
2. **Brake**: once the encoder's velocity word has been within ±STANDSTILL at STANDSTILL_TICKS
   consecutive ticks (the joint at standstill), at the latest STOP_CYCLES after the trip
   (status STOP_LIMIT then), the node asserts its ``brake`` output and keeps holding for
   BRAKE_CYCLES (the brake's engage time plus a margin). A brake engaged while the joint
   still moves has to stop it by slipping (joint 1 of the mrm3 slipped 9–13 mrad with a fixed
   80–100 ms stop).
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

from .fixed import VEL
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
        The time limit of the stop and hold before the brake is engaged (STOP_CYCLES): with
        the standstill rule on (``standstill`` > 0) the brake engages at standstill, at the
        latest this long after the trip (SS1-t as a fallback); off, exactly this long after
        the trip (SS1-t). Assumption: 50 ms, about the time the hold loop at 15 Hz takes to
        bring joint 1 of the mrm3 to rest from the quintic's peak speed (its first turning
        point, 8.8 mrad on, comes 61 ms after the cut).
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
    standstill: float = 0.0
    standstill_s: float = 0.01

    def __post_init__(self):
        for name in ("stop_s", "brake_s"):
            x = require_nonnegative(getattr(self, name), f"safe_stop.{name}")
            if x * CLOCK_HZ > SAFE_STOP_CYCLES_MAX:
                raise InputError(f"safe_stop.{name}", f"{x!r} s exceeds the node's 32-bit "
                                 f"cycle register ({SAFE_STOP_CYCLES_MAX / CLOCK_HZ:.4g} s)")
        require_positive(self.hold_hz, "safe_stop.hold_hz")
        x = require_nonnegative(self.standstill, "safe_stop.standstill")
        if x and VEL.encode_checked(x, "safe_stop.standstill") == 0:
            raise InputError("safe_stop.standstill", f"{x!r} rad/s is below half the node's "
                             f"velocity LSB ({VEL.resolution:.3g} rad/s): 0 turns the rule off")
        require_nonnegative(self.standstill_s, "safe_stop.standstill_s")


def triple_pole_gains(inertia, hz: float) -> dict:
    """PID gains placing a triple pole at ``−2π·hz`` for the inertia ``inertia`` (kg·m², a
    float or an array): ``kp`` N·m/rad, ``ki`` N·m/(rad·s), ``kd`` N·m·s/rad."""
    w = 2 * math.pi * hz
    return {"kp": 3 * inertia * w * w, "ki": inertia * w**3, "kd": 3 * inertia * w}


def hold_gains(params: SafeStopParams, inertia) -> dict:
    """The hold loop's PID gains (SI, :func:`triple_pole_gains` at ``params.hold_hz``) for a
    joint of nominal inertia ``inertia`` (kg·m²)."""
    return triple_pole_gains(inertia, params.hold_hz)


def safe_stop_config(params: SafeStopParams, clock_hz: float = float(CLOCK_HZ),
                     tick_cycles: int = 50) -> dict:
    """The CONFIG words ``{Config: int}`` of ``params``: STOP_CYCLES and BRAKE_CYCLES (the
    durations rounded to whole cycles of ``clock_hz``) and, with the standstill rule on,
    STANDSTILL (the threshold as a VEL word, rounded) and STANDSTILL_TICKS (``standstill_s``
    in control ticks of ``tick_cycles``, rounded, at least 1); off, those two keep their
    reset value 0 and are not sent (the uploads stay those of the fixed timer, byte for
    byte). ``InputError`` on ``safe_stop.standstill_s`` when the ticks exceed the 16-bit
    register."""
    words = {Config.STOP_CYCLES: round(params.stop_s * clock_hz),
             Config.BRAKE_CYCLES: round(params.brake_s * clock_hz)}
    if params.standstill == 0:
        return words
    ticks = max(1, round(params.standstill_s * clock_hz / tick_cycles))
    if ticks >= 1 << 16:
        raise InputError("safe_stop.standstill_s", f"{params.standstill_s!r} s is {ticks} "
                         f"ticks of {tick_cycles} cycles, above the node's 16-bit "
                         f"STANDSTILL_TICKS register (65,535)")
    return words | {Config.STANDSTILL: VEL.encode(params.standstill),
                    Config.STANDSTILL_TICKS: ticks}
