"""Bit-exact, cycle-level reference of the quadrature encoder interface and velocity estimator.

Lines (models/encoder.py): state ``c mod 4`` → ``(A, B) = (0,0), (1,0), (1,1), (0,1)`` (Gray
code, A leads B when the count increases). The count starts at 0 after reset (an incremental
encoder; the master presets it after homing). Per cycle, in this order:

1. Two-flip-flop synchronizer per line (the lines are asynchronous to the FPGA clock); in the
   third cycle after reset the filter takes the synchronized lines as they are, uncounted.
2. Glitch filter per line: the filtered level takes the synchronized one after they have
   differed for ``filter_cycles`` consecutive cycles.
3. ×4 decoder on the filtered pair: a step of ±1 in the Gray sequence moves the count; both
   lines changing at once is an illegal transition — counted (saturating at 0xFFFF), no move.
4. Ages (cycles since the last edge, and since the reference edge) count up, saturating at
   :data:`AGE_MAX`; an edge sets the edge age to 0.
5. On a ``sample`` strobe (not in the cycle right after a taken one), with
   ``dc = count − c_ref`` (saturated to 10 bits, −512..:data:`DC_MAX`) and
   ``window = age_ref − age_edge`` (reference edge to last edge), all as in the strobe's cycle:

   * MEASURE if ``dc ≠ 0`` and ``window ≥ min_window``: ``v = dc / window``, the M/T method
     (counts over the exact time between edges), and the last edge becomes the reference
     (at the end of the next cycle, unless a preset comes in the strobe's cycle);
   * STOP if ``age_edge ≥ stop_cycles``: ``v = 0``;
   * BOUND otherwise: no new edge pair yet, but the next edge has not come either, so
     ``|v| ≤ (|dc| + 1) / age_ref``; ``|v|`` is clipped to that (sign kept). This is what
     makes the estimate decay to zero when the joint stops, instead of holding its last value.

   The division is a reciprocal: normalize ``den`` to ``m ∈ [1, 2)`` (17 bits), 256-entry
   table ``y0 ≈ 1/m``, one Newton–Raphson step ``y1 = y0 (2 − m y0)`` (relative error
   < 2.5e-5, mostly from truncating ``den`` to 17 bits), then ``v = num · y1 · K_v`` scaled
   by a shift, ``K_v = f_clk · 2π / CPR`` (rad/s per count/cycle) as a Q8 constant. The
   result, a VEL word, is visible :data:`VEL_LATENCY` cycles after the strobe's cycle.

Model attributes after :meth:`EncoderModel.cycle` for cycle ``k`` are the register values
visible during cycle ``k + 1``.
"""

from __future__ import annotations

from mrm_cosim.protocol.encoder import AGE_MAX, DC_MAX, RECIP_TABLE, EncoderParams
from mrm_cosim.protocol.fixed import VEL, round_shift, saturate

__all__ = ["VEL_LATENCY", "reciprocal", "velocity_word", "EncoderModel"]

#: Cycles from a ``sample`` strobe to the new velocity word (the gateware's pipeline).
VEL_LATENCY = 13


def reciprocal(den: int) -> tuple[int, int]:
    """``(y1, p)`` with ``1/den ≈ y1 · 2^(−17−p)``, ``den`` in 1..AGE_MAX.

    Every product fits one 18×18 multiplier: ``m`` (17 bits, the normalized ``den``) times the
    table word ``y0`` (17 bits); the Newton–Raphson correction ``y0 · (1 − m y0)`` uses the small
    signed residue ``d`` (≈ ±300).
    """
    den = max(1, min(den, AGE_MAX))
    p = den.bit_length() - 1
    m17 = (den << (25 - p)) >> 9
    y0 = RECIP_TABLE[(m17 >> 8) & 0xFF]
    d = (1 << 17) - ((m17 * y0) >> 16)
    y1 = y0 + ((y0 * d) >> 17)
    return y1, p


def velocity_word(num: int, den: int, kv: int) -> int:
    """VEL word of ``num / den`` counts per cycle (``kv`` from :attr:`EncoderParams.kv`)."""
    y1, p = reciprocal(den)
    return saturate(round_shift((num * y1) * kv, p + 6))   # p + 6 ≥ 1: see encoder.py S6


_PHASE = {(0, 0): 0, (1, 0): 1, (1, 1): 2, (0, 1): 3}


