"""The node's period timer disciplined by the time-code: CONFIG TC_DISCIPLINE's word and the
loop's constants (docs/node.md "Timing", "Discipline"; issue 21 item 3).

A digital PLL on the period, run once per time-code that arrives inside the sync window,
which the loop makes two-sided: ``SYNC_WINDOW`` cycles after a boundary or before the next.
Its input is the signed phase error ``e = phase − target`` (the timer's phase in the strobe's
cycle minus the phase the time-code should arrive at: the link latency from the master, so
that the node's boundary falls on the master's period start); for a time-code before the
boundary ``e = −rem − target``, ``rem = PERIOD + adj − phase`` the cycles to the boundary.
Its outputs set the length of the period the time-code arrived in, ``PERIOD + adj`` cycles,
``adj = r + p``, from :data:`LATENCY` cycles after the time-code (the step is computed
serially; nothing needs it sooner, a time-code comes once a period):

* **phase** ``p = e >> kp``: a share of the error, once, bounded by the error's saturation
  (``|e| ≤ 128``: ``|p| ≤ 128 >> kp`` cycles);
* **rate** ``r``: the integer part of a fractional accumulator. The rate estimate ``f``
  (cycles per period, :data:`FRAC` fraction bits) integrates the error,
  ``f ← sat(f + ((e · 2^FRAC) >> ki))``, but only while ``e`` is not saturated
  (conditional integration: an error the step cannot take up in one period, a node far off
  the master's grid, would wind the rate up by tens of cycles per period, and the node
  would overshoot out of the window); each time-code adds ``f`` to the fraction ``a``
  (``FRAC`` bits) and the carry out is ``r``: ``s = a + f``, ``r = s >> FRAC``, ``a = s mod
  2^FRAC``. A node whose oscillator is δ fast needs ``PERIOD·δ`` more cycles per period (5 at
  100 ppm); the accumulator gives it as a mix of ⌊·⌋ and ⌈·⌉ periods.

``e`` is first saturated to ``[−2^(E_BITS−1), 2^(E_BITS−1))`` = ``[−128, 128)``, ``f`` to
:data:`RATE_BITS` signed bits (± 128 cycles per period: ± 2,560 ppm at 50,000 cycles). Shifts
are arithmetic (floor). Writing the register
clears ``f``, ``a`` and ``adj``; the value 0 (the default) is today's free-running timer. A
time-code outside the window still re-synchronises the timer (acquisition: the phase then
restarts at ``target + 1``, so the arrival cycle counts as phase ``target``) and leaves the
loop as it is. While the loop is on, no control tick comes within TICK cycles before a
boundary: the period's last tick interval may then be up to TICK + |adj| cycles, never
shorter than TICK, so the joint engine is idle at the boundary whatever ``adj`` is.

The word (u32; a value with bits above bit 18 set is ignored)::

    bits  0–11  target   phase the time-code should arrive at (cycles)
    bits 12–14  kp       phase gain 2^−kp
    bits 15–17  ki       rate gain 2^−ki
    bit  18     enable
"""

from __future__ import annotations

from dataclasses import dataclass

from mrm_cosim.errors import InputError

__all__ = ["FRAC", "RATE_BITS", "E_BITS", "STEP_MAX", "TARGET_BITS", "GAIN_BITS", "WORD_BITS",
           "LATENCY", "Discipline", "loop_step", "period_length", "arrival"]

#: fraction bits of the rate estimate ``f`` and of the accumulator ``a``
FRAC = 8
#: signed width of ``f`` (with its FRAC fraction bits): ± 128 cycles per period
RATE_BITS = 16
#: signed width the phase error is saturated to
E_BITS = 8
#: largest phase step of one period (cycles; kp = 0): the saturated error
STEP_MAX = 1 << (E_BITS - 1)
TARGET_BITS = 12
GAIN_BITS = 3
WORD_BITS = TARGET_BITS + 2 * GAIN_BITS + 1
#: cycles from a time-code the loop takes to the first cycle of its new ``adj`` (and ``f``,
#: ``a``): the gateware computes the step serially, the error in the time-code's cycle, then
#: one right shift of each gain's operand a cycle (2^GAIN_BITS − 1 cycles, whatever the
#: gains), then the sums. A time-code in the cycles between is not taken by the loop (it is
#: still a resync outside the window); a write of the register clears the step under way.
LATENCY = (1 << GAIN_BITS) + 1


