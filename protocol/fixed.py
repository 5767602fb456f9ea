"""Fixed-point number formats of the slave node: 24-bit words with a binary-point position.

Every quantity the node stores or sends is a signed 24-bit word ``w`` meaning ``w · 2^lsb``
(the format's LSB exponent). One word size everywhere keeps the packet layout simple (Comm B:
13 words in 40 bytes, DESIGN.md) and lets a 24×24 product map onto four MULT18X18 blocks.
The choices and their error budget are in docs/node.md.

Arithmetic helpers (bit-exact with the gateware):

* :func:`round_shift` — round half up: ``floor(v / 2^s + 1/2)`` for integers, by adding half an
  output LSB and an arithmetic shift (two's complement, so it rounds ties towards +∞);
* :func:`saturate` / :func:`wrap` — to the signed 24-bit range, or modulo 2^24.

Host-side conversion (:meth:`Fmt.encode`) rounds a float the same way and saturates; the upload
path uses :meth:`Fmt.encode_checked`, which refuses a value that does not fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mrm_cosim.errors import InputError, require_finite

__all__ = ["WORD", "WORD_MIN", "WORD_MAX", "Fmt", "round_shift", "saturate", "wrap",
           "VEL", "ACC", "TRIG", "FORCE", "GAIN", "THETA", "RHOT", "SIG", "INVT", "POS",
           "TIME", "CNT", "TS", "CT", "ANG", "KC", "LAMC", "LAM", "IVS", "IVLC", "SGN", "IM",
           "VISC", "KP", "KI", "KD", "IHI", "FORMATS", "theta_group"]

WORD = 24
WORD_MIN = -(1 << (WORD - 1))
WORD_MAX = (1 << (WORD - 1)) - 1


def saturate(v: int, width: int = WORD) -> int:
    """Clamp an integer to the signed ``width``-bit range."""
    lo, hi = -(1 << (width - 1)), (1 << (width - 1)) - 1
    return lo if v < lo else hi if v > hi else v


def wrap(v: int, width: int = WORD) -> int:
    """The signed ``width``-bit value with the same low ``width`` bits as ``v``."""
    v &= (1 << width) - 1
    return v - (1 << width) if v >> (width - 1) else v


def round_shift(v: int, shift: int) -> int:
    """``floor(v / 2^shift + 1/2)`` for ``shift ≥ 0`` (round half up); ``v`` for 0."""
    if shift < 0:
        raise ValueError(f"shift must be non-negative, not {shift!r}")
    return (v + (1 << (shift - 1))) >> shift if shift else v


@dataclass(frozen=True)
class Fmt:
    """A 24-bit signed fixed-point format: a word ``w`` stands for ``w · 2^lsb`` ``unit``.

    Attributes
    ----------
    name : str
    lsb : int
        Exponent of the least significant bit.
    unit : str
        SI unit of the value, for messages and docs.
    """

    name: str
    lsb: int
    unit: str

    @property
    def resolution(self) -> float:
        """Value of one LSB."""
        return math.ldexp(1.0, self.lsb)

    @property
    def max(self) -> float:
        """Largest representable value (the smallest is ``-max - resolution``)."""
        return WORD_MAX * self.resolution

    def encode(self, x: float) -> int:
        """Nearest word to ``x`` (ties up), saturated to the 24-bit range."""
        w = math.floor(math.ldexp(float(x), -self.lsb) + 0.5)
        # saturate(w), inline: the master encodes some forty words a period
        return WORD_MIN if w < WORD_MIN else WORD_MAX if w > WORD_MAX else w

    def encode_checked(self, x, field: str) -> int:
        """Like :meth:`encode`, but raise :class:`InputError` naming ``field`` if ``x`` is not
        finite or does not fit the format."""
        v = require_finite(x, field)
        w = math.floor(math.ldexp(v, -self.lsb) + 0.5)
        if not WORD_MIN <= w <= WORD_MAX:
            raise InputError(field, f"{v!r} {self.unit} does not fit the node's {self.name} "
                             f"format (|x| ≤ {self.max:.6g} {self.unit})")
        return w

    def decode(self, w: int) -> float:
        """The value of word ``w``."""
        return math.ldexp(float(w), self.lsb)


# Formats of the VDC unit and the packets (docs/node.md "Number formats").
VEL   = Fmt("VEL",   -19, "m/s or rad/s")      # ±16, 1.9e-6: V, V_r, q̇, q̇_r
ACC   = Fmt("ACC",   -14, "m/s² or rad/s²")    # ±512, 6.1e-5: dV_r/dt, g, regressor entries
TRIG  = Fmt("TRIG",  -22, "1")                 # ±2, 2.4e-7: sin q, cos q, unit constants
FORCE = Fmt("FORCE", -13, "N or N·m")          # ±1024, 1.2e-4: F_r, τ_Lr, torques
GAIN  = Fmt("GAIN",  -12, "N·s/m or N·m·s/rad")  # ±2048, 2.4e-4: K, k_j
SIG   = Fmt("SIG",   -20, "θ-rate/ρ")          # ±8, 9.5e-7: adaptation signal s = Yᵀ(V_r − V)
INVT  = Fmt("INVT",  -8,  "1/s")               # ±32768, 3.9e-3: 1/T of the backward difference
POS   = Fmt("POS",   -4,  "counts")            # ±524288 counts (±235°): joint positions
TIME  = Fmt("TIME",  0,   "cycles")            # clock cycles
CNT   = Fmt("CNT",   0,   "counts")            # ±8.4e6: the encoder count as an engine word

# Joint controller (docs/node.md "Joint controller").
TS    = Fmt("TS",    -26, "s")                 # ±0.125: time since the period start
CT    = Fmt("CT",    -48, "s")                 # ±3e-8: one clock period (and half of it)
ANG   = Fmt("ANG",   -26, "rad")               # ±0.125: position increment of the interpolation
KC    = Fmt("KC",    -6,  "counts/rad")        # ±131072: counts per radian
LAMC  = Fmt("LAMC",  -30, "rad/(s·count)")     # ±7.8e-3: λ times radians per count
LAM   = Fmt("LAM",   -12, "1/s")               # ±2048: λ
IVS   = Fmt("IVS",   -8,  "s/rad")             # ±32768: 1 / Stribeck-like smoothing speed
IVLC  = Fmt("IVLC",  -20, "1/count")           # ±8: IVS times LAMC
SGN   = Fmt("SGN",   -23, "1")                 # [−1, 1): smooth sign, saturation is the clip
IM    = Fmt("IM",    -20, "kg·m²")             # ±8: reflected rotor inertia estimate
VISC  = Fmt("VISC",  -16, "N·m·s/rad")         # ±128: viscous friction estimate
# PID gains at PID gain shift 0; a node built with shift s has them 2^s coarser
# (joint_program.pid_formats).
KP    = Fmt("KP",    -24, "N·m/count")         # ±0.5: PID proportional gain
KI    = Fmt("KI",    -32, "N·m/(count·tick)")  # ±2e-3: PID integral gain
KD    = Fmt("KD",    -12, "N·m·s/rad")         # ±2048: PID derivative gain
IHI   = Fmt("IHI",   10,  "counts·ticks")      # ±8.6e9: coarse part of the PID integral

# The 13 parameters in three groups of units: mass, first moments, second moments.
THETA = (Fmt("THETA_M", -18, "kg"),            # ±32, 3.8e-6
         Fmt("THETA_H", -22, "kg·m"),          # ±2, 2.4e-7
         Fmt("THETA_I", -26, "kg·m²"))         # ±0.125, 1.5e-8
# Adaptation gain times period per group: Δθ = ρT·s lands on the parameter's LSB.
RHOT = (Fmt("RHOT_M", -24, "kg/SIG"),          # ±0.5
        Fmt("RHOT_H", -28, "kg·m/SIG"),        # ±0.031
        Fmt("RHOT_I", -32, "kg·m²/SIG"))       # ±0.002


def theta_group(j: int) -> int:
    """Group (0 mass, 1 first moment, 2 second moment) of parameter ``j`` (0-based, 0..12)."""
    if not 0 <= j < 13:
        raise ValueError(f"parameter index must be 0..12, not {j!r}")
    return 0 if j == 0 else 1 if j < 4 else 2


FORMATS = {f.name: f for f in (VEL, ACC, TRIG, FORCE, GAIN, SIG, INVT, POS, TIME, CNT, TS, CT,
                               ANG, KC, LAMC, LAM, IVS, IVLC, SGN, IM, VISC, KP, KI, KD, IHI,
                               *THETA, *RHOT)}
