"""Constants of the node's sine/cosine unit: binary-angle scale, CORDIC widths and tables.

# Ref: J. E. Volder, "The CORDIC trigonometric computing technique", IRE Trans. Electronic
# Computers EC-8(3), 1959 (rotation mode).

The arithmetic (count → 24-bit binary angle → half-turn fold → :data:`ITERATIONS` rotation
steps → TRIG words) is specified bit for bit by the reference :mod:`mrm_cosim.hdl.node.trig_ref`
and built by the gateware :mod:`mrm_cosim.hdl.node.trig`; both take these numbers from here:

* ``x, y`` are ``WIDTH``-bit with :data:`GUARD` bits below the TRIG output LSB, starting from
  :data:`X0` (1 / the CORDIC gain);
* ``z`` is in binary-angle units (2^-24 turn) with :data:`ZGUARD` extra bits, and step ``i``
  rotates by :data:`ATAN` ``[i]`` = atan(2^-i) in those units;
* :func:`bam_constant` turns a joint count into a binary angle with one multiplication.
"""

from __future__ import annotations

import math

from .fixed import TRIG

__all__ = ["ITERATIONS", "GUARD", "ZGUARD", "WIDTH", "ATAN", "X0", "bam_constant"]

ITERATIONS = 24
GUARD = 4
ZGUARD = 4
WIDTH = 2 + (-TRIG.lsb) + GUARD          # |x|, |y| ≤ 1.65 before rounding
_ZBITS = 24 + ZGUARD
ATAN = [round(math.atan(2.0**-i) / (2 * math.pi) * 2**_ZBITS) for i in range(ITERATIONS)]
_GAIN = math.prod(math.sqrt(1 + 2.0**(-2 * i)) for i in range(ITERATIONS))
X0 = round(2**(-TRIG.lsb + GUARD) / _GAIN)


def bam_constant(counts_per_rev: int) -> int:
    """``KB = round(2^46 / counts_per_rev)``: binary-angle units (2^-24 turn) per count, Q22."""
    if not isinstance(counts_per_rev, int) or counts_per_rev <= 0:
        raise ValueError(f"counts per revolution must be a positive integer, not "
                         f"{counts_per_rev!r}")
    return round(2**46 / counts_per_rev)
