# amaranth: UnusedElaboratable=no
"""DMP generator: RTL == bit-exact reference (outputs, cycles, strobes); reference vs float."""

import math
import re

import numpy as np
import pytest
from amaranth import Module, Signal, signed
from amaranth.back import rtlil
from amaranth.hdl import Fragment
from amaranth.sim import Simulator
from hypothesis import given, settings
from hypothesis import strategies as st

from mrm_cosim.errors import InputError
from mrm_cosim.hdl.node.dmp import QBITS, DmpGenerator, saturate_shifted
from mrm_cosim.hdl.node.dmp_ref import (CYCLES_FIXED, CYCLES_PER_BASIS, DmpGeneratorModel,
                                        exp2neg, step_cycles)
from mrm_cosim.hdl.node.dmp_ucode import (DIV_CYCLES, OP_CYCLES, RF_WIDTH, SHIFTS, Br, Sat,
                                          program, split_labels)
from mrm_cosim.hdl.tops import build_top
from mrm_cosim.master.dmp import learn_dmp
from mrm_cosim.protocol.dmp import (MAX_BASIS, PHI_MAX, PHI_WIDTH, STEP_CYCLES, DmpParams, Reg,
                                    centre_addr, decode_outputs, dmp_param_payloads,
                                    weight_addr, width_addr)
from mrm_cosim.protocol.fixed import WORD, round_shift, saturate
from mrm_cosim.protocol.regs import Bank, unpack_words
from mrm_cosim.testbench import run_simulation

CPR = 800_000
KC = CPR / (2 * math.pi)


def quintic(duration=1.0, q0=0.2, q1=1.2, dt=1e-3):
    u = np.linspace(0.0, 1.0, int(round(duration / dt)) + 1)
    return q0 + (q1 - q0) * (10 * u**3 - 15 * u**4 + 6 * u**5)


def path(duration=2.0, dt=1e-3):
    t = np.linspace(0.0, duration, int(round(duration / dt)) + 1)
    u = t / duration
    return 0.3 + 0.5 * np.sin(3 * np.pi * u) * u + 0.4 * u


def loop(duration=1.5, dt=1e-3):
    """A demo that ends where it starts: learned without goal scaling."""
    u = np.linspace(0.0, 1.0, int(round(duration / dt)) + 1)
    return -0.4 + 0.6 * np.sin(np.pi * u) ** 2


def params_of(dmp, **kw):
    return DmpParams.from_float(dmp.weights[0], dmp.centers, dmp.widths, dmp.alpha, dmp.beta,
                                dmp.alpha_s, dmp.tau, dmp.x0[0], dmp.g[0], dmp.xd0[0],
                                bool(dmp.goal_scaling[0]), **kw)


QUINTIC = learn_dmp(quintic(), 1e-3, 20)
PATH = learn_dmp(path(), 1e-3, 30)
LOOP = learn_dmp(loop(), 1e-3, 24)


# -- the RTL against the reference ---------------------------------------------------------

def run_rtl(dut, ops, n_cycles):
    """Drive ``ops`` = [(cycle, kind, arg)] (kind: write (addr, word), start, stop, step) and
    return, for every cycle with an op, the state the cycle after it:
    (qd0, vd0, ad0, active, ready, overruns)."""
    by_cycle = {}
    for cycle, kind, arg in ops:
        by_cycle.setdefault(cycle, []).append((kind, arg))
    seen = []

    async def tb(ctx):
        for c in range(n_cycles):
            todo = by_cycle.get(c, [])
            for kind, arg in todo:
                if kind == "write":
                    ctx.set(dut.host_addr, arg[0])
                    ctx.set(dut.host_data, arg[1])
                    ctx.set(dut.host_we, 1)
                else:
                    ctx.set(getattr(dut, kind), 1)
            await ctx.tick()
            for sig in (dut.host_we, dut.start, dut.stop, dut.step):
                ctx.set(sig, 0)
            if todo:
                seen.append((c, ctx.get(dut.qd0), ctx.get(dut.vd0), ctx.get(dut.ad0),
                             ctx.get(dut.active), ctx.get(dut.ready), ctx.get(dut.overruns)))

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(tb)
    run_simulation(sim, "dmp_generator")
    return seen


