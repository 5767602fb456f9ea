# amaranth: UnusedElaboratable=no
"""The primitive generator inside the node core: deployed with PARAM (bank DMP), started,
stepped on the period grid, stopped and switched off with CONFIG DMP, its references taking
over from Comm D's — the gateware against the transaction-level reference (NodeModel) fed with
the same events at the same cycles, torque, status and the observation port every cycle."""

import math

import numpy as np
import pytest
from amaranth import Signal
from amaranth.sim import Simulator

from mrm_cosim.hdl.link.chain import get_packet, put_packet
from mrm_cosim.hdl.node.core import NodeCore
from mrm_cosim.hdl.node.core_ref import NodeModel
from mrm_cosim.master.dmp import learn_dmp
from mrm_cosim.models.encoder import counts_per_rad, quadrature_levels
from mrm_cosim.protocol.discipline import Discipline
from mrm_cosim.protocol.dmp import DmpParams, dmp_param_payloads
from mrm_cosim.protocol.encoder import EncoderParams
from mrm_cosim.protocol.fixed import FORCE
from mrm_cosim.protocol.joint_program import JointParams
from mrm_cosim.protocol.packet import Header, PacketType
from mrm_cosim.protocol.regs import (Config, DmpControl, NodeEvent, Status, config_payloads,
                                     joint_upload, pack_comm_d, parse_comm_a)
from mrm_cosim.testbench import run_simulation

TICK = 50
PERIOD, COMMIT, WINDOW, STEP = 2000, 1000, 300, 1000   # STEP > step_cycles(5) = 728
# CONFIG DMP at this phase: a START's step 0 (step_cycles(5) after the record acts, a few
# cycles after the packet) is ready by the boundary (phase 1300 was, with 590 cycles, until
# the generator's operand phase of 26 Nov)
CONTROL_PHASE = 1200
# A DMP_STEP that does not divide PERIOD and exceeds step_cycles(5) (it was 600 with 590)
NOT_DIVIDING = 800
K_RAD = float(counts_per_rad(800_000))
ENC = EncoderParams(min_window=256, stop_cycles=1 << 20)
Q0 = 0.2


def joint_angle(cycle):
    """The joint (rad) the encoder lines follow: a slow motion near the primitive's start."""
    t = cycle * 20e-9
    return Q0 + 0.5 * t + 60.0 * t * t


def primitive(step=STEP):
    """A 5-basis primitive of a 0.2 s move from Q0 starting at 0.3 rad/s, learned at the
    generator's step (``step`` cycles, 20 µs by default): its references move a few counts
    in the test's periods."""
    dt = step * 20e-9
    t = np.arange(0, 0.2 + dt / 2, dt)
    y = Q0 + 0.3 * t - 0.5 * t**2
    return learn_dmp(y, dt, 5, alpha=25.0, alpha_s=3.0, xd0=[0.3])


def uploads(mode, step=STEP):
    jp = JointParams.from_float(lam=50.0, k_j=3.0, inertia=0.2, viscous=0.16, coulomb=1.0,
                                v_smooth=2e-3, k_p=800.0, k_i=4000.0, k_d=20.0, i_max=2e-4)
    cfg = {Config.MODE: mode, Config.TICK: TICK, Config.TIMEOUT: 30_000,
           Config.RAMP: FORCE.encode(1.5), Config.TAU_MIN: FORCE.encode(-8.0),
           Config.TAU_MAX: FORCE.encode(8.0), Config.DMP_STEP: step}
    d = primitive(step)
    params = DmpParams.from_float(d.weights[0], d.centers, d.widths, d.alpha, d.beta,
                                  d.alpha_s, d.tau, float(d.x0[0]), float(d.g[0]),
                                  float(d.xd0[0]), bool(d.goal_scaling[0]),
                                  step_cycles=step)
    packets = [(PacketType.CONFIG, p) for p in config_payloads(cfg)]
    packets += [(PacketType.PARAM, p) for p in joint_upload(jp)]
    packets += [(PacketType.PARAM, p) for p in dmp_param_payloads(params)]
    packets += [(PacketType.CONFIG, p) for p in config_payloads({Config.ARM: 1})]
    return packets


