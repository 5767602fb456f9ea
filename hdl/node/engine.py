"""Microcoded multiply-accumulate engine: one shared 24×24 multiplier sequenced from a ROM.

This is how the node computes without a divider and with few multipliers, as a Virtex-II design
would (DESIGN.md "Slave node"): a program of multiply-accumulate statements
(:mod:`mrm_cosim.protocol.isa`), scheduled at build time, runs one term per cycle through a
seven-stage pipeline::

    R   instruction from ROM; register-file (or input-port) read of operands a, b
    O   operands registered (off the block RAM's slow output)
    M   four partial products of the 24×24 signed product (17-bit unsigned / 7-bit signed
        halves: each fits one MULT18X18); the operands kept for MIN/MAX
    P   partial products summed (or min/max of the operands), shifted left by ``pshift``
    A   accumulate or subtract (``first`` restarts the sum from the rounding constant
        ``2^(oshift-1)``), ACC_WIDTH bits, exact
    W1  take bits ``oshift .. oshift+23`` (the sum rounded half up), saturate (or wrap)
    W2  write the register file or an output register; MARK / END pulse ``mark`` / ``done``

A result is readable by a term issued :data:`~mrm_cosim.protocol.isa.LATENCY` cycles after the
last term that produced it; the scheduler guarantees that. The product and output shifters are
built for the shift amounts the program uses only (a handful), not as full barrel shifters. The
host port reads the register file at any time (one cycle of latency) and writes it while the
engine is idle. Timing: a ``start`` strobe in cycle 0 gives ``done`` in cycle
:meth:`Microcode.cycles <mrm_cosim.protocol.isa.Microcode.cycles>`.
"""

from amaranth import *
from amaranth.lib import data, wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from mrm_cosim.protocol.fixed import WORD, WORD_MAX, WORD_MIN
from mrm_cosim.protocol.isa import (ACC_WIDTH, ADDR_BITS, INSTR_BITS, INSTR_FIELDS, IO_BASE,
                                    Microcode, Op, mem_depth)

__all__ = ["MacEngine", "InstrLayout"]


InstrLayout = data.StructLayout({name: width for name, width in INSTR_FIELDS})

_NOP, _MAC, _MIN, _MAX, _MARK, _END = (int(op) for op in (Op.NOP, Op.MAC, Op.MIN, Op.MAX,
                                                          Op.MARK, Op.END))


def _ctl_layout():
    """An instruction travelling down the pipeline, and whether it is one."""
    return data.StructLayout({"valid": 1, "ins": InstrLayout})


