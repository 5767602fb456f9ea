"""Sine and cosine of the joint angle from the encoder count: binary angle, then CORDIC.

# Ref: J. E. Volder, "The CORDIC trigonometric computing technique", IRE Trans. Electronic
# Computers EC-8(3), 1959 (rotation mode).

No divider and no table: one constant multiplication turns the count into a 24-bit binary angle,
then :data:`~mrm_cosim.protocol.cordic.ITERATIONS` shift-and-add steps, two cycles each (shift,
then add: short paths). The arithmetic is specified, bit for bit, by :mod:`.trig_ref`.
"""

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.cordic import ATAN, GUARD, ITERATIONS, WIDTH, X0, ZGUARD, bam_constant
from mrm_cosim.protocol.fixed import WORD

__all__ = ["SinCos", "LATENCY"]

LATENCY = 2 * ITERATIONS + 5


class SinCos(wiring.Component):
    """Cosine and sine (TRIG words) of a joint count.

    Parameters
    ----------
    counts_per_rev : int
        Encoder counts per joint revolution (800,000 on the MRM).

    Attributes
    ----------
    start : In(1)
        Strobe: latch ``count`` and compute (ignored while busy).
    count : In(signed(32))
        Joint count; its low 24 bits are used (±2^23 counts).
    busy : Out(1)
    done : Out(1)
        One-cycle pulse in the first cycle ``cos`` and ``sin`` hold the new result
        (:data:`LATENCY` cycles after ``start``).
    cos, sin : Out(signed(24))
    """

    start: In(1)
    count: In(signed(32))
    busy:  Out(1)
    done:  Out(1)
    cos:   Out(signed(WORD))
    sin:   Out(signed(WORD))

    def __init__(self, *, counts_per_rev: int):
        self._kb = bam_constant(counts_per_rev)  # validates
        self._cpr = counts_per_rev
        super().__init__()

    @property
    def counts_per_rev(self) -> int:
        return self._cpr

    def elaborate(self, platform):
        m = Module()

        prod = Signal(signed(24 + self._kb.bit_length() + 1))
        bam  = Signal(signed(24))
        flip = Signal()
        x    = Signal(signed(WIDTH))
        y    = Signal(signed(WIDTH))
        z    = Signal(signed(24 + ZGUARD + 1))
        i    = Signal(range(ITERATIONS))
        atan = Array(C(a, 24 + ZGUARD + 1) for a in ATAN)

        folded = Signal(signed(24))
        m.d.sync += self.done.eq(0)
        need_flip = (bam > (1 << 22)) | (bam < -(1 << 22))
        m.d.comb += folded.eq(Mux(need_flip, bam + (1 << 23), bam))

        cnt = Signal(signed(24))
        xs  = Signal(signed(WIDTH))
        ys  = Signal(signed(WIDTH))
        with m.FSM():
            with m.State("Idle"):
                with m.If(self.start):
                    m.d.sync += [
                        cnt.eq(self.count[:24].as_signed()),
                        self.busy.eq(1),
                    ]
                    m.next = "Multiply"
            with m.State("Multiply"):
                m.d.sync += prod.eq(cnt * self._kb)
                m.next = "Angle"
            with m.State("Angle"):
                m.d.sync += bam.eq(((prod + (1 << 21)) >> 22)[:24])
                m.next = "Fold"
            with m.State("Fold"):
                m.d.sync += [
                    flip.eq(need_flip),
                    x.eq(X0),
                    y.eq(0),
                    z.eq(folded << ZGUARD),
                    i.eq(0),
                ]
                m.next = "Shift"
            # Two cycles per iteration: the shifted operands are registered, then added.
            with m.State("Shift"):
                m.d.sync += [
                    xs.eq(x >> i),
                    ys.eq(y >> i),
                ]
                m.next = "Rotate"
            with m.State("Rotate"):
                with m.If(z >= 0):
                    m.d.sync += [
                        x.eq(x - ys),
                        y.eq(y + xs),
                        z.eq(z - atan[i]),
                    ]
                with m.Else():
                    m.d.sync += [
                        x.eq(x + ys),
                        y.eq(y - xs),
                        z.eq(z + atan[i]),
                    ]
                m.d.sync += i.eq(i + 1)
                with m.If(i == ITERATIONS - 1):
                    m.next = "Output"
                with m.Else():
                    m.next = "Shift"
            with m.State("Output"):
                c = (x + (1 << (GUARD - 1))) >> GUARD
                s = (y + (1 << (GUARD - 1))) >> GUARD
                m.d.sync += [
                    self.cos.eq(Mux(flip, -c, c)),
                    self.sin.eq(Mux(flip, -s, s)),
                    self.busy.eq(0),
                    self.done.eq(1),
                ]
                m.next = "Idle"
        return m