@pytest.mark.parametrize("mode", [1, 0], ids=["pid", "vdc"])
def test_generator_in_the_node_equals_the_reference_cycle_for_cycle(mode):
    """Period 0: Comm D's references; START in period 0 → the generator's references from
    period 1's boundary, a step every 1000 cycles; STOP in period 3 (hold); OFF in period 4
    (Comm D's again). Comm D's τ_D feeds forward (PID) or is τ_Lr (VDC) throughout: the
    generator serves the joint controller in either mode."""
    trace, strobes, model, replies, marks = _run(mode)
    first = marks["first"]
    steps = sorted(c for c, f in strobes if f == NodeEvent.DMP_STEP)
    # the first step at period 1's boundary, then every STEP cycles until the STOP
    assert steps[0] == first + PERIOD
    assert all(b - a == STEP for a, b in zip(steps, steps[1:], strict=False))
    assert marks[DmpControl.STOP] < steps[-1] + STEP
    selected = [c for c in range(len(trace)) if trace[c][3] & Status.DMP]
    assert selected[0] == first + PERIOD + 1
    assert marks[DmpControl.OFF] < selected[-1] < marks[DmpControl.OFF] + 100
    # no generator overrun: every step found its references ready
    assert all(parse_comm_a(r[1])["dmp_overruns"] == 0 for r in replies)
    # the references moved: 0.3 rad/s for 120 µs is 4.6 counts
    x0 = DmpParams.from_float([0.0], [1.0], [0.1], 25.0, 6.25, 3.0, 0.2, Q0, Q0, 0.0,
                              True, step_cycles=STEP).x0
    assert model.dmp.qd0 - x0 > 16 * 2


@pytest.mark.parametrize("step, target, arrive, both", [
    # e = +20, then the loop rings: periods of PERIOD ± 1 while the generator runs
    (STEP, 0, 20, True),
    # DMP_STEP = PERIOD, the default's ratio: steps at the boundaries only
    (PERIOD, 0, 20, True),
    # e = −20: a period shortened by 27 (the generator waiting), then lengthened ones
    (STEP, 40, 20, False),
], ids=["step-lengthened-shortened", "step-is-period", "step-after-shortened"])
def test_generator_steps_on_the_nominal_grid_of_a_disciplined_period(step, target, arrive,
                                                                     both):
    """TC_DISCIPLINE on (kp 0, ki 2) and a time-code each period at phase ``arrive`` of the
    master's grid: the loop makes every period ``PERIOD + adj`` cycles, adj ≠ 0. The
    generator still steps PERIOD / DMP_STEP times a period — at the boundary and every
    DMP_STEP cycles after it while the phase is below PERIOD (the nominal grid; the period's
    last step interval is DMP_STEP + adj) — so no step comes adj cycles before the boundary's
    own and none is counted as an overrun; gateware == reference in every cycle."""
    word = Discipline(target=target, kp=0, ki=2).word
    trace, strobes, model, replies, marks = _run(1, discipline=word, arrive=arrive,
                                                 step=step, control={0: DmpControl.START})
    b = model.boundaries
    lengths = {y - x for x, y in zip(b, b[1:], strict=False) if x > marks["first"]}
    assert max(lengths) > PERIOD and (min(lengths) < PERIOD or not both)
    steps = sorted(c for c, f in strobes if f == NodeEvent.DMP_STEP)
    running = [x for x in b if steps[0] <= x < steps[-1]]
    assert len(running) >= 4
    for x, y in zip(running, running[1:], strict=False):
        assert [c - x for c in steps if x <= c < y] == list(range(0, PERIOD, step))
    assert all(parse_comm_a(r[1])["dmp_overruns"] == 0 for r in replies)
    assert all(parse_comm_a(r[1])["overruns"] == 0 for r in replies)