def run_ref(model, ops):
    by_cycle = {}
    for cycle, kind, arg in ops:
        by_cycle.setdefault(cycle, []).append((kind, arg))
    seen = []
    for c in sorted(by_cycle):
        kinds = {}
        for kind, arg in by_cycle[c]:
            if kind == "write":
                model.write(*arg)
            kinds[kind] = True
        if "stop" in kinds:
            model.stop()
        elif "start" in kinds:
            model.start(c)
        elif "step" in kinds:
            model.step(c)
        seen.append((c, model.qd0, model.vd0, model.ad0, int(model.active),
                     int(model.ready(c + 1)), model.overruns))
    return seen


def upload_ops(words, at=0):
    return [(at + i, "write", (a, w)) for i, (a, w) in enumerate(sorted(words.items()))]


def steps_ops(first, n, gap):
    return [(first + k * gap, "step", None) for k in range(n)]


def check_equal(ops, max_basis=MAX_BASIS):
    n_cycles = max(c for c, _, _ in ops) + 2
    rtl = run_rtl(DmpGenerator(max_basis=max_basis), ops, n_cycles)
    ref = run_ref(DmpGeneratorModel(max_basis), ops)
    for a, b in zip(rtl, ref, strict=True):
        assert a == b, f"cycle {a[0]}: RTL {a[1:]} != reference {b[1:]}"
    return ref


@pytest.mark.parametrize("dmp", [QUINTIC, PATH, LOOP], ids=["quintic", "path", "loop"])
def test_rtl_equals_reference_on_learned_primitives(dmp):
    words = params_of(dmp).words()
    n = dmp.n_basis
    gap = step_cycles(n) + 1                      # the shortest period that never overruns
    ops = upload_ops(words) + [(len(words), "start", None)]
    ops += steps_ops(len(words) + gap, 4, gap)
    seen = check_equal(ops)
    assert all(s[5] == 0 and s[6] == 0 for s in seen[len(words) + 1:])  # no overrun
    assert len({s[1:4] for s in seen[-4:]}) == 4                   # the outputs move


def test_cycle_count_is_the_references():
    """``ready`` rises exactly ``step_cycles(n)`` cycles after the strobe's next cycle."""
    words = params_of(QUINTIC).words()
    n = QUINTIC.n_basis
    t0 = len(words)
    ops = upload_ops(words) + [(t0, "start", None)]
    # Polls (writes of an unused address) the cycle before and at the predicted ready.
    for c in (t0 + step_cycles(n) - 1, t0 + step_cycles(n)):
        ops.append((c, "write", (15, 0)))
    seen = check_equal(ops)
    assert [s[5] for s in seen[-2:]] == [0, 1]


def microprogram_cycles(n: int, max_basis: int = MAX_BASIS) -> int:
    """A step's cycles walked through the microprogram's branches with ``n`` Gaussians: every
    micro-operation OP_CYCLES, the divider's DIV_CYCLES (its 34 quotient bits and rounding)."""
    labels, ops = split_labels(program(max_basis, 0))
    pc = i = cycles = 0
    while True:
        op = ops[pc]
        cycles += DIV_CYCLES if op.get("div") else OP_CYCLES
        br, pc = op.get("br", Br.NONE), pc + 1
        if br == Br.END:
            return cycles
        if br == Br.LOOP:
            i, pc = (0, pc) if i == n - 1 else (i + 1, labels[op["tgt"]])
        elif br == Br.NZERO and n == 0:
            pc = labels[op["tgt"]]


def test_cycle_count_is_the_microprograms():
    """The reference's CYCLES_FIXED and CYCLES_PER_BASIS are the microprogram's: five cycles a
    micro-operation (the operands registered before the multipliers, docs/node.md Clock), the
    divider's 2 + 34 + 2. ``test_cycle_count_is_the_references`` holds the gateware to it: with
    the operand phase removed ``ready`` rises 18 n + 48 cycles early and it fails."""
    assert OP_CYCLES == 5 and DIV_CYCLES == 2 + QBITS + 2
    for n in (0, 1, 2, 20, MAX_BASIS):
        assert microprogram_cycles(n) == step_cycles(n), n
    assert (CYCLES_FIXED, CYCLES_PER_BASIS) == (278, 90)


