"""Joint-side DMP generator: one DOF of a discrete movement primitive, one step per strobe.

# Ref: Ijspeert, Nakanishi, Hoffmann, Pastor, Schaal, "Dynamical movement primitives", Neural
# Computation 25(2), 2013 (transformation and canonical systems); Liu et al., seeds/000
# eqs. 1–2, 5–6 (the float definition is master/dmp.py).

A microprogrammed datapath, like the node's MacEngine: every intermediate value (x, v, φ, k,
s, t, u, ψ, Σψw, Σψ, v̇, …) and the constants it needs live in a 64 × 72-bit register file in
block RAM, and a microprogram in block RAM (:mod:`.dmp_ucode`) issues per five-cycle
micro-operation (read a, read b, operands, product, sum, shift, saturation, write). One signed 35×35
multiplier (four MULT18X18) adds the rounding constant of its one use; one adder/subtractor,
a right shift by 0, 8, 20 or 32 (other rounding points are reached by prescaling a narrow
operand by a power of two: ``rs(a·b, n) = rs(a·2^k·b, n + k)``), and one saturation unit
(24, 35, 40 bits or the unsigned 46-bit clamp of φ) write the result back. A restoring
divider (one quotient bit per cycle) forms ``f = Σψw / Σψ``; the exp unit ``2^(−φ)`` is a
257-entry table of ``2^(−j/256)``, linear interpolation on the multiplier, then a rounding
shift by the integer part as a second product with a scale ``2^(30 − n)`` read from a table —
used for the phase ``s = 2^(−φ)`` (the accumulated exponent, not a product of decays) and for
every Gaussian. The host's words (weights, centres, inverse widths, scalars), the exp table
and the scales share one block RAM; only N_BASIS and the goal-scaling flag are also
registers. The arithmetic is specified bit for bit by :mod:`.dmp_ref`, the register map and
formats by :mod:`mrm_cosim.protocol.dmp`; docs/dmp.md "The joint-side generator".

Double buffering: a computation fills the pending outputs; the ``step`` strobe copies them to
``qd0, vd0, ad0`` (visible the cycle after the strobe) and starts the next one.
"""

from types import SimpleNamespace

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out
from amaranth.utils import bits_for, ceil_log2

from mrm_cosim.protocol.dmp import (EXP_BITS, EXP_TABLE, FLAG_GOAL_SCALING, MAX_BASIS,
                                    MUL_WIDTH, N_SCALARS, PHI_FRAC, PHI_MAX, PHI_WIDTH, Reg,
                                    addr_width, check_max_basis)
from mrm_cosim.protocol.fixed import WORD

from .dmp_ucode import (OP_CYCLES, RCS, RF_INIT, RF_WIDTH, SHIFTS, ASel, BSel, Br, Cond, Dst,
                        EOff, Sat, YSel, assemble, instr_layout, program)

__all__ = ["DmpGenerator"]

QBITS = 34      # quotient bits of the divider: |f| ≤ max|w| bounds q = |num|·2^10/den < 2^34


def _same_from(v, lsb):
    """``v[lsb:]`` all zeros or all ones: ``v >> sh`` fits ``lsb − sh + 1`` signed bits."""
    top = v[lsb:]
    return (top == 0) | (top == (1 << len(top)) - 1)


