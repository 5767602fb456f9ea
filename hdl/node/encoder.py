"""Quadrature encoder interface: synchronizer, glitch filter, ×4 decoder, velocity estimator.

Cycle-exact behaviour, the reasons for the M/T velocity method and the reciprocal (table plus
one Newton–Raphson step, since there is no divider) are in :mod:`.encoder_ref`, which this
gateware equals bit for bit. Velocity pipeline, one stage per cycle after a ``sample`` strobe::

    SA  the strobe's cycle: count − c_ref and the window latched (strobes one cycle apart:
        the second is ignored)
    SB  case (measure / bound / stop), numerator, denominator; the reference moves
    S1  leading one of the denominator (and |dc| + 1 for a bound)
    S1b normalization of the denominator to 17 bits; table address
    S1c table word registered
    S2  u  = m · y0                         (table word y0 arrives)
    S3a t  = y0 · (1 − u)
    S3  y1 = y0 + t                         (Newton–Raphson)
    S4  n  = numerator · y1
    S5  w  = n · K_v
    S6  t  = floor(w / 2^(p+5))
    S7  r  = floor((t + 1) / 2) = round(w / 2^(p+6)), saturated to a VEL word
    S8  velocity ← r per case               → visible VEL_LATENCY cycles after the strobe

Each product but the last fits one MULT18X18 (17-bit unsigned operands, or a small signed one).
"""

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.encoder import AGE_BITS, AGE_MAX, DC_MAX, RECIP_TABLE, EncoderParams
from mrm_cosim.protocol.fixed import WORD, WORD_MAX, WORD_MIN

__all__ = ["QuadratureEncoder"]

_MEASURE, _BOUND, _STOP = 0, 1, 2