def test_multiplier_operands_are_registers():
    """The four partial products read only the operand registers ``mul_a``, ``mul_b``, and
    those are flip-flops: no block RAM output (register file, parameter memory) reaches a
    MULT18X18 in the cycle it is read (docs/node.md, Clock). With the operand register
    removed (the products taken from the RAMs' outputs in phase 1 again) it fails, though the
    outputs and cycle counts would not show it."""
    # read from the netlist Amaranth's public RTLIL backend writes: every `$mul` cell and
    # what its A and B ports connect to, and the cells that drive `mul_a` and `mul_b`
    text = rtlil.convert(DmpGenerator())
    cells = re.findall(r"^  cell (\S+) \S+\n(.*?)^  end$", text, re.S | re.M)
    operands = [set(re.findall(r"\\(\w+)", port))
                for kind, body in cells if kind == "$mul"
                for port in re.findall(r"connect \\[AB] (.*)", body)]
    assert len(operands) == 8                          # the four partial products' A and B
    assert all(wires <= {"mul_a", "mul_b"} and wires for wires in operands), operands
    drivers = {q: kind for kind, body in cells
               for q in re.findall(r"connect \\Q \\(\w+)$", body, re.M)}
    assert drivers.get("mul_a") == drivers.get("mul_b") == "$dff", drivers


def test_small_build_and_no_basis():
    """max_basis = 4 with 3 Gaussians, then n_basis = 0 (f = 0: a pure spring-damper)."""
    p = DmpParams.from_float([50.0, -20.0, 5.0], [1.0, 0.6, 0.3], [0.15, 0.1, 0.1], 25.0, 6.25,
                             2.0, 0.5, 0.1, -0.3, 0.2, True, max_basis=4)
    words = p.words(4)
    gap = step_cycles(3) + 1
    t0 = len(words)
    ops = upload_ops(words) + [(t0, "start", None)] + steps_ops(t0 + gap, 3, gap)
    t1 = t0 + 4 * gap
    ops += [(t1, "write", (Reg.N_BASIS, 0)), (t1 + 1, "start", None)]
    ops += steps_ops(t1 + 1 + step_cycles(0) + 1, 3, step_cycles(0) + 1)
    check_equal(ops, max_basis=4)


def test_start_stop_goal_and_tau_changes_mid_run():
    p = params_of(PATH)
    words = p.words()
    n = PATH.n_basis
    gap = step_cycles(n) + 5
    t = len(words)
    ops = upload_ops(words) + [(t, "start", None)] + steps_ops(t + gap, 2, gap)
    t += 3 * gap
    ops.append((t - 3, "write", p.goal_word(1.5)))           # goal change: one word
    ops += steps_ops(t, 2, gap)
    t += 2 * gap
    ops.append((t - 3, "write", p.invtau_word(1.0)))         # τ 2 s → 1 s: one word
    ops += steps_ops(t, 2, gap)
    t += 2 * gap
    ops.append((t, "stop", None))                            # hold position, zero rates
    ops += [(t + 7, "step", None)]                           # ignored while stopped
    ops += [(t + 20, "start", None)] + steps_ops(t + 20 + gap, 2, gap)
    seen = check_equal(ops)
    stopped = [s for s in seen if s[0] == t][0]
    assert stopped[2:5] == (0, 0, 0) and stopped[1] != 0     # vd0 = ad0 = 0, inactive
    ref = DmpGeneratorModel()
    for a, w in words.items():
        ref.write(a, w)
    ref.start()
    plain = [ref.step() for _ in range(4)]
    changed = [s[1:4] for s in seen if s[0] in (t - 4 * gap, t - 3 * gap)]
    assert changed != plain[2:4]                             # the goal change took effect


def test_overruns_keep_the_outputs_and_are_counted():
    words = params_of(QUINTIC).words()
    n = QUINTIC.n_basis
    t = len(words)
    ops = upload_ops(words) + [(t, "start", None)]
    ops += [(t + 5, "step", None), (t + 9, "step", None)]       # while computing step 0
    first = t + step_cycles(n) + 1
    ops += [(first, "step", None), (first + 1, "step", None)]   # commit, then one too early
    seen = check_equal(ops)
    assert [s[6] for s in seen[-4:]] == [1, 2, 2, 3]
    assert seen[-1][1:4] == seen[-2][1:4] and seen[-2][1:4] != seen[-3][1:4]


