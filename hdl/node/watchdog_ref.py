"""Bit-exact, cycle-level reference of the torque output stage: limits, arming, watchdog.

Per cycle, with the inputs of that cycle (all pulses one cycle wide), in this order:

1. ``arm`` arms the joint and clears a trip (silence counter to 0); ``disarm`` disarms it
   (``disarm`` wins when both come together).
2. ``packet`` (a valid packet for this node) resets the silence counter; otherwise it counts
   up, saturating at 2^32 − 1.
3. While armed and not tripped, the watchdog trips when the silence counter reaches
   ``timeout`` (two periods by default: no Comm B or D for 2 ms).
4. Torque: disarmed → 0; tripped → on each ``tick`` the torque moves ``ramp`` towards zero
   (the joint's safe state: no torque, reached smoothly); armed → on ``cmd_valid`` the
   command clamped to ``[tau_min, tau_max]``.

Register values after :meth:`WatchdogModel.cycle` are those visible in the next cycle.
"""

from __future__ import annotations

__all__ = ["SILENCE_MAX", "WatchdogModel"]

SILENCE_MAX = (1 << 32) - 1


class WatchdogModel:
    """State: ``armed``, ``tripped``, ``silence`` (cycles), ``torque`` (FORCE word)."""

    def __init__(self):
        self.armed = False
        self.tripped = False
        self.silence = 0
        self.torque = 0

    def cycle(self, *, packet=False, tick=False, cmd_valid=False, cmd=0, arm=False,
              disarm=False, timeout=100_000, ramp=0, tau_min=0, tau_max=0) -> None:
        armed, tripped, silence, torque = self.armed, self.tripped, self.silence, self.torque
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
        if not armed:
            self.torque = 0
        elif tripped:
            if tick:
                if abs(torque) <= ramp:
                    self.torque = 0
                else:
                    self.torque = torque - ramp if torque > 0 else torque + ramp
        elif cmd_valid:
            self.torque = min(max(cmd, tau_min), tau_max)

    @property
    def safe(self) -> bool:
        """Tripped and the torque is zero."""
        return self.tripped and self.torque == 0
