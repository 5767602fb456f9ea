# amaranth: UnusedElaboratable=no
"""The multiply-accumulate engine: RTL == instruction-level model == statement semantics."""

import dataclasses

import numpy as np
import pytest
from amaranth.sim import Simulator
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mrm_cosim.hdl.node.engine import MacEngine
from mrm_cosim.hdl.node.engine_ref import EngineModel, run_statements
from mrm_cosim.protocol.fixed import WORD_MAX, WORD_MIN, Fmt, round_shift, saturate
from mrm_cosim.protocol.isa import (IO_BASE, LATENCY, Instr, Op, Program, T, decode, encode,
                                    mem_depth)

from mrm_cosim.testbench import run_simulation


def run_engine(mc, entries, inputs=(), mem=None, host_writes=(), name="engine"):
    """Run ``entries`` one after the other on the RTL engine.

    Returns (register file, outputs, list of (cycles to done, mark cycles) per run). The
    register file starts as ``mem`` (default: the program's init), then ``host_writes``
    ((addr, value) pairs) go through the host port.
    """
    if mem is not None:
        mc = dataclasses.replace(mc, init=list(mem))
    dut = MacEngine(mc)
    depth = mem_depth(mc.depth)
    result = {}

    async def tb(ctx):
        for addr, value in host_writes:
            ctx.set(dut.host_addr, addr)
            ctx.set(dut.host_wdata, value)
            ctx.set(dut.host_we, 1)
            await ctx.tick()
        ctx.set(dut.host_we, 0)
        for k, v in enumerate(inputs):
            ctx.set(dut.inputs[k], v)
        runs = []
        for entry in entries:
            ctx.set(dut.entry, mc.entries[entry])
            ctx.set(dut.start, 1)
            await ctx.tick()
            ctx.set(dut.start, 0)
            cycles, marks = 0, []
            while True:
                cycles += 1
                if ctx.get(dut.mark):
                    marks.append(cycles)
                if ctx.get(dut.done):
                    break
                assert ctx.get(dut.busy)
                assert cycles < 10 * len(mc.instrs) + 50, "engine never finished"
                await ctx.tick()
            await ctx.tick()
            assert not ctx.get(dut.busy)
            runs.append((cycles, marks))
        regs = []
        for addr in range(depth):
            ctx.set(dut.host_addr, addr)
            await ctx.tick()
            regs.append(ctx.get(dut.host_rdata))
        result["mem"] = regs
        result["out"] = [ctx.get(dut.outputs[k]) for k in range(len(dut.outputs))]
        result["runs"] = runs

    sim = Simulator(dut)
    sim.add_clock(1e-6)
    sim.add_testbench(tb)
    run_simulation(sim, name)
    return result["mem"], result["out"], result["runs"]


def _random_program(rng, n_stmts=12, n_regs=10, n_in=3, n_out=2, lsbs=(-20, -14, -8, 0)):
    p = Program("random", depth=64)
    names = []
    for k in range(n_regs):
        names.append(p.reg(f"r{k}", Fmt(f"F{k}", int(rng.choice(lsbs)), "1"), "state",
                           init=int(rng.integers(WORD_MIN, WORD_MAX + 1))))
    ins = [p.reg(f"in{k}", Fmt(f"I{k}", int(rng.choice(lsbs)), "1"), "input")
           for k in range(n_in)]
    outs = [p.reg(f"out{k}", p.regs[names[k]].fmt, "output") for k in range(n_out)]
    p.entry("main")
    readable = names + ins
    for _ in range(n_stmts):
        kind = rng.choice(["mac", "mac", "mac", "min", "max"])
        if kind == "mac":
            terms = []
            for _ in range(int(rng.integers(1, 6))):
                a = str(rng.choice(readable))
                b = None if rng.random() < 0.3 else str(rng.choice(readable))
                t = T(a, b)
                terms.append(-t if rng.random() < 0.5 else t)
            dst = str(rng.choice(names + outs))
            try:
                p.mac(dst, terms, wrap=bool(rng.random() < 0.2))
            except ValueError:
                continue
        else:
            a = str(rng.choice(names))
            same = [n for n in names if p.regs[n].fmt.lsb == p.regs[a].fmt.lsb]
            getattr(p, kind)(str(rng.choice(same)), a, str(rng.choice(same)))
        if rng.random() < 0.1:
            p.mark()
    p.end()
    return p.compile()


def test_instruction_encoding_round_trips():
    ins = Instr(Op.MAC, a=511, b=3, neg=True, first=True, last=True, pshift=15, dst=7,
                oshift=63, wrap=True)
    assert decode(encode(ins)) == ins
    with pytest.raises(ValueError, match="does not fit"):
        encode(Instr(Op.MAC, pshift=16))


