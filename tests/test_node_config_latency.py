# amaranth: UnusedElaboratable=no
"""A CONFIG record acts one cycle after its last byte (the node core holds the decoder's record
in a register before NodeConfig, docs/node.md "Clock"): records landing at a period's edge —
ARM at the boundary's last cycles, PERIOD across the phase it sets, SYNC_WINDOW with a
time-code in the cycle it acts, PRESET — give the same status, torque, count and observation
port on the gateware (NodeCore) as on the reference (NodeModel), cycle for cycle. Either side
without the cycle (the register removed, or the reference applying records at the last byte)
fails here."""

import pytest
from amaranth import Signal
from amaranth.sim import Simulator

from mrm_cosim.hdl.link.chain import put_packet
from mrm_cosim.hdl.node.core import NodeCore
from mrm_cosim.hdl.node.core_ref import NodeModel
from mrm_cosim.protocol.encoder import EncoderParams
from mrm_cosim.protocol.packet import Header, PacketType
from mrm_cosim.protocol.regs import Config, Status, config_payloads
from mrm_cosim.testbench import run_simulation

ENC = EncoderParams(min_window=256, stop_cycles=1 << 20)
PERIOD, WINDOW = 400, 60


def _run(plan, end):
    """``plan``: ``[(kind, cycle, arg)]`` in cycle order — ``("config", c, {reg: value})`` a
    one-record CONFIG packet whose last byte is taken in cycle ``c``, ``("tc", c, value)`` a
    time-code strobe in cycle ``c``. Returns the gateware's trace and the replayed model."""
    dut = NodeCore(encoder=ENC)
    cycle = Signal(32)
    trace, strobes, ends, tcs = {}, [], [], []

    async def counter(ctx):
        for c in range(end + 10):
            ctx.set(cycle, c + 1)
            await ctx.tick()

    async def monitor(ctx):
        for c in range(end):
            _, _, cnt, vel, tq, st, valid, ready, last, ps, ev = await ctx.tick().sample(
                dut.count, dut.velocity, dut.torque, dut.status, dut.rx.valid, dut.rx.ready,
                dut.rx.p.last, dut.period_start, dut.events)
            trace[c] = (cnt, vel, tq, st)
            strobes.extend((c, 1 << k) for k in range(16) if ev >> k & 1)
            if valid and ready and last:
                ends.append(c)
            if ps:
                tcs.append(c)

    sent = []

    async def timecodes(ctx):
        for kind, c, arg in plan:
            if kind == "tc":
                while ctx.get(cycle) < c + 1:
                    await ctx.tick()
                ctx.set(dut.period, arg)
                ctx.set(dut.period_start, 1)
                await ctx.tick()
                ctx.set(dut.period_start, 0)

    async def master(ctx):
        for kind, c, arg in plan:
            if kind == "config":
                (payload,) = config_payloads(arg)
                while ctx.get(cycle) < c - len(payload) + 2:
                    await ctx.tick()
                await put_packet(ctx, dut.rx, Header(dest=1, src=0, type=int(PacketType.CONFIG),
                                                        seq=0),
                                 payload)
                ctx.set(dut.rx.valid, 0)
                sent.append(payload)

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_process(counter)
    sim.add_testbench(monitor)
    sim.add_testbench(master, background=True)
    sim.add_testbench(timecodes, background=True)
    run_simulation(sim, "node_config_latency")
    # the packets and time-codes landed where the plan put them (the edges under test)
    assert ends == [c for kind, c, _ in plan if kind == "config"]
    assert tcs == [c for kind, c, _ in plan if kind == "tc"]

    model = NodeModel(encoder=ENC, events=[])
    packets = iter(sent)
    tc_values = iter(arg for kind, _, arg in plan if kind == "tc")

    def sample(c):
        return trace[c][0], trace[c][1], 0

    for c in range(end - 1):
        model.run(c, sample)
        assert model.torque_at(c) == trace[c][2], f"torque in cycle {c}"
        assert int(model.status) & ~Status.FRESH == trace[c][3] & ~Status.FRESH, \
            f"status in cycle {c}"
        if c in tcs:        # (not run past c first: a record acting in c acts after it)
            model.timecode(c, next(tc_values))
        model.run(c + 1)
        if c in ends:
            model.packet(c, PacketType.CONFIG, next(packets))
    assert sorted(s for s in strobes if s[0] < end - 1) == \
        sorted((c, int(f)) for c, f in model.events if c < end - 1)
    return trace, model


TIMING = {Config.PERIOD: PERIOD, Config.SYNC_WINDOW: WINDOW, Config.TIMEOUT: 1 << 30}


def _setup(first):
    """The timing CONFIG records, one packet each, ending at ``first``, ``first + 10``, …"""
    return [("config", first + 10 * k, {reg: v}) for k, (reg, v) in enumerate(TIMING.items())]


@pytest.mark.parametrize("edge", [-3, -2, -1, 0])
def test_arm_landing_at_the_boundary_edge(edge):
    """ARM's last byte ``edge`` cycles from the boundary at 2·PERIOD: the record acts a cycle
    later, so a last byte 2 cycles before the boundary (the record in the period's last
    cycle, after the integral's fine clear would have been due) arms a period later."""
    nb = 2 * PERIOD
    trace, model = _run(_setup(50) + [("config", nb + edge, {Config.ARM: 1})], 3 * PERIOD + 20)
    armed = min(c for c in trace if trace[c][3] & Status.ARMED)
    assert armed == (nb + 1 if edge <= -3 else nb + PERIOD + 1)


@pytest.mark.parametrize("at", [PERIOD + 248, PERIOD + 249, PERIOD + 250, PERIOD + 251])
def test_period_written_across_the_phase_it_sets(at):
    """PERIOD 250 written while the phase passes 250: the timer compares with it from the
    cycle after the record acts, a phase already past it ends the period at once."""
    trace, model = _run(_setup(50) + [("config", at, {Config.PERIOD: 250})], 3 * PERIOD)
    assert model.boundaries[:3] == [0, PERIOD, max(PERIOD + 250, at + 3)]


@pytest.mark.parametrize("offset", [0, 1])
def test_sync_window_with_a_timecode_where_it_acts(offset):
    """SYNC_WINDOW 20 from 60, a time-code at phase 40 in the cycle the record acts (the old
    window: in it, no resync) or the cycle after (the new: a resync)."""
    end = 2 * PERIOD + 39
    plan = _setup(50) + [("config", end, {Config.SYNC_WINDOW: 20}), ("tc", end + 1 + offset, 7)]
    trace, model = _run(plan, 3 * PERIOD)
    resyncs = [c for c, f in model.events if f == 1 << 1]
    assert resyncs == ([end + 2] if offset else [])


def test_preset_loads_the_count_a_cycle_after_the_record():
    at = PERIOD + 100
    trace, model = _run(_setup(50) + [("config", at, {Config.PRESET: 12345})], PERIOD + 200)
    assert model.presets == [(at + 1, 12345)]
    assert trace[at + 1][0] == 0 and trace[at + 2][0] == 12345