def test_reference_overruns_saturate():
    ref = DmpGeneratorModel(2)
    ref.write(Reg.INVTAU, 1 << 20)
    ref.start(0)
    for _ in range(1, 70_000):
        ref.step(1)
    assert ref.overruns == 0xFFFF
    assert ref.step(1000) is not None


_weights = st.lists(st.integers(-(1 << 20), 1 << 20), min_size=0, max_size=6)


@settings(max_examples=12, deadline=None)
@given(weights=_weights, data=st.data())
def test_rtl_equals_reference_on_random_words(weights, data):
    """Random words in every register (within the formats, saturations reachable)."""
    n = len(weights)
    word = st.integers(-(1 << 23), (1 << 23) - 1)
    words = {weight_addr(i, 8): w for i, w in enumerate(weights)}
    for i in range(n):
        words[centre_addr(i, 8)] = data.draw(st.integers(-(1 << 20), 1 << 23))
        words[width_addr(i, 8)] = data.draw(st.integers(0, 1 << 23))
    words.update({Reg.N_BASIS: n, Reg.FLAGS: data.draw(st.integers(0, 1)),
                  Reg.ALPHA: data.draw(word), Reg.ALPHA_BETA: data.draw(word),
                  Reg.PHASE_RATE: data.draw(word), Reg.DT: data.draw(st.integers(0, 1 << 23)),
                  Reg.INVTAU: data.draw(word), Reg.X0: data.draw(word),
                  Reg.GOAL: data.draw(word), Reg.V0: data.draw(word),
                  Reg.AMPLITUDE: data.draw(word), Reg.RADC: data.draw(word)})
    gap = step_cycles(n) + 1
    t = len(words)
    ops = upload_ops(words) + [(t, "start", None)] + steps_ops(t + gap, 3, gap)
    check_equal(ops, max_basis=8)


# -- the ALU's write-back word -----------------------------------------------------------------

SAT_WIDTHS = {Sat.S24: WORD, Sat.S35: 35, Sat.S40: 40}


def clamp_shifted(s, shift, sat):
    """The write-back word by definition: ``s >> shift`` clamped as ``sat`` says."""
    z = s >> shift
    if sat in SAT_WIDTHS:
        return saturate(z, SAT_WIDTHS[sat])
    if sat is Sat.U46:
        return min(max(z, 0), PHI_MAX)
    return z