@pytest.mark.parametrize("step, arrive", [
    # DMP_STEP does not divide PERIOD: every other boundary's strobe comes 400 cycles after a
    # step (not ready), and the grid step DMP_STEP after the last step taken still comes
    (NOT_DIVIDING, 20),
    # the same with a resync 700 cycles into a period (the loop off): off the grid
    (NOT_DIVIDING, 700),
    # DMP_STEP divides PERIOD; a resync at 1500 moves the boundaries off the old grid
    (STEP, 1500),
], ids=["step-not-dividing", "resync-off-grid", "resync-on-step"])
def test_a_strobe_that_finds_the_generator_busy_leaves_its_grid_step_due(step, arrive):
    """A step strobe whose references are not ready (a boundary's, a few hundred cycles after a
    step that takes 728) changes nothing but the overrun count: the generator's time runs on
    from the last step taken, so the grid step DMP_STEP after it still comes. The reference
    had dropped that step and waited for the next boundary. Gateware == reference every cycle
    (inside ``_run``); time-codes at phase ``arrive`` with TC_DISCIPLINE 0 (a resync when
    outside SYNC_WINDOW)."""
    trace, strobes, model, replies, marks = _run(1, discipline=0, arrive=arrive, step=step,
                                                 control={0: DmpControl.START})
    steps = sorted(c for c, f in strobes if f == NodeEvent.DMP_STEP)
    gaps = {b - a for a, b in zip(steps, steps[1:], strict=False)}
    if step == NOT_DIVIDING:
        # boundary strobes off the grid miss, and are counted; the grid keeps its beat
        assert max(parse_comm_a(r[1])["dmp_overruns"] for r in replies) > 0
        taken = [c for c in steps if c not in set(model.boundaries)]
        assert {b - a for a, b in zip(taken, taken[1:], strict=False)} <= {step, 2 * step}
    assert min(gaps) > 0 and len(steps) >= 10


def test_a_tick_the_tail_took_stays_taken_when_a_later_time_code_lengthens_the_period():
    """Jittered time-codes (phases 17, −43, −106, 16, 13, −74, −78 of the master's periods;
    target 28, kp 0, ki 4): a tick the disciplined period's tail suppressed in its cycle under
    one ``adj`` is not brought back when a time-code after it sets a longer period — the
    gateware's tick counter ran out in that cycle. The reference had kept the suppressed tick
    as its next one and, the period lengthened, ran it 36 cycles in the past (found by a
    probe over random schedules: 79 of 300 hit it); gateware == reference every cycle."""
    word = Discipline(target=28, kp=0, ki=4).word
    _, _, model, replies, _ = _run(1, discipline=word, arrive=[17, -43, -106, 16, 13, -74, -78],
                                   control={})
    b = model.boundaries
    assert len({y - x for x, y in zip(b, b[1:], strict=False)}) > 2     # the loop moved them
    assert all(parse_comm_a(r[1])["overruns"] == 0 for r in replies)