class QuadratureEncoder(wiring.Component):
    """Encoder lines in; count, illegal-transition count and velocity estimate out.

    Parameters
    ----------
    params : EncoderParams

    Attributes
    ----------
    a, b : In(1)
        Raw encoder lines (asynchronous).
    sample : In(1)
        Strobe: start a velocity update from the current state.
    preset, preset_count : In(1), In(signed(32))
        Strobe: load the count (and the velocity reference) with ``preset_count``.
    count : Out(signed(32))
    velocity : Out(signed(24))
        VEL word (rad/s, LSB 2^-19).
    errors : Out(16)
        Illegal transitions (both lines changed at once), saturating.
    """

    a:            In(1)
    b:            In(1)
    sample:       In(1)
    preset:       In(1)
    preset_count: In(signed(32))
    count:        Out(signed(32))
    velocity: Out(signed(WORD))
    errors:   Out(16)

    def __init__(self, params: EncoderParams | None = None):
        self._p = params or EncoderParams()
        super().__init__()

    @property
    def params(self) -> EncoderParams:
        return self._p

    def elaborate(self, platform):
        m = Module()
        edge = self._decoder(m)
        self._velocity(m, *self._sample_decision(m, edge))
        return m

    def _decoder(self, m):
        """Synchronizer, glitch filter, ×4 decoder: ``count`` and ``errors``; returns the
        strobe of a legal transition (an edge)."""
        p = self._p
        # --- synchronizer, filter, decoder ----------------------------------------------------
        s1 = Signal(2)
        s2 = Signal(2)
        filt = Signal(2)
        m.d.sync += [
            s1.eq(Cat(self.a, self.b)),
            s2.eq(s1),
        ]
        new = Signal(2)
        m.d.comb += new.eq(filt)
        wait   = Signal(2, init=2)
        primed = Signal()
        running = Signal()
        m.d.comb += running.eq((wait == 0) & primed)
        with m.If(wait != 0):
            m.d.sync += wait.eq(wait - 1)
        with m.Elif(~primed):
            m.d.comb += new.eq(s2)
            m.d.sync += primed.eq(1)
        for k in range(2):
            fcnt = Signal(range(max(2, p.filter_cycles)), name=f"fcnt_{k}")
            with m.If(~running):
                pass
            with m.Elif(s2[k] != filt[k]):
                with m.If(fcnt == p.filter_cycles - 1):
                    m.d.comb += new[k].eq(s2[k])
                    m.d.sync += fcnt.eq(0)
                with m.Else():
                    m.d.sync += fcnt.eq(fcnt + 1)
            with m.Else():
                m.d.sync += fcnt.eq(0)
        m.d.sync += filt.eq(new)

        def phase(ab):  # (A, B) = (0,0) (1,0) (1,1) (0,1) -> 0 1 2 3
            return Cat(ab[0] ^ ab[1], ab[1])

        d = Signal(2)
        m.d.comb += d.eq(Mux(running, phase(new) - phase(filt), 0))
        edge = Signal()
        m.d.comb += edge.eq((d == 1) | (d == 3))
        with m.If((d == 2) & (self.errors != 0xFFFF)):
            m.d.sync += self.errors.eq(self.errors + 1)
        with m.If(self.preset):
            m.d.sync += self.count.eq(self.preset_count)
        with m.Elif(d == 1):
            m.d.sync += self.count.eq(self.count + 1)
        with m.Elif(d == 3):
            m.d.sync += self.count.eq(self.count - 1)
        return edge

    def _sample_decision(self, m, edge):
        """Edge ages, the reference, and stages SA and SB; returns SB's registers
        ``(ok, case, numerator, denominator)``."""
        p = self._p
        # --- ages and the sample decision -----------------------------------------------------
        age_edge = Signal(AGE_BITS)
        age_ref  = Signal(AGE_BITS)
        c_ref    = Signal(signed(32))
        with m.If(edge):
            m.d.sync += age_edge.eq(0)
        with m.Elif(age_edge != AGE_MAX):
            m.d.sync += age_edge.eq(age_edge + 1)

        # SA (the strobe's cycle): snapshot the differences; SB: decide. A strobe in the cycle
        # right after a strobe is ignored; the reference moves at the end of SB.
        a_ok     = Signal()
        a_cancel = Signal()
        a_dc     = Signal(signed(33))
        a_window = Signal(signed(AGE_BITS + 1))
        a_count  = Signal(signed(32))
        a_edge   = Signal(AGE_BITS)
        a_ref    = Signal(AGE_BITS)
        take = Signal()
        m.d.comb += take.eq(self.sample & ~a_ok)
        m.d.sync += [
            a_ok.eq(take),
            a_cancel.eq(self.preset),
            a_dc.eq(self.count - c_ref),
            a_window.eq(age_ref - age_edge),
            a_count.eq(self.count),
            a_edge.eq(age_edge),
            a_ref.eq(age_ref),
        ]
        dc = Signal(signed(11))
        # Saturation to 10 bits by a sign-extension check (no magnitude comparators).
        high = a_dc[9:]
        fits = (high == 0) | (high == (1 << len(high)) - 1)
        m.d.comb += dc.eq(Mux(fits, a_dc[:10].as_signed(), Mux(a_dc[-1], -DC_MAX - 1, DC_MAX)))
        s0_case = Signal(2)
        s0_num  = Signal(signed(11))
        s0_den  = Signal(AGE_BITS)
        s0_ok   = Signal()
        m.d.sync += s0_ok.eq(a_ok)
        measure = (dc != 0) & (a_window >= p.min_window)
        with m.If(age_ref != AGE_MAX):
            m.d.sync += age_ref.eq(age_ref + 1)
        with m.If(a_ok & measure):
            m.d.sync += [
                s0_case.eq(_MEASURE),
                s0_num.eq(dc),
                s0_den.eq(a_window),
            ]
            with m.If(~a_cancel):
                m.d.sync += [
                    c_ref.eq(a_count),
                    age_ref.eq(Mux(a_edge >= AGE_MAX - 1, AGE_MAX, a_edge + 2)),
                ]
        with m.Elif(a_ok & (a_edge >= p.stop_cycles)):
            m.d.sync += [
                s0_case.eq(_STOP),
                s0_num.eq(0),
                s0_den.eq(1),
            ]
        with m.Elif(a_ok):
            m.d.sync += [
                s0_case.eq(_BOUND),
                s0_num.eq(dc),                  # |dc| + 1 is formed in S1
                s0_den.eq(a_ref),
            ]

        with m.If(self.preset):
            m.d.sync += c_ref.eq(self.preset_count)
        return s0_ok, s0_case, s0_num, s0_den

    def _velocity(self, m, s0_ok, s0_case, s0_num, s0_den):
        """Stages S1 .. S8: the reciprocal of the denominator, the scaled product, rounding,
        saturation and the update of ``velocity`` per case."""
        p = self._p

        def stage(name, value_or_shape, src):
            sig = Signal(value_or_shape, name=name)
            m.d.sync += sig.eq(src)
            return sig

        # --- S1: leading one of the denominator; |dc| + 1 for a bound ------------------------
        den = Signal(AGE_BITS)
        m.d.comb += den.eq(Mux(s0_den == 0, 1, s0_den))
        lead = Signal(range(AGE_BITS))
        for i in range(AGE_BITS):
            with m.If(den[i]):
                m.d.comb += lead.eq(i)
        bound_num = Signal(signed(11))
        m.d.comb += bound_num.eq(Mux(s0_num < 0, -s0_num, s0_num) + 1)
        s1_ok, s1_case = stage("s1_ok", 1, s0_ok), stage("s1_case", 2, s0_case)
        s1_num = stage("s1_num", signed(11), Mux(s0_case == _BOUND, bound_num, s0_num))
        s1_p = stage("s1_p", range(AGE_BITS), lead)
        s1_den = stage("s1_den", AGE_BITS, den)

        # --- S1b: normalize to 17 bits; table address ------------------------------------------
        norm = Signal(AGE_BITS)
        shift = Signal(range(AGE_BITS))
        m.d.comb += [
            shift.eq(AGE_BITS - 1 - s1_p),
            norm.eq(s1_den << shift),
        ]
        m.submodules.table = table = Memory(shape=17, depth=256, init=RECIP_TABLE)
        rd = table.read_port()
        m.d.comb += rd.addr.eq(norm[AGE_BITS - 9:AGE_BITS - 1])
        s1b_ok, s1b_case = stage("s1b_ok", 1, s1_ok), stage("s1b_case", 2, s1_case)
        s1b_num = stage("s1b_num", signed(11), s1_num)
        s1b_p = stage("s1b_p", range(AGE_BITS), s1_p)
        s1b_m = stage("s1b_m", 17, norm[AGE_BITS - 17:])

        # --- S1c: the table word, registered off the block RAM ------------------------------
        s1c_ok, s1c_case = stage("s1c_ok", 1, s1b_ok), stage("s1c_case", 2, s1b_case)
        s1c_num = stage("s1c_num", signed(11), s1b_num)
        s1c_p, s1c_m = stage("s1c_p", range(AGE_BITS), s1b_p), stage("s1c_m", 17, s1b_m)
        y0 = stage("s1c_y0", 17, rd.data)

        # --- S2: u = m · y0 -------------------------------------------------------------------
        s2_ok, s2_case = stage("s2_ok", 1, s1c_ok), stage("s2_case", 2, s1c_case)
        s2_num, s2_p = stage("s2_num", signed(11), s1c_num), stage("s2_p", range(AGE_BITS), s1c_p)
        s2_y0 = stage("s2_y0", 17, y0)
        s2_u  = stage("s2_u", 19, (s1c_m * y0) >> 16)

        # --- S3: y1 = y0 + y0 · (1 − u), the product then the sum -----------------------------
        s3a_ok, s3a_case = stage("s3a_ok", 1, s2_ok), stage("s3a_case", 2, s2_case)
        s3a_num, s3a_p = stage("s3a_num", signed(11), s2_num), stage("s3a_p", range(AGE_BITS),
                                                                      s2_p)
        d = Signal(signed(20))
        m.d.comb += d.eq((1 << 17) - s2_u)
        s3a_y0 = stage("s3a_y0", 17, s2_y0)
        s3a_t = stage("s3a_t", signed(38), s2_y0 * d)
        s3_ok, s3_case, s3_num, s3_p = (stage("s3_ok", 1, s3a_ok), stage("s3_case", 2, s3a_case),
                                        stage("s3_num", signed(11), s3a_num),
                                        stage("s3_p", range(AGE_BITS), s3a_p))
        s3_y1 = stage("s3_y1", 18, s3a_y0 + (s3a_t >> 17))

        # --- S4: n = numerator · y1 -----------------------------------------------------------
        s4_ok, s4_case, s4_p = (stage("s4_ok", 1, s3_ok), stage("s4_case", 2, s3_case),
                                stage("s4_p", range(AGE_BITS), s3_p))
        s4_n = stage("s4_n", signed(30), s3_num * s3_y1)

        # --- S5: w = n · K_v; the rounding constant and shift for S6 ------------------------
        s5_ok, s5_case = stage("s5_ok", 1, s4_ok), stage("s5_case", 2, s4_case)
        s5_w = stage("s5_w", signed(48), s4_n * p.kv)
        s5_sh = stage("s5_sh", range(AGE_BITS + 6), s4_p + 5)

        # --- S6: shift by all but one bit (floor((w + 2^(s-1)) / 2^s) =
        #         floor((floor(w / 2^(s-1)) + 1) / 2), s ≥ 6) ----------------------------------
        s6_ok, s6_case = stage("s6_ok", 1, s5_ok), stage("s6_case", 2, s5_case)
        s6_t = stage("s6_t", signed(48), s5_w >> s5_sh)

        # --- S7: round, saturate ----------------------------------------------------------------
        s7_ok, s7_case = stage("s7_ok", 1, s6_ok), stage("s7_case", 2, s6_case)
        r = Signal(signed(48))
        m.d.comb += r.eq((s6_t + 1) >> 1)
        s7_v = stage("s7_v", signed(WORD), Mux(r > WORD_MAX, WORD_MAX,
                                               Mux(r < WORD_MIN, WORD_MIN, r)))

        # --- S8: apply ------------------------------------------------------------------------
        v = self.velocity
        with m.If(s7_ok):
            with m.Switch(s7_case):
                with m.Case(_MEASURE):
                    m.d.sync += v.eq(s7_v)
                with m.Case(_STOP):
                    m.d.sync += v.eq(0)
                with m.Case(_BOUND):
                    with m.If((v > 0) & (v > s7_v)):
                        m.d.sync += v.eq(s7_v)
                    with m.Elif((v < 0) & (-v > s7_v)):
                        m.d.sync += v.eq(-s7_v)