def test_saturate_shifted_is_the_clamp_of_the_shifted_word():
    """Every (sat, shift) pair, on the words either side of each bound the pair has (where the
    shifted word leaves 24, 35, 40 or 46 bits) and random words of every magnitude."""
    rng = np.random.default_rng(7)
    edges = sorted({b + sh for b in (WORD - 1, 34, 39, PHI_WIDTH) for sh in SHIFTS})
    values = [0, -1, 1, (1 << (RF_WIDTH - 1)) - 1, -(1 << (RF_WIDTH - 1))]
    for e in edges:
        for v in ((1 << e) - 1, 1 << e, -(1 << e), -(1 << e) - 1):
            values += [v, v + 1, v - 1]
    for bits in rng.integers(1, RF_WIDTH, size=120):     # random words of `bits` bits
        v = int.from_bytes(rng.bytes(RF_WIDTH // 8)) >> (RF_WIDTH - int(bits))
        values += [v, -v]
    values = [v for v in values if -(1 << (RF_WIDTH - 1)) <= v < 1 << (RF_WIDTH - 1)]
    m = Module()
    s, sh, sat = Signal(signed(RF_WIDTH)), Signal(2), Signal(Sat)
    w = saturate_shifted(m, s, sh, sat)
    sim = Simulator(m)

    async def bench(ctx):
        for case in Sat:
            for k, shift in enumerate(SHIFTS):
                ctx.set(sat, case)
                ctx.set(sh, k)
                for v in values:
                    ctx.set(s, v)
                    assert ctx.get(w) == clamp_shifted(v, shift, case), (case, shift, v)

    sim.add_testbench(bench)
    sim.run()


# -- the reference against the float DMP ------------------------------------------------------

def ref_rollout(params, n_steps, writes=()):
    ref = DmpGeneratorModel()
    for a, w in params.words().items():
        ref.write(a, w)
    ref.start()
    return np.array([decode_outputs(*ref.step(), CPR) for _ in range(n_steps)])


@pytest.mark.parametrize("dmp, step, bounds", [
    # position counts, velocity rad/s, acceleration rad/s²
    (QUINTIC, STEP_CYCLES, (0.5, 1e-5, 1e-3)),
    (QUINTIC, 5 * STEP_CYCLES, (0.5, 1e-5, 1e-3)),
    (PATH, STEP_CYCLES, (0.5, 1e-5, 1e-3)),
    (PATH, 5 * STEP_CYCLES, (0.5, 1e-5, 1e-3)),
    (LOOP, STEP_CYCLES, (0.5, 1e-5, 1e-3)),
], ids=["quintic-1ms", "quintic-5ms", "path-1ms", "path-5ms", "loop-1ms"])
def test_reference_follows_the_float_rollout(dmp, step, bounds):
    ro = dmp.rollout(step / 50e6)
    q = ref_rollout(params_of(dmp, step_cycles=step), len(ro.t))
    err = (np.max(np.abs(q[:, 0] - ro.x[:, 0])) * KC, np.max(np.abs(q[:, 1] - ro.xd[:, 0])),
           np.max(np.abs(q[:, 2] - ro.xdd[:, 0])))
    assert err[0] <= bounds[0] and err[1] <= bounds[1] and err[2] <= bounds[2], err


def test_ten_second_motion_does_not_drift():
    """τ = 2 s played for 10 s at 1 ms: the reference follows the float all the way (past
    t ≈ 3.5 s every Gaussian underflows; both normalise ψ by the largest one and go on), then
    settles on the particular solution of the remaining forcing s w_last A with
    s = e^(−α_s t/τ): x = g + s w_last A / (α β − α α_s + α_s²)."""
    ro = PATH.rollout(1e-3, 10.0)
    p = params_of(PATH)
    q = ref_rollout(p, len(ro.t))
    assert np.all(np.isfinite(ro.x[:, 0]))
    assert np.max(np.abs(q[:, 0] - ro.x[:, 0])) * KC <= 0.5
    force = math.exp(-PATH.alpha_s * 10.0 / PATH.tau) * PATH.weights[0, -1] * \
        (PATH.g[0] - PATH.x0[0])
    a, b, a_s = PATH.alpha, PATH.beta, PATH.alpha_s
    settled = PATH.g[0] + force / (a * b - a * a_s + a_s * a_s)
    assert abs(q[-1, 0] - settled) * KC <= 0.5
    assert abs(q[-1, 1] + a_s / PATH.tau * (settled - PATH.g[0])) <= 2e-6


def test_ten_second_primitive_error_is_the_tau_word():
    """A 10 s demo (τ = 10 s, 30 Gaussians): 2.2 counts from the float at the end, all of it
    the INVTAU word's rounding (1/τ to 2^-20 /s, 3.8e-6 relative: a time-scale error); against
    the float run with the step ratio k the words give, 0.12 counts."""
    dmp = learn_dmp(path(10.0), 1e-3, 30)
    p = params_of(dmp)
    ro = dmp.rollout(1e-3)
    q = ref_rollout(p, len(ro.t))
    assert np.max(np.abs(q[:, 0] - ro.x[:, 0])) * KC <= 3.0
    k = round_shift(p.dt * p.invtau, 12) * 2.0**-38
    ro = dmp.with_tau(1e-3 / k).rollout(1e-3, 10.0)
    assert np.max(np.abs(q[:, 0] - ro.x[:, 0])) * KC <= 0.25
    assert np.max(np.abs(q[:, 1] - ro.xd[:, 0])) <= 4e-6
    assert np.max(np.abs(q[:, 2] - ro.xdd[:, 0])) <= 2e-4


def test_goal_and_tau_words_match_a_primitive_built_with_them():
    """A goal or τ word written before start gives the float primitive with that goal / τ."""
    p = params_of(QUINTIC)
    for g, tau in ((1.7, None), (None, 1.6)):
        ref = DmpGeneratorModel()
        for a, w in p.words().items():
            ref.write(a, w)
        dmp = QUINTIC
        if g is not None:
            ref.write(*p.goal_word(g))
            dmp = dmp.with_goal([g])
        if tau is not None:
            ref.write(*p.invtau_word(tau))
            dmp = dmp.with_tau(tau)
        ro = dmp.rollout(1e-3)
        ref.start()
        q = np.array([decode_outputs(*ref.step()) for _ in range(len(ro.t))])
        assert np.max(np.abs(q[:, 0] - ro.x[:, 0])) * KC <= 0.5
        assert np.max(np.abs(q[:, 1] - ro.xd[:, 0])) <= 1e-5


def test_exp_unit_is_accurate():
    rng = np.random.default_rng(0)
    for phi in [0, 1, (1 << 40) - 1, 1 << 40, 30 << 40] + \
            [int(v) for v in rng.integers(0, 31 << 40, 3000)]:
        exact = 2.0 ** (-phi / 2**40) * 2**28
        assert abs(exp2neg(phi) - exact) <= 1e-6 * exact + 0.5, phi
    assert exp2neg(31 << 40) == 0 and exp2neg(0) == 1 << 28


# -- host side --------------------------------------------------------------------------------

@pytest.mark.parametrize("change, field", [
    (dict(weights=[1.0] * 33, centers=[0.5] * 33, widths=[0.1] * 33), "dmp.weights"),
    (dict(weights=[1.0, 2.0, 3.0, 1e4]), "dmp.weights[3]"),
    (dict(centers=[0.5, 0.4, 3.0, 0.1]), "dmp.centers[2]"),
    (dict(widths=[0.1, 1e-5, 0.1, 0.1]), "dmp.widths[1]"),
    (dict(widths=[0.1, 0.1, 0.0, 0.1]), "dmp.widths[2]"),
    (dict(centers=[0.5, 0.4]), "dmp.centers"),
    (dict(tau=0.0), "dmp.tau"),
    (dict(tau=-1.0), "dmp.tau"),
    (dict(tau=0.05), "dmp.tau"),                      # 1/τ above the INVTAU format
    (dict(alpha=400.0, beta=100.0, tau=0.2), "dmp.tau"),   # unstable step (Jury)
    (dict(x0_rad=5.0), "dmp.x0"),
    (dict(g_rad=float("nan")), "dmp.g"),
    (dict(alpha=1000.0), "dmp.alpha"),
    (dict(counts_per_rev=4096), "dmp.counts_per_rev"),
    (dict(step_cycles=500_000), "dmp.step_cycles"),
])
def test_from_float_refuses_what_does_not_fit(change, field):
    args = dict(weights=[1.0, 2.0, 3.0, 4.0], centers=[1.0, 0.7, 0.4, 0.2],
                widths=[0.1, 0.1, 0.1, 0.1], alpha=25.0, beta=6.25, alpha_s=2.0, tau=1.0,
                x0_rad=0.0, g_rad=1.0, xd0=0.0, goal_scaling=True)
    kw = {k: change.pop(k) for k in ("counts_per_rev", "step_cycles") if k in change}
    args.update(change)
    with pytest.raises(InputError) as exc:
        DmpParams.from_float(**args, **kw)
    assert exc.value.field == field


def test_param_payloads_write_every_word_in_the_dmp_bank():
    p = params_of(PATH)
    words = p.words()
    got = {}
    for payload in dmp_param_payloads(p):
        assert payload[0] == Bank.DMP == 2
        addr = int.from_bytes(payload[1:3], "little")
        n = (len(payload) - 3) // 3
        for k, w in enumerate(unpack_words(payload, n, 3)):
            got[addr + k] = w
    assert got == words
    assert words[weight_addr(29)] == p.weights[29] and words[width_addr(0)] == p.widths[0]


def test_generator_validates_its_build_parameter_and_is_a_top():
    with pytest.raises(ValueError, match="max_basis"):
        DmpGenerator(max_basis=0)
    top = build_top("dmp_generator", max_basis=8)
    assert top.max_basis == 8 and len(top.host_addr) == 6
    Fragment.get(top, None)                       # elaborates
    with pytest.raises(InputError):
        build_top("dmp_generator", max_basis=1000)