def _run(mode, discipline=None, arrive=None, step=STEP, control=None):
    """The node core with the generator against NodeModel, every cycle; CONFIG DMP as in
    ``control`` (period → DmpControl, START / STOP / OFF in periods 0, 3, 4 by default).
    With ``discipline`` (TC_DISCIPLINE) a time-code comes at phase ``arrive`` of each of the
    master's periods (a list: ``arrive[n]`` in period ``n``). Returns
    ``(trace, strobes, model, replies, marks)``."""
    if control is None:
        control = {0: DmpControl.START, 3: DmpControl.STOP, 4: DmpControl.OFF}
    end = 8 * PERIOD + 1500
    dut = NodeCore(encoder=ENC)
    trace, strobes, events, replies, sent, marks = {}, [], [], [], [], {}
    dut_cycle = Signal(32)

    async def encoder_lines(ctx):
        for c in range(end + 10):
            a, b = quadrature_levels(np.array([math.floor(joint_angle(c + 1) * K_RAD)]))
            ctx.set(dut.enc_a, int(a[0]))
            ctx.set(dut.enc_b, int(b[0]))
            await ctx.tick()

    async def counter(ctx):
        for c in range(end + 10):
            ctx.set(dut_cycle, c + 1)
            await ctx.tick()

    async def monitor(ctx):
        for c in range(end):
            _, _, cnt, vel, tq, st, valid, ready, last, ps, ev = await ctx.tick().sample(
                dut.count, dut.velocity, dut.torque, dut.status, dut.rx.valid, dut.rx.ready,
                dut.rx.p.last, dut.period_start, dut.events)
            trace[c] = (cnt, vel, tq, st)
            if ev:
                strobes.extend((c, f) for f in NodeEvent if ev & f)
            if valid and ready and last:
                events.append((c, "packet"))
            if ps:
                events.append((c, "timecode"))

    async def send(ctx, ptype, payload, seq=0):
        await put_packet(ctx, dut.rx, Header(dest=1, src=0, type=int(ptype), seq=seq), payload)
        sent.append((int(ptype), bytes(payload)))

    async def wait_until(ctx, cycle):
        while ctx.get(dut_cycle) < cycle:
            await ctx.tick()

    async def master(ctx):
        ctx.set(dut.period, 0)
        timing = {Config.PERIOD: PERIOD, Config.COMMIT: COMMIT, Config.SYNC_WINDOW: WINDOW}
        if discipline is not None:
            timing[Config.TC_DISCIPLINE] = discipline
        for ptype, payload in [(PacketType.CONFIG, p) for p in config_payloads(timing)] + \
                uploads(mode, step):
            await send(ctx, ptype, payload)
        first = (ctx.get(dut_cycle) // PERIOD + 1) * PERIOD
        marks["first"] = first
        for n in range(7):
            start = first + PERIOD * n
            if discipline is not None:
                await wait_until(ctx, start + (arrive[n] if isinstance(arrive, list)
                                               else arrive))
                ctx.set(dut.period, n + 1)
                ctx.set(dut.period_start, 1)
                await ctx.tick()
                ctx.set(dut.period_start, 0)
            await wait_until(ctx, start + 40)
            await send(ctx, PacketType.COMM_A, b"\0", seq=n)
            replies.append(await get_packet(ctx, dut.tx))
            q = joint_angle(start)
            await send(ctx, PacketType.COMM_D, pack_comm_d(0.5 + 0.1 * n, [0, 0, 9.81], q,
                                                           0.3, 0.0))
            ctl = control.get(n)
            if ctl is not None:
                await wait_until(ctx, start + CONTROL_PHASE)
                marks[ctl] = ctx.get(dut_cycle)
                await send(ctx, PacketType.CONFIG, config_payloads({Config.DMP: ctl})[0])

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_process(encoder_lines)
    sim.add_process(counter)
    sim.add_testbench(monitor)
    sim.add_testbench(master, background=True)
    run_simulation(sim, "node_dmp_core")

    model = NodeModel(encoder=ENC, events=[])
    packets = iter(sent)
    tcs = iter(range(1, 100))
    by_cycle = {}
    for c, kind in events:
        by_cycle.setdefault(c, []).append(kind)

    def sample(c):
        return trace[c][0], trace[c][1], 0

    ref_replies = []
    for c in range(end - 1):
        model.run(c, sample)
        assert model.torque_at(c) == trace[c][2], f"torque in cycle {c}"
        if c >= marks["first"]:
            assert int(model.status) == trace[c][3], f"status in cycle {c}"
        model.run(c + 1)
        for kind in sorted(by_cycle.get(c, []), reverse=True):     # time-code first
            if kind == "timecode":
                model.timecode(c, next(tcs))
                continue
            ptype, payload = next(packets)
            reply = model.packet(c, ptype, payload)
            if reply is not None:
                ref_replies.append(reply)
    assert [r[1] for r in replies] == ref_replies
    assert sorted(e for e in strobes if e[0] < end - 1) == \
        sorted(e for e in model.events if e[0] < end - 1)
    return [trace[c] for c in range(end)], strobes, model, replies, marks
