"""The joint-side DMP generator's words: formats, register map, exp table, host-side encoding.

The generator (:mod:`mrm_cosim.hdl.node.dmp`, bit-exact reference
:mod:`mrm_cosim.hdl.node.dmp_ref`) runs one degree of freedom of the discrete DMP of
:mod:`mrm_cosim.master.dmp` (Liu et al., seeds/000 eqs. 1–2 and 5–6) in fixed point, one step
of the semi-implicit Euler recurrence per ``step`` strobe::

    v̇_k     = α (β (g − x_k) − v_k) + s_k f(s_k) A,     A = g − x0  (or a fixed amplitude)
    v_{k+1} = v_k + k v̇_k,    x_{k+1} = x_k + k v_{k+1},    k = Δt/τ
    s_k     = 2^(−φ_k),       φ_{k+1} = φ_k + k α_s log2(e)

and outputs ``(x_k, v_k/τ, v̇_k/τ²)`` as the node's ``q_d0`` POS, ``q̇_d0`` VEL, ``q̈_d0`` ACC
words. The phase is not multiplied by a decay per step: its exponent φ (in octaves) is
accumulated and ``s = 2^(−φ)`` evaluated every step by the same exp unit as the Gaussians
``ψ_i = 2^(−(R_i (s − c_i))²)`` with ``R_i = √(log2 e) / (√2 σ_i)``. docs/dmp.md "The joint-side
generator" gives the rounding points and the accuracy against the float rollout.

Pure Python: the master encodes with it, the gateware and the reference take their constants
from it.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from mrm_cosim.errors import InputError, require_finite, require_positive
from mrm_cosim.units import CLOCK_HZ

from .fixed import ACC, POS, VEL, Fmt
from .regs import Bank, param_payloads

__all__ = ["MAX_BASIS", "STEP_CYCLES", "SCALARS", "N_SCALARS", "Reg", "weight_addr",
           "centre_addr", "width_addr", "addr_width", "WEIGHT", "PHASE", "WIDTH", "ALPHA",
           "ALPHA_BETA", "PHASE_RATE", "DT", "INVTAU", "RADC", "EXP_BITS", "EXP_FRAC",
           "EXP_TABLE", "PHI_FRAC", "PHI_WIDTH", "PHI_MAX", "FLAG_GOAL_SCALING", "DmpParams",
           "check_max_basis", "dmp_param_payloads", "decode_outputs"]

#: Default (and largest tested) number of Gaussians the generator is built for.
MAX_BASIS = 32
#: Default step: 1 ms at the 50 MHz node clock.
STEP_CYCLES = CLOCK_HZ // 1000

# Word formats (a word w means w · 2^lsb). POS (counts, 2^-4) holds x0, g, v0 and A.
WEIGHT     = Fmt("DMP_W",     -11, "1 (or rad without goal scaling)")  # ±4096: w_i
PHASE      = Fmt("DMP_PH",    -22, "1")              # ±2: the phase s and the centres c_i
WIDTH      = Fmt("DMP_R",     -12, "1")              # ±2048: R_i = √(log2 e)/(√2 σ_i)
ALPHA      = Fmt("DMP_ALPHA", -14, "1")              # ±512: α
ALPHA_BETA = Fmt("DMP_AB",    -8,  "1")              # ±32768: α β
PHASE_RATE = Fmt("DMP_AS",    -16, "octaves")        # ±128: α_s log2(e)
DT         = Fmt("DMP_DT",    -30, "s")              # ≤ 7.8 ms: the step Δt
INVTAU     = Fmt("DMP_IT",    -20, "1/s")            # ≤ 8 /s: 1/τ (τ ≥ 0.125 s)
RADC       = Fmt("DMP_RADC",  -36, "rad/count")      # 2π / counts_per_rev

#: Internal fractions (LSB exponents) of the wide state and intermediate values.
X_LSB, V_LSB, K_LSB, VDOT_LSB, PSI_LSB, F_LSB = -16, -10, -38, -4, -28, -20
#: Phase exponent φ (octaves): unsigned, PHI_FRAC fraction bits, PHI_WIDTH bits in all.
PHI_FRAC, PHI_WIDTH = 40, 46
PHI_MAX = (1 << PHI_WIDTH) - 1
#: Width of the shared multiplier's signed operands (a 35×35 product: four MULT18X18).
MUL_WIDTH = 35

#: exp unit: 2^(−j/2^EXP_BITS) for j = 0 … 2^EXP_BITS, EXP_FRAC fraction bits, round to nearest.
EXP_BITS, EXP_FRAC = 8, 30
EXP_TABLE = tuple(round(math.ldexp(2.0 ** (-j / (1 << EXP_BITS)), EXP_FRAC))
                  for j in range((1 << EXP_BITS) + 1))

FLAG_GOAL_SCALING = 1 << 0


class Reg(enum.IntEnum):
    """Scalar registers (addresses 0–15); the per-basis arrays follow (:func:`weight_addr`)."""

    N_BASIS    = 0    # basis functions in use, 0 … max_basis (larger values are clamped)
    FLAGS      = 1    # bit 0: goal scaling (A = g − x0) else A = AMPLITUDE
    ALPHA      = 2    # α, ALPHA
    ALPHA_BETA = 3    # α β, ALPHA_BETA
    PHASE_RATE = 4    # α_s log2(e), PHASE_RATE
    DT         = 5    # Δt, DT
    INVTAU     = 6    # 1/τ, INVTAU (latched at the start of each step's computation)
    X0         = 7    # start, POS counts
    GOAL       = 8    # goal, POS counts (latched at the start of each step's computation)
    V0         = 9    # initial scaled velocity τ ẋ(0), POS counts
    AMPLITUDE  = 10   # A without goal scaling, POS counts
    RADC       = 11   # radians per count, RADC


SCALARS = tuple(Reg)
N_SCALARS = 16


def check_max_basis(max_basis) -> int:
    """``max_basis`` if it is an integer 1 … 256, else ``ValueError``."""
    if isinstance(max_basis, bool) or not isinstance(max_basis, int) or \
            not 1 <= max_basis <= 256:
        raise ValueError(f"max_basis must be an integer from 1 to 256, not {max_basis!r}")
    return max_basis


def weight_addr(i: int, max_basis: int = MAX_BASIS) -> int:
    """Address of weight ``w_i``."""
    return N_SCALARS + i


def centre_addr(i: int, max_basis: int = MAX_BASIS) -> int:
    """Address of centre ``c_i``."""
    return N_SCALARS + max_basis + i


def width_addr(i: int, max_basis: int = MAX_BASIS) -> int:
    """Address of the inverse width ``R_i``."""
    return N_SCALARS + 2 * max_basis + i


def addr_width(max_basis: int = MAX_BASIS) -> int:
    """Bits of the host address port."""
    return (N_SCALARS + 3 * check_max_basis(max_basis) - 1).bit_length()


def _stable(k: float, alpha: float, beta: float) -> bool:
    # Jury (master/dmp.py Dmp.check_step): eigenvalues of [[1 − k²αβ, k(1 − kα)],
    # [−kαβ, 1 − kα]] inside the unit circle iff kα < 2 and k²αβ < 4 − 2kα.
    ka = k * alpha
    return ka < 2.0 and k * k * alpha * beta < 4.0 - 2.0 * ka


def _floats(values, field: str) -> list[float]:
    try:
        seq = list(values)
    except TypeError:
        raise InputError(field, f"must be a sequence of numbers, not {values!r}") from None
    return [require_finite(v, f"{field}[{i}]") for i, v in enumerate(seq)]


@dataclass(frozen=True)
class DmpParams:
    """The words of one joint's primitive (one DOF), as the generator's registers hold them.

    Attributes
    ----------
    weights, centres, widths : tuple of int, length ``n_basis``
        WEIGHT, PHASE and WIDTH words (``w_i``, ``c_i``, ``R_i``).
    alpha, alpha_beta, phase_rate, dt, invtau : int
        ALPHA, ALPHA_BETA, PHASE_RATE, DT, INVTAU words.
    x0, goal, v0, amplitude : int
        POS words (counts · 2^4).
    radc : int
        RADC word.
    goal_scaling : bool
    """

    weights: tuple[int, ...]
    centres: tuple[int, ...]
    widths: tuple[int, ...]
    alpha: int
    alpha_beta: int
    phase_rate: int
    dt: int
    invtau: int
    x0: int
    goal: int
    v0: int
    amplitude: int
    radc: int
    goal_scaling: bool

    @property
    def n_basis(self) -> int:
        return len(self.weights)

    @classmethod
    def from_float(cls, weights, centers, widths, alpha, beta, alpha_s, tau, x0_rad, g_rad,
                   xd0, goal_scaling, *, counts_per_rev: int = 800_000,
                   step_cycles: int = STEP_CYCLES, amplitude=None, max_basis: int = MAX_BASIS,
                   field: str = "dmp") -> DmpParams:
        """Words of a primitive given in SI units and radians (one DOF of
        :class:`mrm_cosim.master.dmp.Dmp`), checked.

        Parameters
        ----------
        weights, centers, widths : sequence of float, length n_basis
            ``w_i`` (dimensionless with goal scaling, rad without), ``c_i``, ``σ_i``.
        alpha, beta, alpha_s : float
        tau : float, s
        x0_rad, g_rad : float, rad
        xd0 : float, rad/s
            Initial velocity; ``v0 = τ ẋ0`` is stored (for this τ).
        goal_scaling : bool
        counts_per_rev : int
            Encoder counts per joint revolution (≥ 51,472 for the RADC format).
        step_cycles : int
            Clock cycles per step (``Δt = step_cycles / CLOCK_HZ``, at most 7.8 ms).
        amplitude : float, rad, optional
            ``A`` when ``goal_scaling`` is False (default 1 rad, the units the weights of
            :func:`~mrm_cosim.master.dmp.learn_dmp` have then).
        max_basis : int
            The generator's build parameter.
        field : str
            Name of the primitive in errors (``"dmp"`` → ``"dmp.weights[3]"``).

        Raises
        ------
        InputError
            Naming the field that does not fit its format, an n_basis above ``max_basis``, a
            non-positive τ or σ, or a step too long for α (the recurrence would diverge).
        """
        w = _floats(weights, f"{field}.weights")
        c = _floats(centers, f"{field}.centers")
        s = _floats(widths, f"{field}.widths")
        n = len(w)
        if not 1 <= n <= check_max_basis(max_basis):
            raise InputError(f"{field}.weights", f"has {n} basis functions; the generator "
                             f"holds 1 to {max_basis}")
        for name, arr in (("centers", c), ("widths", s)):
            if len(arr) != n:
                raise InputError(f"{field}.{name}", f"must have {n} elements (one per weight), "
                                 f"not {len(arr)}")
        if isinstance(counts_per_rev, bool) or not isinstance(counts_per_rev, int) or \
                counts_per_rev <= 0:
            raise InputError(f"{field}.counts_per_rev", f"must be a positive integer, not "
                             f"{counts_per_rev!r}")
        if isinstance(step_cycles, bool) or not isinstance(step_cycles, int) or step_cycles <= 0:
            raise InputError(f"{field}.step_cycles", f"must be a positive integer, not "
                             f"{step_cycles!r}")
        alpha = require_positive(alpha, f"{field}.alpha")
        beta = require_positive(beta, f"{field}.beta")
        alpha_s = require_positive(alpha_s, f"{field}.alpha_s")
        tau = require_positive(tau, f"{field}.tau")
        dt = step_cycles / CLOCK_HZ
        if not _stable(dt / tau, alpha, beta):
            raise InputError(f"{field}.tau", f"{tau!r} s is too short for a {dt * 1e3:g} ms "
                             f"step with α = {alpha}: the recurrence would diverge")
        kc = counts_per_rev / (2.0 * math.pi)
        ws = tuple(WEIGHT.encode_checked(v, f"{field}.weights[{i}]") for i, v in enumerate(w))
        cs = tuple(PHASE.encode_checked(v, f"{field}.centers[{i}]") for i, v in enumerate(c))
        rs = []
        for i, sigma in enumerate(s):
            sigma = require_positive(sigma, f"{field}.widths[{i}]")
            r = math.sqrt(math.log2(math.e)) / (math.sqrt(2.0) * sigma)
            rs.append(WIDTH.encode_checked(r, f"{field}.widths[{i}]"))
        amp = 1.0 if amplitude is None else amplitude
        invtau = INVTAU.encode_checked(1.0 / tau, f"{field}.tau")
        if invtau <= 0:
            raise InputError(f"{field}.tau", f"{tau!r} s is too long for the INVTAU format "
                             f"(1/τ ≥ {INVTAU.resolution:g} /s)")
        return cls(
            weights=ws, centres=cs, widths=tuple(rs),
            alpha=ALPHA.encode_checked(alpha, f"{field}.alpha"),
            alpha_beta=ALPHA_BETA.encode_checked(alpha * beta, f"{field}.beta"),
            phase_rate=PHASE_RATE.encode_checked(alpha_s * math.log2(math.e),
                                                 f"{field}.alpha_s"),
            dt=DT.encode_checked(dt, f"{field}.step_cycles"),
            invtau=invtau,
            x0=POS.encode_checked(require_finite(x0_rad, f"{field}.x0") * kc, f"{field}.x0"),
            goal=POS.encode_checked(require_finite(g_rad, f"{field}.g") * kc, f"{field}.g"),
            v0=POS.encode_checked(tau * require_finite(xd0, f"{field}.xd0") * kc,
                                  f"{field}.xd0"),
            amplitude=POS.encode_checked(require_finite(amp, f"{field}.amplitude") * kc,
                                         f"{field}.amplitude"),
            radc=RADC.encode_checked(1.0 / kc, f"{field}.counts_per_rev"),
            goal_scaling=bool(goal_scaling))

    def words(self, max_basis: int = MAX_BASIS) -> dict[int, int]:
        """The register map: ``{address: word}`` of every scalar and per-basis word."""
        if self.n_basis > check_max_basis(max_basis):
            raise InputError("dmp.weights", f"has {self.n_basis} basis functions; the "
                             f"generator holds {max_basis}")
        out = {Reg.N_BASIS: self.n_basis,
               Reg.FLAGS: FLAG_GOAL_SCALING if self.goal_scaling else 0,
               Reg.ALPHA: self.alpha, Reg.ALPHA_BETA: self.alpha_beta,
               Reg.PHASE_RATE: self.phase_rate, Reg.DT: self.dt, Reg.INVTAU: self.invtau,
               Reg.X0: self.x0, Reg.GOAL: self.goal, Reg.V0: self.v0,
               Reg.AMPLITUDE: self.amplitude, Reg.RADC: self.radc}
        out = {int(a): v for a, v in out.items()}
        for i in range(self.n_basis):
            out[weight_addr(i, max_basis)] = self.weights[i]
            out[centre_addr(i, max_basis)] = self.centres[i]
            out[width_addr(i, max_basis)] = self.widths[i]
        return out

    def goal_word(self, g_rad: float, *, counts_per_rev: int = 800_000,
                  field: str = "dmp.g") -> tuple[int, int]:
        """``(address, word)`` of a new goal (rad): one write, effective at the next step."""
        kc = counts_per_rev / (2.0 * math.pi)
        return int(Reg.GOAL), POS.encode_checked(require_finite(g_rad, field) * kc, field)

    def invtau_word(self, tau: float, *, field: str = "dmp.tau") -> tuple[int, int]:
        """``(address, word)`` of a new time constant τ (s): one write, effective at the next
        step. Its stability at the uploaded step is the caller's to check
        (:meth:`from_float`); ``v`` is kept, so the speed ``v/τ`` changes with it."""
        tau = require_positive(tau, field)
        w = INVTAU.encode_checked(1.0 / tau, field)
        if w <= 0:
            raise InputError(field, f"{tau!r} s is too long for the INVTAU format")
        return int(Reg.INVTAU), w


def dmp_param_payloads(params: DmpParams, max_basis: int = MAX_BASIS) -> list[bytes]:
    """PARAM payloads (bank :attr:`Bank.DMP`) writing every word of ``params``."""
    return param_payloads(Bank.DMP, params.words(max_basis))


def decode_outputs(qd0: int, vd0: int, ad0: int,
                   counts_per_rev: int = 800_000) -> tuple[float, float, float]:
    """``(q rad, q̇ rad/s, q̈ rad/s²)`` of the generator's three output words."""
    rad = 2.0 * math.pi / counts_per_rev
    return POS.decode(qd0) * rad, VEL.decode(vd0), ACC.decode(ad0)


assert max(EXP_TABLE) < (1 << 31) and EXP_TABLE[-1] == 1 << (EXP_FRAC - 1)
