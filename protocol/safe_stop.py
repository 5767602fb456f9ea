"""The node's safe stop on loss of the master: its parameters and their register words.

# Ref: IEC 61800-5-2:2016 §4.2.2 (safety sub-functions of power drive systems): STO (safe
# torque off), SS1 (safe stop 1: stop, then STO; SS1-r / SS1-t: at standstill, or after a
# time), SS2 (safe stop 2: stop, then monitored standstill).

When a node's watchdog trips (no valid packet for TIMEOUT cycles while armed) the node does
not drop its torque at once, which lets an arm fall under gravity; it runs an SS1 sequence
whose brake waits for monitored standstill, with SS1-t's time limit as a fallback
(docs/node.md "Safe stop"):

1. **Stop** (SS1's controlled stop, by the node's own loop): the joint engine runs its PID
   program at every control tick on node-local references — zero velocity and acceleration,
   no feed-forward, and as position each tick's own encoder count, so only the damping
   ``k_d (0 − q̇)`` acts: the joint decelerates, at most at the torque limit — until a tick
   finds the velocity word within ±STANDSTILL (the joint at rest). With STOP_TRAIL > 0 the
   position is not the count itself but trails it by at most STOP_TRAIL counts (each tick
   ``q_d0 ← clamp(q_d0, count − E, count + E)``): a joint that gravity drives builds a position
   error of up to E, whose P term and integral carry the load, so it comes to rest.
2. **Hold** (SS2's standstill): from that tick the position reference is frozen at that
   tick's count and the PID (``kp, ki, kd`` of the JOINT bank: hold gains) holds the joint
   where it came to rest — not where it was at the trip, which a torque-limited joint
   overshoots and a stiff hold pulled it back through (joint 1 of the mrm3: a growing limit
   cycle, never a standstill).
3. **Brake**: once the velocity word has been within ±STANDSTILL at STANDSTILL_TICKS
   consecutive ticks, at the latest STOP_CYCLES after the trip (status STOP_LIMIT then, and
   the reference frozen there), the node asserts its ``brake`` output and keeps holding for
   BRAKE_CYCLES (the brake's engage time plus a margin).
4. **STO**: then the torque ramps to zero by RAMP per control tick; the brake stays engaged.

With STANDSTILL = 0 (the rule off) the reference is the first hold tick's count and the brake
comes at STOP_CYCLES: the fixed timer of the first version. The gains are the master's
(:func:`mrm_cosim.master.uploads.hold_gains`); this module holds the parameters and their
register words only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mrm_cosim.errors import InputError, require_nonnegative, require_positive
from mrm_cosim.units import CLOCK_HZ

from .fixed import VEL
from .regs import Config

__all__ = ["SafeStopParams", "SAFE_STOP_CYCLES_MAX", "STOP_TRAIL_MAX_MRAD", "safe_stop_config",
           "stop_trail_counts"]

#: Largest STOP_CYCLES / BRAKE_CYCLES value: the registers are 24 bits, unsigned (0.336 s at
#: 50 MHz; 32 bits cost the XC2V1000 LUTs it did not have, docs/node.md "Resources"); the node
#: ignores a CONFIG write above it.
SAFE_STOP_CYCLES_MAX = (1 << 24) - 1
#: Largest ``stop_trail`` (mrad): a bound on the input, far above any useful trail (a trail is
#: a pull-back after rest); the STOP_TRAIL register (16 bits, counts) holds it for encoders up
#: to 2^16 / 0.05 counts per radian.
STOP_TRAIL_MAX_MRAD = 50.0


@dataclass(frozen=True)
class SafeStopParams:
    """The safe stop's physical parameters (SI units).

    Attributes
    ----------
    stop_s : float, s
        The time limit of the stop and hold before the brake is engaged (STOP_CYCLES): with
        the standstill rule on the brake engages at standstill, at the latest this long after
        the trip (SS1-t as a fallback); off (``standstill`` = 0), exactly this long after the
        trip. Assumption: 0.2 s, about 2.5 times the 83 ms joint 1 of the mrm3 takes from
        the quintic's peak speed to its brake at standstill (docs/faults.md "Safe stop in
        the closed loop").
    brake_s : float, s
        The brake's engage time plus a margin, during which the node still holds
        (BRAKE_CYCLES). Assumption: 50 ms (spring-applied holding brakes of this size engage
        in 10–40 ms; the plant's brake model states its own).
    hold_hz : float, Hz
        Triple pole of the hold loop for the joints whose node does not run its PID (VDC and
        torque modes): the PID words ``kp, ki, kd`` take the master's hold gains for the
        joint's nominal inertia. A node in PID mode holds with its tracking gains. 15 Hz is
        the node PID's default bandwidth (``Gains.pid_fpga_hz``), stable on the compliant
        plant.
    standstill : float, rad/s
        The standstill threshold (STANDSTILL, a VEL word): the stop ends (the reference
        freezes) at the first tick within ±this, the brake after ``standstill_s`` of
        consecutive such ticks; 0 turns the rule off (the fixed timer). Assumption: 10 mrad/s:
        the 15 Hz hold at rest dithers by one encoder count, which the M/T estimate reports
        as a few mrad/s, so a 2 mrad/s band was never held for 10 ms by joint 1 of the mrm3.
    standstill_s : float, s
        How long the velocity must stay within the band (STANDSTILL_TICKS, in control
        ticks). Assumption: 10 ms.
    stop_trail : float, **mrad** (the one field not in SI units: ``[safety] stop_trail``)
        How far the hold's target may trail the joint while it stops (STOP_TRAIL, converted
        per joint with its encoder's counts per radian, :func:`stop_trail_counts`); 0: the
        target is each tick's count (only damping acts while stopping). At most
        :data:`STOP_TRAIL_MAX_MRAD`.
    """

    stop_s: float = 0.2
    brake_s: float = 0.05
    hold_hz: float = 15.0
    standstill: float = 0.01
    standstill_s: float = 0.01
    stop_trail: float = 1.0

    def __post_init__(self):
        for name in ("stop_s", "brake_s"):
            x = require_nonnegative(getattr(self, name), f"safe_stop.{name}")
            if x * CLOCK_HZ > SAFE_STOP_CYCLES_MAX:
                raise InputError(f"safe_stop.{name}", f"{x!r} s exceeds the node's 24-bit "
                                 f"cycle register ({SAFE_STOP_CYCLES_MAX / CLOCK_HZ:.4g} s)")
        require_positive(self.hold_hz, "safe_stop.hold_hz")
        x = require_nonnegative(self.standstill, "safe_stop.standstill")
        if x and VEL.encode_checked(x, "safe_stop.standstill") == 0:
            raise InputError("safe_stop.standstill", f"{x!r} rad/s is below half the node's "
                             f"velocity LSB ({VEL.resolution:.3g} rad/s): 0 turns the rule off")
        require_nonnegative(self.standstill_s, "safe_stop.standstill_s")
        x = require_nonnegative(self.stop_trail, "safe_stop.stop_trail")
        if x > STOP_TRAIL_MAX_MRAD:
            raise InputError("safe_stop.stop_trail", f"{x!r} mrad exceeds "
                             f"{STOP_TRAIL_MAX_MRAD:g} mrad (the hold's target may trail the "
                             f"joint by that at most)")


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


def stop_trail_counts(params: SafeStopParams, counts_per_rev: int) -> int:
    """CONFIG STOP_TRAIL for a joint of ``counts_per_rev`` encoder counts per revolution:
    ``params.stop_trail`` (mrad) in counts, rounded. ``InputError`` on
    ``safe_stop.stop_trail`` when it exceeds the 16-bit register."""
    counts = round(params.stop_trail * 1e-3 * counts_per_rev / (2 * math.pi))
    if counts >= 1 << 16:
        raise InputError("safe_stop.stop_trail", f"{params.stop_trail!r} mrad is {counts} "
                         f"counts of this encoder, above the node's 16-bit STOP_TRAIL "
                         f"register (65,535)")
    return counts
