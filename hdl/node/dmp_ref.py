"""Bit-exact reference of the joint-side DMP generator (:mod:`.dmp`), one call per step.

The recurrence, formats and register map are in :mod:`mrm_cosim.protocol.dmp`. A step's
computation (started by ``start`` for step 0, by each committing ``step`` for the next) does,
with ``rs(v, n) = floor(v/2^n + 1/2)`` (round half up, :func:`round_shift`) and ``sat_n`` the
signed ``n``-bit clamp:

1. Latch ``g`` and ``1/τ`` (``IT``) from their registers: a goal or τ write while running is
   one word, effective from this step on.
2. ``k = rs(DT · IT, 12)`` (K_LSB 2^-38); ``dφ = rs(k · PHASE_RATE, 14)`` (φ's LSB 2^-40).
3. Phase ``s = rs(E(φ), 6)`` (PHASE, 2^-22), ``E`` the exp unit below.
4. Per basis ``i < n``, first pass: ``t_i = rs((s − c_i) · R_i, 14)`` (2^-20) and
   ``u_i = t_i²`` (2^-40, octaves, exact) and their minimum ``u_min``; second pass (``t_i``,
   ``u_i`` recomputed): ``ψ_i = E(min(u_i − u_min, PHI_MAX))`` (2^-28),
   ``num = Σ ψ_i w_i`` (2^-39), ``den = Σ ψ_i`` (2^-28), exact. Scaling every ψ by
   ``2^(u_min)`` leaves ``f = Σψw/Σψ`` unchanged and keeps the nearest Gaussian at 1, so
   nothing underflows however far the phase is from the centres (past the last one, ``f``
   tends to its weight, as in float; a fixed ψ format would give 0/0).
5. Division: ``q = floor(|num| · 2^10 / den)``, ``f = ±((q + 1) >> 1)`` with the sign of
   ``num`` (rounded half away from zero, 2^-20); ``f = 0`` when n = 0.
6. Forcing: ``sf = rs(s · f, 22)`` (2^-20); ``F = rs(sf · A, 20)`` (counts, 2^-4) with
   ``A = g − x0`` (goal scaling) or the AMPLITUDE word.
7. ``e = rs((g << 12) − x, 8)`` (2^-8); ``v̇ = sat35(rs(e · AB, 12) − rs(v · α, 20) + F)``
   (counts, 2^-4).
8. Outputs (pending): ``a1 = sat35(rs(v̇ · IT, 20))``, ``a2 = sat35(rs(a1 · IT, 20))``
   (counts/s², 2^-4), ``q̈_d0 = sat24(rs(a2 · RADC, 26))`` (ACC);
   ``vt = sat35(rs(v · IT, 22))`` (counts/s, 2^-8), ``q̇_d0 = sat24(rs(vt · RADC, 25))`` (VEL);
   ``q_d0 = sat24(rs(x, 12))`` (POS).
9. State: ``v ← sat35(v + rs(k · v̇, 32))`` (2^-10), then ``x ← sat40(x + rs(k · v, 32))``
   (2^-16, with the new ``v``), ``φ ← clamp(φ + dφ, 0, PHI_MAX)``.

The exp unit ``E(φ) ≈ 2^(−φ)`` (φ unsigned, 2^-40; result 2^-28): ``n = φ >> 40``,
``j`` the next 8 bits, ``r`` the 24 below them; ``y = T[j] − rs((T[j] − T[j+1]) · r, 24)``
(linear interpolation in the table ``T[j] = round(2^30 · 2^(−j/256))``, error ≤ 9.2e-7
relative), ``E = ((y >> (n + 1)) + 1) >> 1`` = ``rs(y, n + 2)``, zero for ``n ≥ 31`` (the gateware
forms it as ``rs(y · 2^(30 − n), 32)`` on the multiplier: the same value).

Start: ``x = X0 << 12``, ``v = V0 << 6``, ``φ = 0``, then the computation of step 0.
A computation takes :func:`step_cycles` clock cycles (``278 + 90 n``) from the cycle after
its strobe: a strobe in cycle ``c`` has ``ready`` high from cycle ``c + 1 + cycles`` on.
"""

from __future__ import annotations

