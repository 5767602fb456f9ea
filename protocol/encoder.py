"""The node's encoder interface: its build parameters and the velocity estimator's constants.

The quadrature decoder and M/T velocity estimator are specified bit for bit by the reference
:mod:`mrm_cosim.hdl.node.encoder_ref` (which explains every step) and built by the gateware
:mod:`mrm_cosim.hdl.node.encoder`; both take from here the parameters a node is built with
(:class:`EncoderParams`, one set per node: :func:`encoders_per_node`) and the estimator's
widths and reciprocal table. The velocity it reports in Comm A is a VEL word (:mod:`.fixed`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mrm_cosim.errors import InputError
from mrm_cosim.units import CLOCK_HZ

__all__ = ["AGE_BITS", "AGE_MAX", "DC_MAX", "RECIP_TABLE", "EncoderParams", "encoders_per_node"]

#: Width of the ages (cycles since the last edge, and since the reference edge), saturating.
AGE_BITS = 26
AGE_MAX = (1 << AGE_BITS) - 1
#: Largest count difference of one measurement (10 bits signed: −512..511).
DC_MAX = 511
#: ``y0 ≈ 2^17 / m`` for the 256 intervals of the normalized denominator ``m ∈ [1, 2)``.
RECIP_TABLE = [round(2**17 / (1 + (i + 0.5) / 256)) for i in range(256)]


@dataclass(frozen=True)
class EncoderParams:
    """Build-time parameters of the encoder interface.

    Attributes
    ----------
    counts_per_rev : int
        Counts per joint revolution after ×4 decoding (800,000 on the MRM).
    clock_hz : float
        FPGA clock (50 MHz).
    filter_cycles : int
        Cycles a line must hold a new level before it is believed (≥ 1).
    min_window : int
        Shortest time between the two edges of a measurement, cycles.
    stop_cycles : int
        With no edge for this long the velocity is zero, cycles.
    """

    counts_per_rev: int = 800_000
    clock_hz: float = float(CLOCK_HZ)
    filter_cycles: int = 2
    min_window: int = 2048
    stop_cycles: int = 1 << 24

    def __post_init__(self):
        for name in ("counts_per_rev", "filter_cycles", "min_window", "stop_cycles"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InputError(name, f"must be a positive integer, not {v!r}")
        for name in ("min_window", "stop_cycles"):
            if getattr(self, name) > AGE_MAX:
                raise InputError(name, f"must be at most {AGE_MAX}, not {getattr(self, name)!r}")
        if not (math.isfinite(self.clock_hz) and self.clock_hz > 0):
            raise InputError("clock_hz", f"must be positive, not {self.clock_hz!r}")
        if not 0 < self._kv_q8(self.counts_per_rev) < (1 << 17):
            lo, hi = self.counts_per_rev_range()
            raise InputError("counts_per_rev", f"{self.counts_per_rev} gives the velocity "
                             f"constant K_v = {self._kv_q8(self.counts_per_rev) / 256!r} rad/s "
                             f"per count/cycle at {self.clock_hz:g} Hz, outside the estimator's "
                             f"17-bit Q8 range; it must be from {lo} to {hi}")

    def _kv_q8(self, counts_per_rev: int) -> int:
        return round(self.clock_hz * 2 * math.pi / counts_per_rev * 256)

    def counts_per_rev_range(self) -> tuple[int, int]:
        """The smallest and largest ``counts_per_rev`` whose ``K_v`` fits (0 < Q8 < 2^17)."""
        c = self.clock_hz * 2 * math.pi * 256
        lo = max(1, math.floor(c / ((1 << 17) - 0.5)) - 2)
        while not self._kv_q8(lo) < (1 << 17):
            lo += 1
        hi = math.ceil(c / 0.5) + 2
        while not self._kv_q8(hi) > 0:
            hi -= 1
        return lo, hi

    @property
    def kv(self) -> int:
        """``K_v`` in Q8: rad/s per count/cycle times 2^8 (17 bits at 50 MHz, 800,000 cpr);
        :meth:`__post_init__` has checked that it fits."""
        return self._kv_q8(self.counts_per_rev)


def encoders_per_node(encoder, n: int) -> list:
    """``encoder`` as one :class:`EncoderParams` per node: a list or tuple of ``n`` (node 1
    first), or one set (``None``: the default) for every node."""
    encoders = (list(encoder) if isinstance(encoder, list | tuple)
                else [encoder or EncoderParams()] * n)
    if len(encoders) != n:
        raise ValueError(f"encoder: {len(encoders)} parameter sets for {n} nodes")
    return encoders