def saturate_shifted(m, s, sh, sat):
    """``w = sat(s >> SHIFTS[sh])``, the ALU's write-back word (``sat`` a :class:`Sat`).

    The saturation is decided from ``s`` itself, beside the shift, not after it: ``z = s >>
    sh`` fits ``width`` signed bits when ``s``'s bits from ``width − 1 + sh`` up are all equal
    (``z``'s bits above ``s``'s are copies of its sign), so every (sat, sh) pair's decision is a
    tree over ``s``, one select chooses among them, and the word is a last 2:1 mux between ``z``
    and the bound. Decided after the shift, the shift's mux, the decision's tree and the
    saturation's muxes ran one after another: the generator's slowest path (docs/node.md,
    Clock). tests/test_node_dmp.py checks every (sat, sh) pair against the clamp of ``z``.
    """
    z = Signal(signed(RF_WIDTH))
    with m.Switch(sh):
        for k, shift in enumerate(SHIFTS):
            with m.Case(k):
                m.d.comb += z.eq(s >> shift)
    sign = s[-1]
    fits = Signal()
    bound = Signal(signed(RF_WIDTH))
    with m.Switch(sat):
        for case, width in ((Sat.S24, WORD), (Sat.S35, 35), (Sat.S40, 40)):
            with m.Case(case):
                with m.Switch(sh):
                    for k, shift in enumerate(SHIFTS):
                        with m.Case(k):
                            m.d.comb += fits.eq(_same_from(s, width - 1 + shift))
                m.d.comb += bound.eq(Mux(sign, -(1 << (width - 1)), (1 << (width - 1)) - 1))
        with m.Case(Sat.U46):
            # 0 … PHI_MAX: 0 when negative, PHI_MAX when z's bits from PHI_WIDTH are not 0
            with m.Switch(sh):
                for k, shift in enumerate(SHIFTS):
                    with m.Case(k):
                        m.d.comb += fits.eq(~sign & (s[PHI_WIDTH + shift:] == 0))
            m.d.comb += bound.eq(Mux(sign, 0, PHI_MAX))
        with m.Default():
            m.d.comb += fits.eq(1)
    w = Signal(signed(RF_WIDTH))
    m.d.comb += w.eq(Mux(fits, z, bound))
    return w