from mrm_cosim.protocol.dmp import (EXP_BITS, EXP_TABLE, FLAG_GOAL_SCALING, MAX_BASIS,
                                    N_SCALARS, PHI_FRAC, PHI_MAX, Reg, addr_width,
                                    check_max_basis)
from mrm_cosim.protocol.fixed import round_shift as rs
from mrm_cosim.protocol.fixed import saturate, wrap

__all__ = ["DmpGeneratorModel", "exp2neg", "step_cycles", "CYCLES_FIXED", "CYCLES_PER_BASIS"]

#: Cycles of a step's computation: CYCLES_FIXED + CYCLES_PER_BASIS · n_basis. The gateware's
#: microprogram has 49 micro-operations outside the basis loops and 18 in them; each takes five
#: cycles (read, operands, product, sum, write; four before the operand register of
#: 26 Nov, docs/node.md Clock), but the divider's takes 38 (read, operands, 34 quotient bits,
#: the rounding, write): 48·5 + 38 = 278 and 18·5 = 90 (it was 48·4 + 38 = 230, 18·4 = 72).
#: tests/test_node_dmp.py derives both from the microprogram and checks ``ready`` against them.
CYCLES_FIXED = 278
CYCLES_PER_BASIS = 90


def step_cycles(n_basis: int) -> int:
    """Clock cycles from a ``start`` or committing ``step`` strobe to ``ready``."""
    return CYCLES_FIXED + CYCLES_PER_BASIS * n_basis


def exp2neg(phi: int) -> int:
    """``2^(−φ)`` with 28 fraction bits of ``φ`` unsigned with 40 (see the module docstring)."""
    n = phi >> PHI_FRAC
    frac = phi & ((1 << PHI_FRAC) - 1)
    j = frac >> (PHI_FRAC - EXP_BITS)
    r = (frac >> (PHI_FRAC - EXP_BITS - 24)) & ((1 << 24) - 1)
    t0, t1 = EXP_TABLE[j], EXP_TABLE[j + 1]
    y = t0 - rs((t0 - t1) * r, 24)
    if n >= 31:
        return 0
    return ((y >> (n + 1)) + 1) >> 1