class EncoderModel:
    """Cycle-level model; call :meth:`cycle` once per clock with the raw line levels.

    Attributes
    ----------
    count : int
        Joint count (32-bit signed wrap).
    velocity : int
        VEL word of the estimate.
    errors : int
        Illegal transitions seen (saturating 16-bit).
    """

    def __init__(self, params: EncoderParams | None = None):
        self.p = params or EncoderParams()
        self.s1 = [0, 0]
        self.s2 = [0, 0]
        self.filt = [0, 0]
        self.fcnt = [0, 0]
        self.primed = False
        self.count = 0
        self.errors = 0
        self.age_edge = 0
        self.age_ref = 0
        self.c_ref = 0
        self.velocity = 0
        self._pipe: list[tuple[int, str, int, int]] = []   # (due cycle, case, num, den)
        self._pending_ref: tuple[int, int, int] | None = None
        self._last_taken = -2
        self.now = 0

    def cycle(self, a: int, b: int, sample: bool = False, preset: int | None = None) -> None:
        """Advance one clock with raw levels ``a, b`` during it and optional strobes.

        ``preset`` (an integer) loads the count and the reference count in this cycle
        (the master's homing: an incremental encoder counts from 0 at power-up).
        """
        p = self.p
        # Velocity pipeline results due now (computed from state latched earlier).
        while self._pipe and self._pipe[0][0] == self.now:
            _, case, num, den = self._pipe.pop(0)
            if case == "stop":
                self.velocity = 0
            else:
                v = velocity_word(num, den, p.kv)
                if case == "measure":
                    self.velocity = v
                elif abs(self.velocity) > v:
                    self.velocity = v if self.velocity > 0 else -v
        # Sample strobe: decide on the current state (a strobe in the cycle right after a
        # taken one is ignored: the decision takes two cycles).
        if sample and self._last_taken != self.now - 1:
            self._last_taken = self.now
            dc = max(-DC_MAX - 1, min(DC_MAX, self.count - self.c_ref))
            window = self.age_ref - self.age_edge
            if dc != 0 and window >= p.min_window:
                self._pipe.append((self.now + VEL_LATENCY - 1, "measure", dc, window))
                # The reference moves one cycle later, unless a preset comes in this cycle.
                if preset is None:
                    self._pending_ref = (self.now + 1, self.count,
                                         min(self.age_edge + 2, AGE_MAX))
                new_ref = None
            elif self.age_edge >= p.stop_cycles:
                self._pipe.append((self.now + VEL_LATENCY - 1, "stop", 0, 1))
                new_ref = None
            else:
                self._pipe.append((self.now + VEL_LATENCY - 1, "bound", abs(dc) + 1,
                                   self.age_ref))
                new_ref = None
        else:
            new_ref = None
        # Filter and decoder (on the synchronized levels of the previous cycles).
        old = tuple(self.filt)
        for k in range(2):
            if self.now < 2:          # the synchronizer holds no sample yet
                continue
            if not self.primed:       # first sample: take the lines as they are, no count
                self.filt[k] = self.s2[k]
                continue
            if self.s2[k] != self.filt[k]:
                if self.fcnt[k] == p.filter_cycles - 1:
                    self.filt[k] = self.s2[k]
                    self.fcnt[k] = 0
                else:
                    self.fcnt[k] += 1
            else:
                self.fcnt[k] = 0
        new = tuple(self.filt)
        edge = False
        if self.now >= 2 and not self.primed:
            self.primed = True
        elif new != old:
            d = (_PHASE[new] - _PHASE[old]) % 4
            if d == 2:
                self.errors = min(self.errors + 1, 0xFFFF)
            else:
                step = 1 if d == 1 else -1
                self.count = ((self.count + step + 2**31) % 2**32) - 2**31
                edge = True
        self.age_edge = 0 if edge else min(self.age_edge + 1, AGE_MAX)
        self.age_ref = min(self.age_ref + 1, AGE_MAX)
        if new_ref is not None:
            self.c_ref, self.age_ref = new_ref
        if self._pending_ref is not None and self._pending_ref[0] == self.now:
            _, self.c_ref, self.age_ref = self._pending_ref
            self._pending_ref = None
        if preset is not None:
            self.count = self.c_ref = ((preset + 2**31) % 2**32) - 2**31
        self.s2 = list(self.s1)
        self.s1 = [a, b]
        self.now += 1

    @property
    def velocity_rad_s(self) -> float:
        return VEL.decode(self.velocity)
