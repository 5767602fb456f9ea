"""Bit-exact reference of the node's sine/cosine unit: encoder count → binary angle → CORDIC.

# Ref: J. E. Volder, "The CORDIC trigonometric computing technique", IRE Trans. Electronic
# Computers EC-8(3), 1959 (rotation mode).

1. Binary angle: ``bam = floor(c · KB / 2^22 + 1/2) mod 2^24`` with ``KB = round(2^46 / CPR)``,
   the 24-bit fraction of a turn of the joint count ``c`` (24-bit signed, ±10 turns); one
   constant multiplication, no divider. Its error is about half a binary-angle LSB
   (2π/2^24 rad) over the whole count range.
2. Half-turn fold: as a signed angle ``s`` in [−π, π); if ``|s| > π/2`` rotate by π (negate
   the result) so the CORDIC sees [−π/2, π/2].
3. CORDIC rotation, :data:`ITERATIONS` steps of shift-and-add on ``WIDTH``-bit ``x, y`` with
   ``GUARD`` bits below the output LSB; ``z`` in binary-angle units with ``ZGUARD`` extra
   bits; ``d = +1`` when ``z ≥ 0``; shifts are arithmetic (floor).
4. Outputs ``cos q, sin q`` rounded half up to TRIG words (LSB 2^-22).
"""

from __future__ import annotations

from mrm_cosim.protocol.cordic import ATAN, GUARD, ITERATIONS, X0, ZGUARD, bam_constant
from mrm_cosim.protocol.fixed import round_shift, wrap

__all__ = ["binary_angle", "cordic", "sin_cos"]


def binary_angle(count: int, counts_per_rev: int) -> int:
    """24-bit binary angle (unsigned, 2^24 per turn) of a count (taken as 24-bit signed)."""
    c = wrap(count, 24)
    return round_shift(c * bam_constant(counts_per_rev), 22) & 0xFFFFFF


def cordic(bam: int) -> tuple[int, int]:
    """``(cos, sin)`` TRIG words of a 24-bit binary angle."""
    s = wrap(bam, 24)                      # signed, [−2^23, 2^23) = [−π, π)
    flip = s > (1 << 22) or s < -(1 << 22)
    if flip:
        s = wrap(s + (1 << 23), 24)
    x, y, z = X0, 0, s << ZGUARD
    for i in range(ITERATIONS):
        if z >= 0:
            x, y, z = x - (y >> i), y + (x >> i), z - ATAN[i]
        else:
            x, y, z = x + (y >> i), y - (x >> i), z + ATAN[i]
    c, s_ = round_shift(x, GUARD), round_shift(y, GUARD)
    return (-c, -s_) if flip else (c, s_)


def sin_cos(count: int, counts_per_rev: int) -> tuple[int, int]:
    """``(cos q, sin q)`` TRIG words of joint count ``count``."""
    return cordic(binary_angle(count, counts_per_rev))