def test_statement_semantics_round_half_up_and_saturate():
    p = Program("t")
    x = p.reg("x", Fmt("X", -4, "1"), "state")
    y = p.reg("y", Fmt("Y", -2, "1"), "state")
    z = p.reg("z", Fmt("Z", 0, "1"), "state")
    p.entry("main")
    p.mac(y, [T(x)])           # 4 fractional bits onto 2: ties go up
    p.mac(z, [T(x, x)])        # x² saturates
    p.end()
    mc = p.compile()
    for xv, yv in [(2, 1), (-2, 0), (6, 2), (-6, -1), (1, 0), (-1, 0)]:
        vals = run_statements(mc, "main", {"x": xv})
        assert vals["y"] == yv == round_shift(xv, 2)
    vals = run_statements(mc, "main", {"x": WORD_MIN})
    assert vals["z"] == saturate(WORD_MIN * WORD_MIN >> 8) == WORD_MAX


@pytest.mark.parametrize("seed", range(6))
def test_random_programs_rtl_equals_models(seed):
    rng = np.random.default_rng(seed)
    mc = _random_program(rng)
    inputs = [int(v) for v in rng.integers(WORD_MIN, WORD_MAX + 1, 3)]
    model = EngineModel(mc)
    marks = model.run("main", inputs)
    # Statement semantics: same register file as the instruction-level model.
    values = {r.name: r.init for r in mc.regs.values() if r.kind == "state"}
    values = run_statements(mc, "main", values,
                            {f"in{k}": v for k, v in enumerate(inputs)})
    for r in mc.regs.values():
        if r.kind == "state":
            assert model.mem[r.addr] == values[r.name], r.name
        if r.kind == "output" and r.name in values:
            assert model.outputs[r.addr - IO_BASE] == values[r.name], r.name
    mem, out, runs = run_engine(mc, ["main"], inputs, name=f"engine_random{seed}")
    assert mem == model.mem
    assert out == model.outputs[:len(out)]
    cycles, mark_cycles = runs[0]
    assert cycles == mc.cycles("main")
    assert mark_cycles == [a - mc.entries["main"] + 1 + LATENCY for a in marks]


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(a=st.integers(WORD_MIN, WORD_MAX), b=st.integers(WORD_MIN, WORD_MAX),
       c=st.integers(WORD_MIN, WORD_MAX), d=st.integers(WORD_MIN, WORD_MAX))
def test_products_at_the_word_limits(a, b, c, d):
    """Dot products of extreme words through every shift and both write-back modes."""
    p = Program("limits")
    f = [p.reg(n, Fmt(n, lsb, "1"), "state") for n, lsb in
         (("a", -8), ("b", -8), ("c", -4), ("d", -2))]
    outs = [p.reg(f"o{k}", Fmt(f"O{k}", lsb, "1"), "state") for k, lsb in
            enumerate((-16, -12, -8, -4, 0, 8))]
    p.entry("main")
    for k, o in enumerate(outs):
        p.mac(o, [T("a", "b"), -T("c", "d"), T("a", "c"), -T("b"), T("d", "d")], wrap=k % 2 == 1)
    p.min(f[0], "a", "b")
    p.max(f[1], "a", "b")
    p.end()
    mc = p.compile()
    init = list(mc.init)
    for name, v in zip("abcd", (a, b, c, d), strict=True):
        init[mc.addr(name)] = v
    model = EngineModel(mc, init)
    model.run("main")
    mem, _, _ = run_engine(mc, ["main"], mem=init, name="engine_limits")
    assert mem == model.mem


def test_host_port_writes_only_while_idle_and_back_to_back_runs():
    p = Program("host")
    p.reg("x", Fmt("X", 0, "1"), "state")
    p.reg("y", Fmt("Y", 0, "1"), "state")
    p.reg("q", Fmt("Q", 0, "1"), "output")
    p.entry("inc")
    p.mac("x", [T("x"), T("ONE0")])
    p.mac("y", [T("x", "x")])
    p.mac("q", [T("y")])
    p.end()
    p.entry("twice")
    p.mac("x", [T("x"), T("x")])
    p.end()
    mc = p.compile()
    mem, out, runs = run_engine(mc, ["inc", "inc", "twice", "inc"],
                                host_writes=[(mc.addr("x"), 5)], name="engine_host")
    x = ((5 + 1 + 1) * 2) + 1
    assert mem[mc.addr("x")] == x
    assert mem[mc.addr("y")] == x * x
    assert out[0] == x * x
    assert [r[0] for r in runs] == [mc.cycles(e) for e in ("inc", "inc", "twice", "inc")]


def test_scheduler_fills_latency_and_rejects_bad_programs():
    p = Program("chain")
    for n in "abc":
        p.reg(n, Fmt(n, 0, "1"), "state")
    p.entry("main")
    p.mac("b", [T("a", "a")])
    p.mac("c", [T("b", "b")])   # depends on b: NOPs in between
    p.end()
    mc = p.compile()
    ops = [i.op for i in mc.instrs]
    assert ops == [Op.MAC] + [Op.NOP] * (LATENCY - 1) + [Op.MAC, Op.END]
    with pytest.raises(ValueError, match="product shift"):
        q = Program("bad")
        q.reg("u", Fmt("U", -30, "1"), "state")
        q.reg("v", Fmt("V", 0, "1"), "state")
        q.mac("v", [T("u", "u"), T("v")])
        q.compile()
    with pytest.raises(ValueError, match="cannot be written"):
        Program("bad2").mac("ONE0", [T("ONE0")])
