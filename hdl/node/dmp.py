"""Joint-side DMP generator: one DOF of a discrete movement primitive, one step per strobe.

# Ref: Ijspeert, Nakanishi, Hoffmann, Pastor, Schaal, "Dynamical movement primitives", Neural
# Computation 25(2), 2013 (transformation and canonical systems); Liu et al., seeds/000
# eqs. 1–2, 5–6 (the float definition is master/dmp.py).

A sequential datapath: one signed 35×35 multiplier (four MULT18X18) shared by every product,
a restoring divider (one quotient bit per cycle) for ``f = Σψw / Σψ``, and an exp unit
``2^(−φ)`` — a 257-entry table of ``2^(−j/256)`` in block RAM, linear interpolation on the
multiplier, then a rounding shift by the integer part as a second product with a one-hot
operand — used for the phase ``s = 2^(−φ)`` (the accumulated exponent, not a product of
decays) and for every Gaussian. Parameters live in one block RAM (weights, centres, inverse
widths, and the scalars used only as operands, at their register addresses) and registers (the
scalars needed at a strobe or in a computation's first cycle). The arithmetic is
specified bit for bit by :mod:`.dmp_ref`, the register map and formats by
:mod:`mrm_cosim.protocol.dmp`; docs/dmp.md "The joint-side generator".

Double buffering: a computation fills the pending outputs; the ``step`` strobe copies them to
``qd0, vd0, ad0`` (visible the cycle after the strobe) and starts the next one.
"""

from contextlib import contextmanager
from types import SimpleNamespace

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out
from amaranth.utils import bits_for

from mrm_cosim.protocol.dmp import (EXP_BITS, EXP_TABLE, FLAG_GOAL_SCALING, MAX_BASIS,
                                    MUL_WIDTH, N_SCALARS, PHI_FRAC, PHI_MAX, PHI_WIDTH, Reg,
                                    addr_width, check_max_basis)
from mrm_cosim.protocol.fixed import WORD

__all__ = ["DmpGenerator"]

_IN_MEMORY = (Reg.ALPHA, Reg.ALPHA_BETA, Reg.PHASE_RATE, Reg.AMPLITUDE, Reg.RADC)
QBITS = 34      # quotient bits of the divider: |f| ≤ max|w| bounds q = |num|·2^10/den < 2^34


def _rs(v, n):
    """Round half up and shift right by ``n`` (arithmetic for signed values)."""
    return (v + (1 << (n - 1))) >> n


def _sat(v, width):
    lo, hi = -(1 << (width - 1)), (1 << (width - 1)) - 1
    return Mux(v > hi, hi, Mux(v < lo, lo, v))


