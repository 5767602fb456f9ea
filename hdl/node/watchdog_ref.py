"""Bit-exact, cycle-level reference of the torque output stage: limits, arming, watchdog and
its safe stop.

# Ref: IEC 61800-5-2:2016 §4.2.2: SS1 (here: the brake at monitored standstill, SS1-t's time
# limit as a fallback), SS2, STO (docs/node.md "Safe stop").

Per cycle, with the inputs of that cycle (all pulses one cycle wide), in this order:

1. ``arm`` arms the joint and clears a trip (silence counter to 0); ``disarm`` disarms it
   (``disarm`` wins when both come together).
2. ``packet`` (a valid packet for this node) resets the silence counter; otherwise it counts
   up, saturating at 2^32 − 1.
3. While armed and not tripped, the watchdog trips when the silence counter reaches
   ``timeout`` (two periods by default: no Comm B or D for 2 ms); ``since``, the cycles since
   the trip, is 0 in the first tripped cycle and counts up (saturating at 2^32 − 1) while
   tripped; the trip clears ``braked`` and ``run``.
4. The safe stop's brake, while tripped and not ``braked``: at the time limit (``since ≥
   stop_cycles``, "at_limit") the brake is on from this cycle, ``braked`` is set and
   ``since`` restarts at 1 (cycles since the brake's first cycle); otherwise at a ``tick``
   whose ``velocity`` is within ±``standstill`` (``standstill`` ≠ 0) ``run`` counts the
   consecutive such ticks (any other tick clears it), and the tick that makes it
   ``standstill_ticks`` (0 counts as 1) sets ``braked`` with ``since`` = 0: the brake from
   the next cycle. ``standstill`` = 0: only the time limit, the fixed timer (SS1-t).
5. The outputs, from the registers before the cycle: ``holding`` (armed, tripped, and before
   ``braked`` not at a limit with ``brake_cycles`` = 0, after it ``since < brake_cycles``:
   the joint engine holds the joint, SS1/SS2's stop and standstill), ``brake`` (tripped and
   ``braked``, at the limit or disarmed) and ``limit`` (tripped, braked at the time limit,
   ``standstill`` ≠ 0); ``rest`` (combinational with this cycle's ``velocity``: the
   standstill rule off, the velocity within ±``standstill``, or the brake engaged or at the
   limit): the control ticks freeze the hold's target at a hold tick that sees it, and until
   then give it the tick's count (the joint stops, then is held where it came to rest).
6. Torque: disarmed → 0; tripped and not holding (STO) → on each ``tick`` the torque moves
   ``ramp`` towards zero (no torque, reached smoothly); armed otherwise (normal, or holding)
   → on ``cmd_valid`` the command clamped to ``[tau_min, tau_max]``.

With ``stop_cycles = brake_cycles = 0`` (the reset values) a trip goes to STO at once, the
stage's behaviour before the safe stop.

Register values after :meth:`WatchdogModel.cycle` are those visible in the next cycle; the
properties :attr:`holding`, :attr:`brake`, :attr:`limit` and :attr:`safe` are the outputs in
the next cycle with the ``stop_cycles`` / ``brake_cycles`` / ``standstill`` of the last call.
"""

from __future__ import annotations

__all__ = ["SILENCE_MAX", "SINCE_MAX", "WatchdogModel"]

SILENCE_MAX = (1 << 32) - 1
#: ``since`` saturates here: 24 bits, the width of the STOP_CYCLES / BRAKE_CYCLES registers.
SINCE_MAX = (1 << 24) - 1


class WatchdogModel:
    """State: ``armed``, ``tripped``, ``silence`` and ``since`` (cycles), ``braked``,
    ``by_limit``, ``run`` (ticks), ``torque`` (FORCE word)."""

    def __init__(self):
        self.armed = False
        self.tripped = False
        self.silence = 0
        self.since = 0
        self.torque = 0
        self.stop_cycles = 0
        self.brake_cycles = 0
        self.standstill = 0
        self.braked = False
        self.by_limit = False
        self.run = 0

    def cycle(self, *, packet=False, tick=False, cmd_valid=False, cmd=0, arm=False,
              disarm=False, timeout=100_000, ramp=0, tau_min=0, tau_max=0, stop_cycles=0,
              brake_cycles=0, velocity=0, standstill=0, standstill_ticks=0) -> None:
        self.stop_cycles, self.brake_cycles = stop_cycles, brake_cycles
        self.standstill = standstill
        at_limit = self._at_limit
        still = standstill != 0 and abs(velocity) <= standstill
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
            self.braked = self.by_limit = False
            self.run = 0
        elif tripped:
            if at_limit:
                self.braked = self.by_limit = True
                self.since = 1
            elif not self.braked and tick and still and self.run + 1 >= standstill_ticks:
                self.braked = True
                self.since = 0
            else:
                self.since = min(self.since + 1, SINCE_MAX)
                if not self.braked and tick:
                    self.run = self.run + 1 if still else 0
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
    def _at_limit(self) -> bool:
        return not self.braked and self.since >= self.stop_cycles

    @property
    def holding(self) -> bool:
        """Armed, tripped and within the hold: the joint engine holds the joint."""
        if not (self.armed and self.tripped):
            return False
        if self.braked:
            return self.since < self.brake_cycles
        return not self._at_limit or self.brake_cycles != 0

    @property
    def brake(self) -> bool:
        """Tripped and the brake engaged (standstill or the time limit), or tripped and
        disarmed."""
        return self.tripped and (self.braked or self._at_limit or not self.armed)

    @property
    def limit(self) -> bool:
        """Tripped, the brake engaged at the time limit, the standstill rule on."""
        return (self.tripped and (self.by_limit or self._at_limit)
                and self.standstill != 0)

    def rest(self, velocity: int) -> bool:
        """The ``rest`` output in the next cycle with the velocity word ``velocity`` there:
        the hold's target is frozen at a hold tick that finds it (the standstill rule off,
        ``velocity`` within ±``standstill``, or the brake engaged or at the time limit);
        until then it follows the count."""
        thr = self.standstill
        return thr == 0 or abs(velocity) <= thr or self.braked or self._at_limit

    @property
    def safe(self) -> bool:
        """Tripped, past the hold (STO) and the torque is zero."""
        return self.tripped and not self.holding and self.torque == 0