class MacEngine(wiring.Component):
    """The engine running one compiled program.

    Parameters
    ----------
    microcode : Microcode

    Attributes
    ----------
    start : In(1)
        Strobe: run from ``entry`` (ignored while busy).
    entry : In(ROM address)
        Start address, from ``microcode.entries``.
    busy : Out(1)
        From the cycle after ``start`` until ``done``.
    mark, done : Out(1)
        One-cycle pulses when a MARK / the END reaches write-back (earlier writes landed).
    inputs : In(ArrayLayout(signed(24), n))
        Input ports, read by the program at ``IO_BASE + k``; hold them while busy.
    outputs : Out(ArrayLayout(signed(24), n))
        Output registers, written by the program at ``IO_BASE + k``.
    host_addr, host_wdata, host_we : In
        Host write port of the register file (effective only while idle).
    host_rdata : Out(signed(24))
        Register-file word at the previous cycle's ``host_addr``.
    """

    def __init__(self, microcode: Microcode):
        if not isinstance(microcode, Microcode):
            raise TypeError(f"microcode must be a Microcode, not {microcode!r}")
        self._mc = microcode
        self._rom_depth = max(2, len(microcode.instrs))
        self._n_in = max(1, sum(r.kind == "input" for r in microcode.regs.values()))
        self._n_out = max(1, sum(r.kind == "output" for r in microcode.regs.values()))
        macs = [i for i in microcode.instrs if i.op == Op.MAC]
        self._pshifts = sorted({i.pshift for i in macs} | {0})
        self._oshifts = sorted({i.oshift for i in macs if i.last} | {0})
        super().__init__({
            "start":      In(1),
            "entry":      In(range(self._rom_depth)),
            "busy":       Out(1),
            "mark":       Out(1),
            "done":       Out(1),
            "inputs":     In(data.ArrayLayout(signed(WORD), self._n_in)),
            "outputs":    Out(data.ArrayLayout(signed(WORD), self._n_out)),
            "host_addr":  In(ADDR_BITS),
            "host_wdata": In(signed(WORD)),
            "host_we":    In(1),
            "host_rdata": Out(signed(WORD)),
        })

    @property
    def microcode(self) -> Microcode:
        return self._mc

    def elaborate(self, platform):
        m = Module()
        mc = self._mc

        m.submodules.rom = rom = Memory(shape=INSTR_BITS, depth=self._rom_depth,
                                        init=mc.words + [0] * (self._rom_depth - len(mc.words)))
        rom_rd = rom.read_port()
        depth = mem_depth(mc.depth)
        abits = ceil_log2(depth) if depth > 1 else 1
        m.submodules.regfile = regfile = Memory(shape=signed(WORD), depth=max(2, depth),
                                                init=mc.init + [0] * (max(2, depth) - len(mc.init)))
        rd_a = regfile.read_port()
        rd_b = regfile.read_port()
        rd_h = regfile.read_port()
        wr   = regfile.write_port()
        ins, f_valid = self._fetch(m, rom_rd)
        c1o, opa, opb = self._operands(m, ins, f_valid, rd_a, rd_b, rd_h, abits)
        c5, wb_data = self._datapath(m, c1o, opa, opb)
        self._write_back(m, c5, wb_data, wr, abits)
        return m

    def _fetch(self, m, rom_rd):
        """Program counter and ROM read; returns the instruction and whether it is valid."""
        # --- fetch ---------------------------------------------------------------------------
        pc       = Signal(range(self._rom_depth))
        fetching = Signal()
        f_valid  = Signal()
        ins      = Signal(InstrLayout)
        is_end   = Signal()
        m.d.comb += [
            rom_rd.addr.eq(pc),
            ins.eq(rom_rd.data),
            is_end.eq(f_valid & (ins.op == _END)),
        ]
        m.d.sync += f_valid.eq(fetching & ~is_end)
        with m.If(self.start & ~self.busy):
            m.d.sync += [
                pc.eq(self.entry),
                fetching.eq(1),
                self.busy.eq(1),
            ]
        with m.Elif(is_end):
            m.d.sync += fetching.eq(0)
        with m.Elif(fetching):
            m.d.sync += pc.eq(pc + 1)
        return ins, f_valid

    def _operands(self, m, ins, f_valid, rd_a, rd_b, rd_h, abits):
        """Stages R and O (and the host read port); returns O's instruction and operands."""
        # --- R: operand read -----------------------------------------------------------------
        c1 = Signal(_ctl_layout())
        io_a = Signal(signed(WORD))
        io_b = Signal(signed(WORD))
        sel_a_io = Signal()
        sel_b_io = Signal()
        inputs = Array(self.inputs[k] for k in range(self._n_in))
        m.d.comb += [
            rd_a.addr.eq(ins.a[:abits]),
            rd_b.addr.eq(ins.b[:abits]),
            rd_h.addr.eq(self.host_addr[:abits]),
            self.host_rdata.eq(rd_h.data),
        ]
        m.d.sync += [
            c1.valid.eq(f_valid),
            c1.ins.eq(ins),
            sel_a_io.eq(ins.a >= IO_BASE),
            sel_b_io.eq(ins.b >= IO_BASE),
            io_a.eq(inputs[(ins.a - IO_BASE)[:4]]),
            io_b.eq(inputs[(ins.b - IO_BASE)[:4]]),
        ]

        # --- O: operands registered (off the block RAM's slow output) ---------------------------
        opa = Signal(signed(WORD))
        opb = Signal(signed(WORD))
        c1o = Signal(_ctl_layout())
        m.d.sync += [
            c1o.eq(c1),
            opa.eq(Mux(sel_a_io, io_a, rd_a.data)),
            opb.eq(Mux(sel_b_io, io_b, rd_b.data)),
        ]
        return c1o, opa, opb

    def _datapath(self, m, c1o, opa, opb):
        """Stages M, P, A and W1; returns W1's instruction and the word to write."""
        # --- M: partial products -------------------------------------------------------------
        pp_ll = Signal(34)
        pp_lh = Signal(signed(25))
        pp_hl = Signal(signed(25))
        pp_hh = Signal(signed(14))
        opa2  = Signal(signed(WORD))
        opb2  = Signal(signed(WORD))
        c2 = Signal(_ctl_layout())
        a_lo, a_hi = opa[:17], opa[17:].as_signed()
        b_lo, b_hi = opb[:17], opb[17:].as_signed()
        m.d.sync += [
            c2.eq(c1o),
            pp_ll.eq(a_lo * b_lo),
            pp_lh.eq(a_lo * b_hi),
            pp_hl.eq(a_hi * b_lo),
            pp_hh.eq(a_hi * b_hi),
            opa2.eq(opa),               # MIN/MAX compare one stage later, off the RAM's output
            opb2.eq(opb),
        ]
        sel = Signal(signed(WORD))
        m.d.comb += sel.eq(Mux((opa2 < opb2) ^ (c2.ins.op == _MAX), opa2, opb2))

        # --- P: product, alignment -----------------------------------------------------------
        prod = Signal(signed(2 * WORD))
        term = Signal(signed(ACC_WIDTH))
        c3 = Signal(_ctl_layout())
        is_mac2 = c2.ins.op == _MAC
        m.d.comb += prod.eq(Mux(is_mac2,
                                (pp_hh << 34) + ((pp_lh + pp_hl) << 17) + pp_ll,
                                sel))
        m.d.sync += c3.eq(c2)
        # Only the shifts the program uses are built (a few cases instead of a barrel shifter).
        with m.Switch(c2.ins.pshift):
            for v in self._pshifts:
                with m.Case(v):
                    m.d.sync += term.eq(prod << v)

        # --- A: accumulate; a statement starts from its rounding constant ------------------
        # (the compiler repeats a statement's oshift on all its terms), so W1 only slices.
        acc  = Signal(signed(ACC_WIDTH))
        half = Signal(ACC_WIDTH)
        base = Signal(signed(ACC_WIDTH))
        c4 = Signal(_ctl_layout())
        with m.Switch(c3.ins.oshift):
            for v in self._oshifts:
                with m.Case(v):
                    m.d.comb += half.eq((1 << v) >> 1)
        m.d.comb += base.eq(Mux(c3.ins.first, half, acc))
        flip = Signal(signed(ACC_WIDTH))
        m.d.comb += flip.eq(term ^ c3.ins.neg.replicate(ACC_WIDTH))
        m.d.sync += c4.eq(c3)
        with m.If(c3.valid & ((c3.ins.op == _MAC) | (c3.ins.op == _MIN) | (c3.ins.op == _MAX))):
            m.d.sync += acc.eq(base + flip + c3.ins.neg)

        # --- W1: shift (a slice per used oshift) and saturate --------------------------------
        wb_data = Signal(signed(WORD))
        window  = Signal(WORD)
        fits    = Signal()
        c5 = Signal(_ctl_layout())
        with m.Switch(c4.ins.oshift):
            for v in self._oshifts:
                with m.Case(v):
                    upper = acc[v + WORD - 1:]
                    m.d.comb += [
                        window.eq(acc[v:v + WORD]),
                        fits.eq((upper == 0) | (upper == (1 << len(upper)) - 1)),
                    ]
        m.d.sync += c5.eq(c4)
        with m.If(c4.ins.wrap | fits):
            m.d.sync += wb_data.eq(window)
        with m.Elif(acc[-1]):
            m.d.sync += wb_data.eq(WORD_MIN)
        with m.Else():
            m.d.sync += wb_data.eq(WORD_MAX)
        return c5, wb_data

    def _write_back(self, m, c5, wb_data, wr, abits):
        """Stage W2: the register file (or the host write while idle), the outputs, MARK and
        END, ``busy`` falling."""
        # --- W2: write back ------------------------------------------------------------------
        writes = c5.valid & c5.ins.last & ((c5.ins.op == _MAC) | (c5.ins.op == _MIN) |
                                            (c5.ins.op == _MAX))
        to_io = c5.ins.dst >= IO_BASE
        m.d.comb += [
            self.mark.eq(c5.valid & (c5.ins.op == _MARK)),
            self.done.eq(c5.valid & (c5.ins.op == _END)),
        ]
        with m.If(self.done):
            m.d.sync += self.busy.eq(0)
        with m.If(writes & ~to_io):
            m.d.comb += [
                wr.addr.eq(c5.ins.dst[:abits]),
                wr.data.eq(wb_data),
                wr.en.eq(1),
            ]
        with m.Elif(self.host_we & ~self.busy):
            m.d.comb += [
                wr.addr.eq(self.host_addr[:abits]),
                wr.data.eq(self.host_wdata),
                wr.en.eq(1),
            ]
        for k in range(self._n_out):
            with m.If(writes & to_io & (c5.ins.dst[:4] == k)):
                m.d.sync += self.outputs[k].eq(wb_data)
