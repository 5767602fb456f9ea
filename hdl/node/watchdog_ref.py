"""Bit-exact, cycle-level reference of the torque output stage: limits, arming, watchdog and
its safe stop.

# Ref: IEC 61800-5-2:2016 §4.2.2: SS1-t, SS2, STO (docs/node.md "Safe stop").

Per cycle, with the inputs of that cycle (all pulses one cycle wide), in this order:

1. ``arm`` arms the joint and clears a trip (silence counter to 0); ``disarm`` disarms it
   (``disarm`` wins when both come together).
2. ``packet`` (a valid packet for this node) resets the silence counter; otherwise it counts
   up, saturating at 2^32 − 1.
3. While armed and not tripped, the watchdog trips when the silence counter reaches
   ``timeout`` (two periods by default: no Comm B or D for 2 ms); ``since``, the cycles since
   the trip, is 0 in the first tripped cycle and counts up (saturating at 2^32 − 1) while
   tripped.
4. The safe stop, from the registers before the cycle: ``holding`` (armed, tripped, ``since <
   stop_cycles + brake_cycles``: the joint engine holds the joint, SS1/SS2's stop and
   standstill) and ``brake`` (tripped and ``since ≥ stop_cycles`` or disarmed).
5. Torque: disarmed → 0; tripped and not holding (STO) → on each ``tick`` the torque moves
   ``ramp`` towards zero (no torque, reached smoothly); armed otherwise (normal, or holding)
   → on ``cmd_valid`` the command clamped to ``[tau_min, tau_max]``.

With ``stop_cycles = brake_cycles = 0`` (the reset values) a trip goes to STO at once, the
stage's behaviour before the safe stop.

Register values after :meth:`WatchdogModel.cycle` are those visible in the next cycle; the
properties :attr:`holding`, :attr:`brake` and :attr:`safe` are the outputs in the next cycle
with the ``stop_cycles`` / ``brake_cycles`` of the last call (the registers feeding them).
"""

from __future__ import annotations

__all__ = ["SILENCE_MAX", "WatchdogModel"]

SILENCE_MAX = (1 << 32) - 1


class WatchdogModel:
    """State: ``armed``, ``tripped``, ``silence`` and ``since`` (cycles), ``torque`` (FORCE
    word)."""

    def __init__(self):
        self.armed = False
        self.tripped = False
        self.silence = 0
        self.since = 0
        self.torque = 0
        self.stop_cycles = 0
        self.brake_cycles = 0

    def cycle(self, *, packet=False, tick=False, cmd_valid=False, cmd=0, arm=False,
              disarm=False, timeout=100_000, ramp=0, tau_min=0, tau_max=0, stop_cycles=0,
              brake_cycles=0) -> None:
        self.stop_cycles, self.brake_cycles = stop_cycles, brake_cycles
        armed, tripped, silence, torque = self.armed, self.tripped, self.silence, self.torque
        holding = self.holding
        if disarm:
            self.armed = False
        elif arm:
            self.armed = True
            self.tripped = False
        if arm or packet:
            self.silence = 0
        else:
            self.silence = min(silence + 1, SILENCE_MAX)
        if armed and not tripped and not arm and not disarm and silence >= timeout:
            self.tripped = True
            self.since = 0
        elif tripped:
            self.since = min(self.since + 1, SILENCE_MAX)
        if not armed:
            self.torque = 0
        elif tripped and not holding:
            if tick:
                if abs(torque) <= ramp:
                    self.torque = 0
                else:
                    self.torque = torque - ramp if torque > 0 else torque + ramp
        elif cmd_valid:
            self.torque = min(max(cmd, tau_min), tau_max)

    @property
    def holding(self) -> bool:
        """Armed, tripped and within the hold: the joint engine holds the joint."""
        return (self.armed and self.tripped
                and self.since < self.stop_cycles + self.brake_cycles)

    @property
    def brake(self) -> bool:
        """Tripped and ``stop_cycles`` into the trip, or tripped and disarmed."""
        return self.tripped and (self.since >= self.stop_cycles or not self.armed)

    @property
    def safe(self) -> bool:
        """Tripped, past the hold (STO) and the torque is zero."""
        return self.tripped and not self.holding and self.torque == 0