@dataclass(frozen=True)
class Discipline:
    """The fields of CONFIG TC_DISCIPLINE (module docstring).

    Parameters
    ----------
    target : int, cycles
        Phase at which the time-code should arrive: the node's link latency from the master.
    kp, ki : int
        Phase and rate gains as right shifts (2^−kp, 2^−ki).
    enable : bool
    """

    target: int = 0
    kp: int = 1
    ki: int = 4
    enable: bool = True

    def __post_init__(self):
        for name, bits in (("target", TARGET_BITS), ("kp", GAIN_BITS), ("ki", GAIN_BITS)):
            v = getattr(self, name)
            if not (isinstance(v, int) and 0 <= v < (1 << bits)):
                raise InputError(f"discipline.{name}",
                                 f"must be an integer in [0, {(1 << bits) - 1}], not {v!r}")

    @property
    def word(self) -> int:
        return (self.target | self.kp << TARGET_BITS | self.ki << (TARGET_BITS + GAIN_BITS)
                | int(bool(self.enable)) << (TARGET_BITS + 2 * GAIN_BITS))

    @classmethod
    def from_word(cls, word: int) -> Discipline:
        return cls(target=word & ((1 << TARGET_BITS) - 1),
                   kp=(word >> TARGET_BITS) & ((1 << GAIN_BITS) - 1),
                   ki=(word >> (TARGET_BITS + GAIN_BITS)) & ((1 << GAIN_BITS) - 1),
                   enable=bool(word >> (TARGET_BITS + 2 * GAIN_BITS) & 1))


def _clamp(x: int, lo: int, hi: int) -> int:
    return lo if x < lo else hi if x > hi else x


def loop_step(word: int, phase: int, f: int, a: int) -> tuple[int, int, int]:
    """One update of the loop for a time-code at ``phase`` (inside the window, the loop on;
    before a boundary: minus the cycles to it, :func:`arrival`).

    Returns
    -------
    f, a, adj : int
        The new rate estimate (FRAC fraction bits), fraction, and the adjustment of the
        current period's length (cycles).
    """
    d = Discipline.from_word(word)
    e_max = 1 << (E_BITS - 1)
    raw = phase - d.target
    e = _clamp(raw, -e_max, e_max - 1)
    if e == raw:                                # not saturated: integrate
        f_max = 1 << (RATE_BITS - 1)
        f = _clamp(f + ((e << FRAC) >> d.ki), -f_max, f_max - 1)
    s = a + f
    return f, s & ((1 << FRAC) - 1), (s >> FRAC) + (e >> d.kp)


def period_length(period: int, adj: int) -> int:
    """Cycles from a boundary to the next: ``PERIOD + adj``, at least 2 (the timer ends a
    period when the cycles to its end, ``PERIOD + adj − phase``, are ≤ 1, phase 1 at the
    earliest)."""
    return max(period + adj, 2)


def arrival(word: int, phase: int, window: int, length: int) -> tuple[bool, int]:
    """A time-code at ``phase`` of a period of ``length = PERIOD + adj`` cycles: ``(resync,
    loop_phase)``. ``resync``: outside the window (with the loop on, outside both sides of
    it); ``loop_phase``: the phase the loop takes, ``phase − length`` (minus the cycles to the
    boundary) for an early one."""
    if phase < window:
        return False, phase
    if Discipline.from_word(word).enable and length - phase <= window:
        return False, phase - length
    return True, phase