class DmpGeneratorModel:
    """The generator's registers, state and outputs; pure Python integers.

    Parameters
    ----------
    max_basis : int
        Build parameter: Gaussians the parameter memory holds.

    Attributes
    ----------
    qd0, vd0, ad0 : int
        Output words (POS, VEL, ACC), as the gateware's ports after the last commit.
    pending : tuple of int or None
        The precomputed next step's outputs (None: not ready).
    active : bool
    overruns : int
    """

    def __init__(self, max_basis: int = MAX_BASIS):
        self.max_basis = check_max_basis(max_basis)
        self.regs = {int(r): 0 for r in Reg}
        self.mem = [0] * (3 * max_basis)
        self.x = self.v = self.phi = 0
        self.qd0 = self.vd0 = self.ad0 = 0
        self.pending: tuple[int, int, int] | None = None
        self._ready_at: int | None = None
        self.active = False
        self.overruns = 0

    # -- host port -------------------------------------------------------------------------

    def write(self, addr: int, word: int) -> None:
        """Host write of a 24-bit word (any time; G and INVTAU are used from the next step's
        computation, other words written while a computation runs are undefined)."""
        addr &= (1 << addr_width(self.max_basis)) - 1
        word = wrap(word)
        if addr >= N_SCALARS:
            if addr - N_SCALARS < len(self.mem):
                self.mem[addr - N_SCALARS] = word
        elif addr == Reg.N_BASIS:
            self.regs[addr] = min(max(word, 0), self.max_basis)
        elif addr in self.regs:
            self.regs[addr] = word

    def read(self, addr: int) -> int:
        """The word at ``addr`` (0 for an unused address)."""
        if addr >= N_SCALARS:
            return self.mem[addr - N_SCALARS] if addr - N_SCALARS < len(self.mem) else 0
        return self.regs.get(addr, 0)

    @property
    def n_basis(self) -> int:
        return self.regs[Reg.N_BASIS]

    @property
    def cycles(self) -> int:
        """Cycles the gateware takes for one step's computation with the current n_basis."""
        return step_cycles(self.n_basis)

    # -- control strobes ---------------------------------------------------------------------

    def start(self, cycle: int | None = None) -> tuple[int, int, int]:
        """Initialise from X0, V0, φ = 0 and compute step 0's outputs (pending, returned).

        ``cycle``: the clock cycle of the strobe, for a timed caller (see :meth:`step`)."""
        self._ready_at = None if cycle is None else cycle + 1 + self.cycles
        self.x = self.regs[Reg.X0] << 12
        self.v = self.regs[Reg.V0] << 6
        self.phi = 0
        self.active = True
        self.pending = self._compute()
        return self.pending

    def stop(self) -> None:
        """Stop: position held, velocity and acceleration zero, nothing pending."""
        self.active = False
        self.pending = None
        self.vd0 = self.ad0 = 0

    def step(self, cycle: int | None = None) -> tuple[int, int, int] | None:
        """The step strobe: commit the pending outputs and compute the next step.

        Returns the committed ``(qd0, vd0, ad0)``, or None if nothing was pending (an overrun
        while active, counted; ignored while stopped). With ``cycle`` (the strobe's clock
        cycle, as for :meth:`start`) the pending step counts only from ``cycles + 1`` cycles
        after the strobe that started its computation, when the gateware's ``ready`` rises."""
        if not self.active:
            return None
        if self.pending is None or (cycle is not None and self._ready_at is not None
                                    and cycle < self._ready_at):
            self.overruns = min(self.overruns + 1, 0xFFFF)
            return None
        self.qd0, self.vd0, self.ad0 = out = self.pending
        self._ready_at = None if cycle is None else cycle + 1 + self.cycles
        self.pending = self._compute()
        return out

    def ready(self, cycle: int | None = None) -> bool:
        """Whether a step strobe in ``cycle`` would commit (``ready``)."""
        return self.active and self.pending is not None and (
            cycle is None or self._ready_at is None or cycle >= self._ready_at)

    # -- one step's computation ----------------------------------------------------------------

    def _forcing_ratio(self, s: int) -> int:
        n = self.n_basis
        u = []
        for i in range(n):
            c = self.mem[self.max_basis + i]
            r = self.mem[2 * self.max_basis + i]
            t = rs((s - c) * r, 14)
            u.append(t * t)
        if not u:
            return 0
        umin = min(u)
        num = den = 0
        for i in range(n):
            psi = exp2neg(min(u[i] - umin, PHI_MAX))
            num += psi * self.mem[i]
            den += psi
        q = (abs(num) << 10) // den
        f = (q + 1) >> 1
        return -f if num < 0 else f

    def _compute(self) -> tuple[int, int, int]:
        g, it = self.regs[Reg.GOAL], self.regs[Reg.INVTAU]
        k = rs(self.regs[Reg.DT] * it, 12)
        dphi = rs(k * self.regs[Reg.PHASE_RATE], 14)
        s = rs(exp2neg(self.phi), 6)
        f = self._forcing_ratio(s)
        sf = rs(s * f, 22)
        gs = self.regs[Reg.FLAGS] & FLAG_GOAL_SCALING
        amp = g - self.regs[Reg.X0] if gs else self.regs[Reg.AMPLITUDE]
        force = rs(sf * amp, 20)
        e = rs((g << 12) - self.x, 8)
        vdot = saturate(rs(e * self.regs[Reg.ALPHA_BETA], 12)
                        - rs(self.v * self.regs[Reg.ALPHA], 20) + force, 35)
        radc = self.regs[Reg.RADC]
        a1 = saturate(rs(vdot * it, 20), 35)
        a2 = saturate(rs(a1 * it, 20), 35)
        ad0 = saturate(rs(a2 * radc, 26))
        vt = saturate(rs(self.v * it, 22), 35)
        vd0 = saturate(rs(vt * radc, 25))
        qd0 = saturate(rs(self.x, 12))
        self.v = saturate(self.v + rs(k * vdot, 32), 35)
        self.x = saturate(self.x + rs(k * self.v, 32), 40)
        self.phi = min(max(self.phi + dphi, 0), PHI_MAX)
        return qd0, vd0, ad0