class DmpGenerator(wiring.Component):
    """The DMP generator of one joint (docs/dmp.md "The joint-side generator").

    Parameters
    ----------
    max_basis : int
        Gaussians the parameter memory holds (1 … 256; default 32).

    Attributes
    ----------
    host_addr : In(addr_width(max_basis))
    host_data : In(signed(24))
    host_we : In(1)
        Parameter write, any cycle, never refused (register map: :class:`~.protocol.dmp.Reg`
        and :func:`~.protocol.dmp.weight_addr` …). GOAL and INVTAU are latched at the start of
        each step's computation; other writes during a computation are undefined.
    start : In(1)
        Strobe: initialise from X0, V0, phase 1 and compute step 0 (pending).
    stop : In(1)
        Strobe: stop; ``qd0`` holds, ``vd0 = ad0 = 0``. Priority stop > start > step.
    step : In(1)
        Strobe: commit the pending step to the outputs (the next cycle), compute the next.
    qd0 : Out(signed(24))
        POS counts.
    vd0 : Out(signed(24))
        VEL rad/s.
    ad0 : Out(signed(24))
        ACC rad/s².
    active, ready, busy : Out(1)
        Started and not stopped; pending step computed; computing.
    overruns : Out(16)
        Step strobes while active and not ready (outputs kept), saturating.
    """

    def __init__(self, *, max_basis: int = MAX_BASIS):
        self._mb = check_max_basis(max_basis)
        super().__init__({
            "host_addr": In(addr_width(max_basis)),
            "host_data": In(signed(WORD)),
            "host_we":   In(1),
            "start":     In(1),
            "stop":      In(1),
            "step":      In(1),
            "qd0":       Out(signed(WORD)),
            "vd0":       Out(signed(WORD)),
            "ad0":       Out(signed(WORD)),
            "active":    Out(1),
            "ready":     Out(1),
            "busy":      Out(1),
            "overruns":  Out(16),
        })

    @property
    def max_basis(self) -> int:
        return self._mb

    def elaborate(self, platform):
        m = Module()
        mb = self._mb
        d = SimpleNamespace()
        ext0 = N_SCALARS + 3 * mb                       # the exp table in the parameter memory
        scales = [(1 << (30 - n)) if n <= 30 else 0 for n in range(64)]
        ext_init = [0] * ext0 + list(EXP_TABLE) + scales
        d.ext_bits = ceil_log2(len(ext_init))
        m.submodules.ext = ext = Memory(shape=signed(32), depth=len(ext_init), init=ext_init,
                                        attrs={"ram_style": "block"})
        words = assemble(program(mb, ext0), instr_layout(d.ext_bits, 7))
        layout = instr_layout(d.ext_bits, 7)
        m.submodules.rom = rom = Memory(shape=layout.size, depth=128, init=words,
                                        attrs={"rom_style": "block", "ram_style": "block"})
        m.submodules.rf = rf = Memory(shape=signed(RF_WIDTH), depth=64, init=RF_INIT,
                                      attrs={"ram_style": "block"})
        d.ext, d.rom = ext.read_port(), rom.read_port()
        d.rfa, d.rfb, d.rfw = rf.read_port(), rf.read_port(), rf.write_port()
        d.ins = Signal(layout)
        m.d.comb += d.ins.eq(d.rom.data)
        # The micro-operation's word again as a register, from phase 1 on: the ROM's output is
        # stable from phase 0 to 4 but comes late in a cycle (a block RAM's clock-to-output),
        # so only phase 0's addresses and the sequencer take it from the ROM.
        d.ins_r = Signal(layout, name="ins_r")
        for name, shape in (("n", range(mb + 1)), ("gs", 1), ("init", 1), ("flag", 1),
                            ("run", 1), ("rdy", 1), ("pc", 7), ("pc_nxt", 7),
                            ("ph", range(OP_CYCLES)), ("i", range(mb)),
                            ("ein", unsigned(PHI_WIDTH)),
                            ("rc", unsigned(32)), ("p", signed(2 * MUL_WIDTH)),
                            ("f", signed(QBITS)), ("stall", 1),
                            ("pqd", signed(WORD)), ("pvd", signed(WORD)),
                            ("pad", signed(WORD))):
            setattr(d, name, Signal(shape, name=name))
        with m.If(d.ph == 0):
            m.d.sync += d.ins_r.eq(d.ins)
        self._host(m, ext.write_port(), d)
        self._sequencer(m, d)
        self._operands(m, d)
        self._alu(m, d)
        self._divider(m, d)
        self._control(m, d)
        return m

    def _host(self, m, wr, d):
        addr, data = self.host_addr, self.host_data
        m.d.comb += [
            wr.addr.eq(addr),
            wr.data.eq(data),
            wr.en.eq(self.host_we & (addr < N_SCALARS + 3 * self._mb)),
        ]
        with m.If(self.host_we):
            with m.Switch(addr):
                with m.Case(Reg.N_BASIS):
                    m.d.sync += d.n.eq(Mux(data < 0, 0, Mux(data > self._mb, self._mb, data)))
                with m.Case(Reg.FLAGS):
                    m.d.sync += d.gs.eq((data & FLAG_GOAL_SCALING) != 0)

    def _sequencer(self, m, d):
        """Program counter, the five phases of a micro-operation (OP_CYCLES), branches."""
        ins = d.ins
        last = OP_CYCLES - 1
        m.d.comb += [d.rom.addr.eq(d.pc_nxt), d.pc_nxt.eq(d.pc)]
        m.d.sync += d.pc.eq(d.pc_nxt)
        with m.If(d.run & ~((d.ph == last) & d.stall)):
            m.d.sync += d.ph.eq(Mux(d.ph == last, 0, d.ph + 1))
        with m.If(d.run & (d.ph == last) & ~d.stall):
            m.d.comb += d.pc_nxt.eq(d.pc + 1)
            with m.Switch(ins.br):
                with m.Case(Br.LOOP):
                    with m.If(d.i == d.n - 1):
                        m.d.sync += d.i.eq(0)
                    with m.Else():
                        m.d.sync += d.i.eq(d.i + 1)
                        m.d.comb += d.pc_nxt.eq(ins.tgt)
                with m.Case(Br.NZERO):
                    with m.If(d.n == 0):
                        m.d.comb += d.pc_nxt.eq(ins.tgt)
                with m.Case(Br.END):
                    m.d.sync += [d.run.eq(0), d.rdy.eq(1)]

    def _operands(self, m, d):
        """Register-file and parameter-memory reads; the multiplier's operands and product."""
        ins = d.ins
        off = Signal(range(1 << d.ext_bits))
        with m.Switch(ins.eoff):
            with m.Case(EOff.I):
                m.d.comb += off.eq(d.i)
            with m.Case(EOff.J):
                m.d.comb += off.eq(d.ein[PHI_FRAC - EXP_BITS:PHI_FRAC])
            with m.Case(EOff.N):
                m.d.comb += off.eq(d.ein[PHI_FRAC:])
        m.d.comb += [
            d.ext.addr.eq(ins.ebase + off),
            d.rfa.addr.eq(ins.ra),
            d.rfb.addr.eq(ins.rb),
        ]
        # Operand a: the register file's word, or one prepared in phase 0 (ein and f do not
        # change between phases 0 and 1), so that a block RAM's output meets one 2:1 mux,
        # not a 4:1, before the multipliers.
        a_alt = Signal(signed(MUL_WIDTH), name="a_alt")
        a_rf = Signal(name="a_rf")                  # the selects, one register bit each
        with m.If(d.ph == 0):
            m.d.sync += a_rf.eq(ins.asel == ASel.RF)
            with m.Switch(ins.asel):
                with m.Case(ASel.R):
                    m.d.sync += a_alt.eq(Cat(C(0, 8),
                                             d.ein[PHI_FRAC - EXP_BITS - 24:PHI_FRAC - EXP_BITS]))
                with m.Case(ASel.F):
                    m.d.sync += a_alt.eq(d.f)
                with m.Case(ASel.ONE):
                    m.d.sync += a_alt.eq(1)
        # The operands are registers at the end of phase 1 and the multipliers take them in
        # phase 2: a block RAM's output (5.8 ns clock to output on an ECP5) and a MULT18X18
        # are no longer one path (docs/node.md, Clock). Both block RAMs' outputs are stable
        # from phase 1 to 4 (their addresses are the ROM's word, stable from phase 0 to 4).
        a = Signal(signed(MUL_WIDTH), name="mul_a")
        b = Signal(signed(MUL_WIDTH), name="mul_b")
        with m.If(d.ph == 1):
            m.d.sync += [
                a.eq(Mux(a_rf, d.rfa.data[:MUL_WIDTH].as_signed(), a_alt)),
                b.eq(Mux(d.ins_r.bsel == BSel.EXT, d.ext.data,
                         d.rfb.data[:MUL_WIDTH].as_signed())),
            ]
        # a·b as four 18×18 signed products (one MULT18X18 each: 17-bit unsigned low halves,
        # 18-bit signed high halves), registered in phase 2, and summed with the rounding
        # constant in phase 3: ``p`` is a·b + rc of the last operands from phase 3 on, and
        # the multipliers and the sum are not one path.
        h = MUL_WIDTH - 18
        parts = {(i, j): Signal(signed(36), name=f"pp_{i}{j}") for i in "lh" for j in "lh"}
        half = {"l": lambda v: v[:h], "h": lambda v: v[h:].as_signed()}
        with m.If((d.ph == 2) & d.ins_r.mul):
            m.d.sync += d.rc.eq(Array(C(v, 32) for v in RCS)[d.ins_r.rc])
            for (i, j), pp in parts.items():
                m.d.sync += pp.eq(half[i](a) * half[j](b))
        m.d.comb += d.p.eq(parts["l", "l"] + d.rc
                           + ((parts["l", "h"] + parts["h", "l"]) << h)
                           + (parts["h", "h"] << (2 * h)))

    def _alu(self, m, d):
        """``z = sat((X ± Y) >> sh)`` and its write, in a micro-operation's last phase."""
        # Phase 3 forms the sum, phase 4 shifts, saturates and writes it. The sum's inputs
        # are registers: the register file's operands taken in phase 1 (the block RAMs'
        # outputs are stable from phase 1 to 4) and the four partial products (``p``, their
        # sum with the rounding constant, is ready in phase 3); phase 4 works from the sum and
        # the micro-operation's fields, both registered (the microcode ROM's output is stable
        # from phase 0 to 4). Every value equals, at phase 4, what a one-cycle ALU computed
        # there from the same operands: this only cuts the path (docs/node.md, Clock).
        x = Signal(signed(RF_WIDTH), name="alu_x")
        y_rf = Signal(signed(RF_WIDTH), name="alu_y_rf")
        with m.If(d.ph == 1):
            m.d.sync += [x.eq(Mux(d.ins_r.xz, 0, d.rfa.data)), y_rf.eq(d.rfb.data)]
        y = Mux(d.ins_r.ysel == YSel.RF, y_rf, d.p)
        s = Signal(signed(RF_WIDTH), name="alu_s")
        m.d.sync += s.eq(x + Mux(d.ins_r.neg, ~y, y) + d.ins_r.neg)
        ins = d.ins_r
        w = saturate_shifted(m, s, ins.sh, ins.sat)
        ok = Signal()
        with m.Switch(ins.cond):
            with m.Case(Cond.ALWAYS):
                m.d.comb += ok.eq(1)
            with m.Case(Cond.INIT):
                m.d.comb += ok.eq(d.init)
            with m.Case(Cond.FLAG):
                m.d.comb += ok.eq(d.flag)
            with m.Case(Cond.NFLAG):
                m.d.comb += ok.eq(~d.flag)
            with m.Case(Cond.GS):
                m.d.comb += ok.eq(d.gs)
            with m.Case(Cond.NGS):
                m.d.comb += ok.eq(~d.gs)
        last = Signal()
        m.d.comb += [
            last.eq(d.run & (d.ph == OP_CYCLES - 1) & ok),
            d.rfw.addr.eq(ins.wa),
            d.rfw.data.eq(w),
            d.rfw.en.eq(last & (ins.dst == Dst.RF)),
        ]
        with m.If(last & ins.setf):
            m.d.sync += d.flag.eq(s < 0)
        with m.If(last):
            with m.Switch(ins.dst):
                with m.Case(Dst.EIN):
                    m.d.sync += d.ein.eq(w)
                with m.Case(Dst.QD):
                    m.d.sync += d.pqd.eq(w)
                with m.Case(Dst.VD):
                    m.d.sync += d.pvd.eq(w)
                with m.Case(Dst.AD):
                    m.d.sync += d.pad.eq(w)

    def _divider(self, m, d):
        """``q = floor(|num|·2^10 / den)``, one bit per cycle; ``f = ±((q + 1) >> 1)``: the
        micro-operation with ``div`` holds the sequencer until ``f`` is ready."""
        den_w = 29 + bits_for(self._mb)
        rem = Signal(unsigned(den_w + 1))
        nlow = Signal(unsigned(QBITS))
        q = Signal(unsigned(QBITS))
        neg = Signal()
        cnt = Signal(range(QBITS))
        act = Signal()
        rnd = Signal()
        m.d.comb += d.stall.eq(d.ins.div & (act | rnd))
        with m.If(d.run & (d.ph == 1) & d.ins.div):
            mag = Cat(C(0, 10), d.rfa.data[:den_w + 25])
            m.d.sync += [rem.eq(mag[QBITS:]), nlow.eq(mag[:QBITS]), q.eq(0),
                         neg.eq(d.flag), cnt.eq(0), act.eq(1)]
        with m.If(act):
            trial = Cat(nlow[-1], rem)
            diff = trial - d.rfb.data[:den_w]       # one subtractor: its borrow is the compare
            fits = ~diff[-1]
            m.d.sync += [rem.eq(Mux(fits, diff, trial)), nlow.eq(nlow << 1),
                         q.eq(Cat(fits, q)), cnt.eq(cnt + 1)]
            with m.If(cnt == QBITS - 1):
                m.d.sync += [act.eq(0), rnd.eq(1)]
        with m.If(rnd):
            # ±((q + 1) >> 1) in one adder: −((q + 1) >> 1) = (~q + 1) >> 1; n = 0: f = 0.
            qx = Cat(q ^ neg.replicate(QBITS), neg).as_signed()
            m.d.sync += [d.f.eq(Mux(d.n == 0, 0, (qx + 1) >> 1)), rnd.eq(0)]
        with m.If(self.start | self.stop):
            m.d.sync += [act.eq(0), rnd.eq(0)]

    def _control(self, m, d):
        """Strobes: start/stop state, the commit of the pending outputs, overruns."""
        m.d.comb += [self.ready.eq(d.rdy), self.busy.eq(d.run)]
        go = Signal()
        with m.If(self.stop):
            m.d.sync += [self.active.eq(0), self.vd0.eq(0), self.ad0.eq(0),
                         d.run.eq(0), d.rdy.eq(0)]
        with m.Elif(self.start):
            m.d.comb += go.eq(1)
            m.d.sync += [self.active.eq(1), d.init.eq(1)]
        with m.Elif(self.step & d.rdy):
            m.d.comb += go.eq(1)
            m.d.sync += [self.qd0.eq(d.pqd), self.vd0.eq(d.pvd), self.ad0.eq(d.pad),
                         d.init.eq(0)]
        with m.Elif(self.step & self.active):
            with m.If(self.overruns != 0xFFFF):
                m.d.sync += self.overruns.eq(self.overruns + 1)
        with m.If(go):
            m.d.comb += d.pc_nxt.eq(0)
            m.d.sync += [d.run.eq(1), d.rdy.eq(0), d.ph.eq(0), d.i.eq(0)]