def _over(v, width):
    """Whether the non-negative value ``v`` is ``2^width`` or more (its high bits)."""
    v = Value.cast(v)
    return v[width:].any() if len(v) > width else C(0, 1)


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
        # Words used at any time or in the first cycle of a computation are registers; the
        # others (_IN_MEMORY) are read from the parameter memory in the cycle before their
        # product is issued (a wait state of the previous one), so they share the
        # multiplier operand's memory input instead of one multiplexer input each.
        d.reg = {r: Signal(signed(WORD), name=f"r_{r.name.lower()}") for r in Reg
                 if r != Reg.N_BASIS and r not in _IN_MEMORY}
        d.n = Signal(range(mb + 1))
        m.submodules.params = params = Memory(shape=signed(WORD), depth=N_SCALARS + 3 * mb,
                                              init=[])
        m.submodules.table = table = Memory(shape=unsigned(31), depth=len(EXP_TABLE),
                                            init=EXP_TABLE)
        d.rd = self._rd = params.read_port()
        d.trd = table.read_port()
        self._host(m, params.write_port(), d)

        d.a = Signal(signed(MUL_WIDTH))
        d.b = Signal(signed(MUL_WIDTH))
        d.rc = Signal(unsigned(32))          # rounding constant of the product's one use
        d.p = Signal(signed(2 * MUL_WIDTH))
        m.d.sync += d.p.eq(d.a * d.b + d.rc)

        den_w = 29 + bits_for(mb)
        for name, shape in (("gl", signed(WORD)), ("itl", signed(WORD)), ("k", signed(35)),
                            ("dphi", signed(48)), ("phi", unsigned(PHI_WIDTH)),
                            ("x", signed(40)), ("v", signed(35)), ("s", signed(WORD)),
                            ("cc", signed(WORD)), ("wl", signed(WORD)), ("pass2", 1),
                            ("umin", unsigned(2 * MUL_WIDTH)),
                            ("psi", unsigned(29)), ("num", signed(den_w + 25)),
                            ("den", unsigned(den_w)), ("rem", unsigned(den_w + 1)),
                            ("nlow", unsigned(QBITS)), ("q", unsigned(QBITS)), ("neg", 1),
                            ("f", signed(QBITS)), ("force", signed(40)), ("t1", signed(48)),
                            ("vdot", signed(35)), ("ein", unsigned(PHI_WIDTH)),
                            ("eout", unsigned(29)), ("t0", unsigned(31)),
                            ("ret", 1), ("i", range(mb)), ("cnt", range(QBITS)),
                            ("pqd", signed(WORD)), ("pvd", signed(WORD)),
                            ("pad", signed(WORD))):
            setattr(d, name, Signal(shape, name=name))

        with m.FSM() as fsm:
            self._prologue(m, d)
            self._exp(m, d)
            self._basis(m, d)
            self._divide(m, d)
            self._forcing(m, d)
            self._outputs(m, d)
        self._control(m, d, fsm)
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
                for r, sig in d.reg.items():
                    with m.Case(r):
                        m.d.sync += sig.eq(data)

    @contextmanager
    def _state(self, m, name):
        """An FSM state that stop (to Idle) and start (to Latch) override."""
        with m.State(name):
            yield
            with m.If(self.stop):
                m.next = "Idle"
            with m.Elif(self.start):
                m.next = "Latch"

    def _wait(self, m, name, nxt, read=None):
        """A cycle for the multiplier's product register; ``read``: a scalar in the parameter
        memory that the next state takes from its read port."""
        with self._state(m, name):
            if read is not None:
                m.d.comb += self._rd.addr.eq(read)
            m.next = nxt

    def _mul(self, m, d, a, b, shift=0):
        """Issue ``a·b``; ``d.p >> shift`` two cycles later is ``rs(a·b, shift)`` (the half-LSB
        is added in the multiplier, so each rounding point costs no adder)."""
        m.d.sync += [d.a.eq(a), d.b.eq(b), d.rc.eq((1 << (shift - 1)) if shift else 0)]

    def _prologue(self, m, d):
        with self._state(m, "Idle"):
            pass
        with self._state(m, "Ready"):
            with m.If(self.step & ~self.start & ~self.stop):
                m.d.sync += [self.qd0.eq(d.pqd), self.vd0.eq(d.pvd), self.ad0.eq(d.pad)]
                m.next = "Latch"
        with self._state(m, "Latch"):
            m.d.sync += [d.gl.eq(d.reg[Reg.GOAL]), d.itl.eq(d.reg[Reg.INVTAU])]
            self._mul(m, d, d.reg[Reg.DT], d.reg[Reg.INVTAU], 12)
            m.next = "K-Wait"
        self._wait(m, "K-Wait", "K", Reg.PHASE_RATE)
        with self._state(m, "K"):
            k = d.p >> 12
            m.d.sync += d.k.eq(k)
            self._mul(m, d, k, d.rd.data, 14)
            m.next = "Dphi-Wait"
        self._wait(m, "Dphi-Wait", "Dphi")
        with self._state(m, "Dphi"):
            m.d.sync += [d.dphi.eq(d.p >> 14), d.ein.eq(d.phi), d.ret.eq(0)]
            m.next = "Exp-Table"
        with self._state(m, "Phase"):
            m.d.sync += [d.s.eq(_rs(d.eout, 6)), d.i.eq(0), d.num.eq(0), d.den.eq(0),
                         d.pass2.eq(0)]
            with m.If(d.n == 0):
                m.next = "Div-Init"
            with m.Else():
                m.next = "Basis-Centre"

    def _exp(self, m, d):
        """``eout = 2^(−ein)``: table, interpolation on the multiplier, rounding shift."""
        j = d.ein[PHI_FRAC - EXP_BITS:PHI_FRAC]
        r = d.ein[PHI_FRAC - EXP_BITS - 24:PHI_FRAC - EXP_BITS]
        n = d.ein[PHI_FRAC:]
        with self._state(m, "Exp-Table"):
            m.d.comb += d.trd.addr.eq(j)
            m.next = "Exp-Next"
        with self._state(m, "Exp-Next"):
            m.d.comb += d.trd.addr.eq(j + 1)
            m.d.sync += d.t0.eq(d.trd.data)
            m.next = "Exp-Slope"
        with self._state(m, "Exp-Slope"):
            self._mul(m, d, d.t0 - d.trd.data, r, 24)
            m.next = "Exp-Wait"
        self._wait(m, "Exp-Wait", "Exp-Interp")
        with self._state(m, "Exp-Interp"):
            # rs(y, n + 2) = rs(y · 2^(30 − n), 32) for n ≤ 30: the shift is a product, with
            # a one-hot operand, not a 31-bit barrel shifter.
            scale = Mux(n >= 31, 0, C(1, 31) << (30 - n[:5]).as_unsigned())
            self._mul(m, d, d.t0 - (d.p >> 24), scale, 32)
            m.next = "Exp-Shift-Wait"
        self._wait(m, "Exp-Shift-Wait", "Exp-Shift")
        with self._state(m, "Exp-Shift"):
            m.d.sync += d.eout.eq(d.p >> 32)
            with m.If(d.ret):
                m.next = "Basis-Psi"
            with m.Else():
                m.next = "Phase"

    def _basis(self, m, d):
        mb = self._mb
        with self._state(m, "Basis-Centre"):
            m.d.comb += d.rd.addr.eq(N_SCALARS + mb + d.i)
            m.next = "Basis-Width"
        with self._state(m, "Basis-Width"):
            m.d.comb += d.rd.addr.eq(N_SCALARS + 2 * mb + d.i)
            m.d.sync += d.cc.eq(d.rd.data)
            m.next = "Basis-Diff"
        with self._state(m, "Basis-Diff"):
            m.d.comb += d.rd.addr.eq(N_SCALARS + d.i)
            self._mul(m, d, d.s - d.cc, d.rd.data, 14)
            m.next = "Basis-Weight"
        with self._state(m, "Basis-Weight"):
            m.d.sync += d.wl.eq(d.rd.data)
            m.next = "Basis-Square"
        with self._state(m, "Basis-Square"):
            t = d.p >> 14
            self._mul(m, d, t, t)
            m.next = "Basis-Square-Wait"
        self._wait(m, "Basis-Square-Wait", "Basis-Exp")
        with self._state(m, "Basis-Exp"):
            # One subtractor: its borrow is u < u_min (first pass), its value u − u_min ≥ 0
            # (second pass).
            u = d.p.as_unsigned()
            diff = u - d.umin
            with m.If(d.pass2):
                m.d.sync += [d.ein.eq(Mux(_over(diff[:-1], PHI_WIDTH), PHI_MAX, diff[:-1])),
                             d.ret.eq(1)]
                m.next = "Exp-Table"
            with m.Else():
                with m.If(diff[-1] | (d.i == 0)):
                    m.d.sync += d.umin.eq(u)
                m.d.sync += d.i.eq(d.i + 1)
                with m.If(d.i == d.n - 1):
                    m.d.sync += [d.i.eq(0), d.pass2.eq(1)]
                m.next = "Basis-Centre"
        with self._state(m, "Basis-Psi"):
            m.d.sync += d.psi.eq(d.eout)
            self._mul(m, d, d.eout, d.wl)
            m.next = "Basis-Psi-Wait"
        with self._state(m, "Basis-Psi-Wait"):
            m.d.sync += d.den.eq(d.den + d.psi)
            m.next = "Basis-Acc"
        with self._state(m, "Basis-Acc"):
            m.d.sync += [d.num.eq(d.num + d.p), d.i.eq(d.i + 1)]
            with m.If(d.i == d.n - 1):
                m.next = "Div-Init"
            with m.Else():
                m.next = "Basis-Centre"

    def _divide(self, m, d):
        """``q = floor(|num|·2^10 / den)``, one bit per cycle; ``f`` rounded from it."""
        with self._state(m, "Div-Init"):
            mag = Cat(C(0, 10), Mux(d.num < 0, -d.num, d.num).as_unsigned())
            m.d.sync += [d.rem.eq(mag[QBITS:]), d.nlow.eq(mag[:QBITS]), d.q.eq(0),
                         d.neg.eq(d.num < 0), d.cnt.eq(0)]
            m.next = "Div-Step"
        with self._state(m, "Div-Step"):
            trial = Cat(d.nlow[-1], d.rem)
            diff = trial - d.den                    # one subtractor: its borrow is the compare
            fits = ~diff[-1]
            m.d.sync += [d.rem.eq(Mux(fits, diff, trial)), d.nlow.eq(d.nlow << 1),
                         d.q.eq(Cat(fits, d.q)), d.cnt.eq(d.cnt + 1)]
            with m.If(d.cnt == QBITS - 1):
                m.next = "Div-Round"
        with self._state(m, "Div-Round"):
            # ±((q + 1) >> 1) in one adder: −((q + 1) >> 1) = (~q + 1) >> 1.
            qx = Cat(d.q ^ d.neg.replicate(QBITS), d.neg).as_signed()
            m.d.sync += d.f.eq(Mux(d.den == 0, 0, (qx + 1) >> 1))  # den = 0: n = 0
            m.next = "Force-Gate"

    def _forcing(self, m, d):
        """``F = s f A`` and ``v̇ = α β (g − x) − α v + F``."""
        gs = (d.reg[Reg.FLAGS] & FLAG_GOAL_SCALING) != 0
        amp = Mux(gs, d.gl - d.reg[Reg.X0], d.rd.data)
        with self._state(m, "Force-Gate"):
            self._mul(m, d, d.s, d.f, 22)
            m.next = "Force-Gate-Wait"
        self._wait(m, "Force-Gate-Wait", "Force-Scale", Reg.AMPLITUDE)
        with self._state(m, "Force-Scale"):
            self._mul(m, d, (d.p >> 22), amp, 20)
            m.next = "Force-Scale-Wait"
        self._wait(m, "Force-Scale-Wait", "Spring", Reg.ALPHA_BETA)
        with self._state(m, "Spring"):
            m.d.sync += d.force.eq(d.p >> 20)
            self._mul(m, d, _rs((d.gl << 12) - d.x, 8), d.rd.data, 12)
            m.next = "Spring-Wait"
        self._wait(m, "Spring-Wait", "Damper", Reg.ALPHA)
        with self._state(m, "Damper"):
            m.d.sync += d.t1.eq(d.p >> 12)
            self._mul(m, d, d.v, d.rd.data, 20)
            m.next = "Damper-Wait"
        self._wait(m, "Damper-Wait", "Accel")
        with self._state(m, "Accel"):
            vdot = _sat(d.t1 - (d.p >> 20) + d.force, 35)
            m.d.sync += d.vdot.eq(vdot)
            self._mul(m, d, vdot, d.itl, 20)
            m.next = "Accel-Wait"
        self._wait(m, "Accel-Wait", "Accel-Tau2")

    def _outputs(self, m, d):
        """Pending outputs from (x, v, v̇), then the state update."""
        radc = d.rd.data
        # One saturation of the product serves the chain: sat35(p >> 20) or sat35(p >> 22);
        # the output words saturate it again to 24 bits, which equals sat24(p >> 26) and
        # sat24(p >> 25) (both clamps are monotone and the 35-bit range covers the 24-bit).
        sel22 = Signal()
        zs = _sat(Mux(sel22, d.p >> 22, d.p >> 20), 35)
        with self._state(m, "Accel-Tau2"):
            self._mul(m, d, zs, d.itl, 20)
            m.next = "Accel-Tau2-Wait"
        self._wait(m, "Accel-Tau2-Wait", "Accel-Out", Reg.RADC)
        with self._state(m, "Accel-Out"):
            self._mul(m, d, zs, radc, 26)
            m.next = "Accel-Out-Wait"
        self._wait(m, "Accel-Out-Wait", "Vel-Tau")
        with self._state(m, "Vel-Tau"):
            m.d.sync += d.pad.eq(_sat(zs >> 6, WORD))
            self._mul(m, d, d.v, d.itl, 22)
            m.next = "Vel-Tau-Wait"
        self._wait(m, "Vel-Tau-Wait", "Vel-Out", Reg.RADC)
        with self._state(m, "Vel-Out"):
            m.d.comb += sel22.eq(1)
            self._mul(m, d, zs, radc, 25)
            m.next = "Vel-Out-Wait"
        self._wait(m, "Vel-Out-Wait", "Update-V")
        with self._state(m, "Update-V"):
            m.d.comb += sel22.eq(1)
            m.d.sync += [d.pvd.eq(_sat(zs >> 3, WORD)),
                         d.pqd.eq(_sat(_rs(d.x, 12), WORD))]
            self._mul(m, d, d.k, d.vdot, 32)
            m.next = "Update-V-Wait"
        self._wait(m, "Update-V-Wait", "Update-X")
        with self._state(m, "Update-X"):
            v = _sat(d.v + (d.p >> 32), 35)
            m.d.sync += d.v.eq(v)
            self._mul(m, d, d.k, v, 32)
            m.next = "Update-X-Wait"
        self._wait(m, "Update-X-Wait", "Update-Phase")
        with self._state(m, "Update-Phase"):
            phi = d.phi + d.dphi
            m.d.sync += [d.x.eq(_sat(d.x + (d.p >> 32), 40)),
                         d.phi.eq(Mux(phi[-1], 0, Mux(_over(phi, PHI_WIDTH), PHI_MAX, phi)))]
            m.next = "Ready"

    def _control(self, m, d, fsm):
        """Strobes outside the sequence: start/stop state, outputs on stop, overruns."""
        ready = fsm.ongoing("Ready")
        m.d.comb += [
            self.ready.eq(ready),
            self.busy.eq(~ready & ~fsm.ongoing("Idle")),
        ]
        with m.If(self.stop):
            m.d.sync += [self.active.eq(0), self.vd0.eq(0), self.ad0.eq(0)]
        with m.Elif(self.start):
            m.d.sync += [self.active.eq(1), d.x.eq(d.reg[Reg.X0] << 12),
                         d.v.eq(d.reg[Reg.V0] << 6), d.phi.eq(0)]
        with m.Elif(self.step & self.active & ~ready):
            with m.If(self.overruns != 0xFFFF):
                m.d.sync += self.overruns.eq(self.overruns + 1)
