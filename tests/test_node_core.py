# amaranth: UnusedElaboratable=no
"""Node core: uploads, the A/B/C/D exchange, joint ticks and the watchdog, against the
transaction-level reference (NodeModel) fed with the same events at the same cycles."""

import math
import sys

import numpy as np
import pytest
from amaranth.sim import Simulator

from mrm_cosim.hdl.link.chain import get_packet, put_packet
from mrm_cosim.protocol.crc import crc16
from mrm_cosim.protocol.discipline import Discipline, loop_step
from mrm_cosim.protocol.packet import Header, PacketType
from mrm_cosim.hdl.node.core import NodeCore
from mrm_cosim.hdl.node.core_ref import NodeModel
from mrm_cosim.protocol.encoder import EncoderParams
from mrm_cosim.protocol.fixed import FORCE, VEL
from mrm_cosim.protocol.joint_program import JointParams
from mrm_cosim.protocol.regs import (
    Config, NodeEvent, Status, config_payloads, joint_upload, pack_comm_b, pack_comm_d,
    parse_comm_a, parse_comm_c, vdc_upload,
)
from mrm_cosim.models.encoder import counts_per_rad, quadrature_levels
from mrm_cosim.models.robot import load_robot

from mrm_cosim.testbench import packet_ends, run_simulation

TICK = 50
K_RAD = float(counts_per_rad(800_000))
ENC = EncoderParams(min_window=256, stop_cycles=1 << 20)


def joint_angle(cycle):
    """A slow joint motion (rad) the encoder lines follow."""
    t = cycle * 20e-9
    return 0.2 + 0.3 * t + 40.0 * t * t


def uploads(mode=0, safe=None):
    theta = load_robot("mrm3").nominal_theta[1]
    K = np.full((2, 6), 40.0)
    rho = np.zeros((2, 13))
    rho[:, 0] = 20.0
    lower, upper = theta * 0.7 - 1e-3, theta * 1.3 + 1e-3
    lower, upper = np.minimum(lower, upper), np.maximum(lower, upper)
    jp = JointParams.from_float(lam=50.0, k_j=3.0, inertia=0.2, viscous=0.16, coulomb=1.0,
                                offset=0.0, v_smooth=2e-3, k_p=800.0, k_i=4000.0, k_d=20.0,
                                i_max=2e-4)
    cfg = {Config.MODE: mode, Config.TICK: TICK, Config.TIMEOUT: 3000,
           Config.RAMP: FORCE.encode(1.5), Config.TAU_MIN: FORCE.encode(-8.0),
           Config.TAU_MAX: FORCE.encode(8.0)}
    if safe is not None:
        cfg.update({Config.STOP_CYCLES: safe[0], Config.BRAKE_CYCLES: safe[1]})
        if len(safe) > 3:
            cfg.update({Config.STANDSTILL: safe[3], Config.STANDSTILL_TICKS: safe[4]})
        if len(safe) > 5:
            cfg[Config.STOP_TRAIL] = safe[5]
    packets = [(PacketType.CONFIG, p) for p in config_payloads(cfg)]
    packets += [(PacketType.PARAM, p) for p in vdc_upload(theta, K, rho, lower, upper)]
    packets += [(PacketType.PARAM, p) for p in joint_upload(jp)]
    packets += [(PacketType.CONFIG, p) for p in config_payloads({Config.ARM: 1})]
    return packets


def period_packets(rng, n):
    g = rng.normal(size=3)
    g *= 9.81 / np.linalg.norm(g)
    V = rng.normal(size=6) * 0.3
    b = pack_comm_b(0.31 + 0.01 * n, V, V + rng.normal(size=6) * 1e-3, prime=False)
    d = pack_comm_d(rng.uniform(-3, 3), g, joint_angle(2000 * (n + 1)) - 1e-4, 0.31, 0.8)
    return b, d


PERIOD, COMMIT, WINDOW = 2000, 1000, 300


def timing_config():
    return {Config.PERIOD: PERIOD, Config.COMMIT: COMMIT, Config.SYNC_WINDOW: WINDOW}


@pytest.mark.parametrize("mode, n_periods, end, safe", [
    (0, 2, 11_500, None), (1, 1, 9_500, None), (2, 1, 9_500, None),
    # the safe stop (STOP_CYCLES, BRAKE_CYCLES, re-arm cycle): hold, brake, STO, re-armed
    (0, 1, 13_000, (700, 500, 11_000)), (1, 1, 13_000, (400, 900, 11_000)),
    # re-armed while still holding (a VDC node holds on the PID words)
    (0, 1, 12_000, (3000, 2000, 9_400)),
    # with the standstill rule (+ STANDSTILL word, STANDSTILL_TICKS): the joint turns at
    # ~0.3 rad/s, within ±0.5 rad/s (a standstill: the brake after 5 ticks, long before
    # STOP_CYCLES), not within ±0.1 rad/s (the brake at the time limit, STOP_LIMIT)
    (1, 1, 13_000, (1500, 500, 11_000, VEL.encode(0.5), 5)),
    (0, 1, 13_000, (700, 500, 11_000, VEL.encode(0.1), 5)),
    # an explicit STOP_TRAIL 0: today's stop (the target each tick's count)
    (1, 1, 13_000, (700, 500, 11_000, VEL.encode(0.1), 5, 0))])
def test_exchange_ticks_and_watchdog_equal_the_reference(mode, n_periods, end, safe):
    _exchange(mode, n_periods, end, safe)


def decelerating_angle(cycle):
    """3 rad/s to cycle 10,000 (the watchdog trips before it), then a constant deceleration to
    rest at cycle 12,000 (rad)."""
    t, t0, t1 = cycle * 20e-9, 10_000 * 20e-9, 12_000 * 20e-9
    if t <= t0:
        return 0.2 + 3.0 * t
    dt = min(t, t1) - t0
    return 0.2 + 3.0 * t0 + 3.0 * dt - 0.5 * 3.0 / (t1 - t0) * dt * dt


def test_the_hold_follows_the_joint_to_rest_then_holds_where_it_stopped(monkeypatch):
    """The safe stop's stop (docs/node.md "Safe stop"): the joint still moves at 3 rad/s when
    the watchdog trips and slows to rest 40 µs later; until a hold tick sees the velocity
    within ±1 rad/s the hold's reference is each tick's count, then it is frozen, and the
    brake engages at standstill, not at the time limit. The core's torque, status and brake
    equal the reference's in every cycle."""
    monkeypatch.setattr(sys.modules[__name__], "joint_angle", decelerating_angle)
    trace, model = _exchange(1, 1, 16_000, (4000, 500, 15_000, VEL.encode(1.0), 5))
    trip = min(c for c in trace if trace[c][3] & Status.TRIPPED)
    assert abs(VEL.decode(trace[trip][1])) > 2.0          # moving at the trip
    # the reference held the count it stopped at, counts past the first hold tick's
    assert model.hold_fixed and model.hold_pos >> 4 > trace[trip][0] + 5
    engage = min(c for c in trace if trace[c][4])
    assert trip + 500 < engage < trip + 4000                # at standstill, after a stop
    assert not any(trace[c][3] & Status.STOP_LIMIT for c in trace)


def test_the_hold_trails_the_joint_by_stop_trail_then_holds(monkeypatch):
    """STOP_TRAIL = 2 counts: the joint (3 rad/s, ~0.38 counts a tick, slowing to rest) drives
    the hold's target, which trails the count by at most 2 counts, until a hold tick sees the
    velocity within ±1 rad/s; the target is frozen there, 2 counts behind the count it
    stopped at, and the brake engages at standstill. The core's torque, status and brake
    equal the reference's in every cycle."""
    monkeypatch.setattr(sys.modules[__name__], "joint_angle", decelerating_angle)
    trace, model = _exchange(1, 1, 16_000, (4000, 500, 15_000, VEL.encode(1.0), 5, 2))
    trip = min(c for c in trace if trace[c][3] & Status.TRIPPED)
    assert abs(VEL.decode(trace[trip][1])) > 2.0          # moving at the trip
    engage = min(c for c in trace if trace[c][4])
    assert trip + 500 < engage < trip + 4000                # at standstill, after a stop
    assert model.hold_fixed and model.hold_pos & 15 == 0    # a count
    assert trace[trip][0] + 3 < model.hold_pos >> 4 == trace[engage][0] - 2
    assert not any(trace[c][3] & Status.STOP_LIMIT for c in trace)


def steady_angle(cycle):
    """3 rad/s throughout (rad): never at rest."""
    return 0.2 + 3.0 * cycle * 20e-9


def test_a_joint_driven_through_the_trail_drags_the_target_to_the_limit(monkeypatch):
    """STOP_TRAIL = 3 counts, the joint driven on at 3 rad/s (not within ±0.5 rad/s): the
    target follows 3 counts behind the count at every tick after the joint has moved 3
    counts, to the time limit (STOP_LIMIT), where it freezes; RTL == reference every cycle."""
    monkeypatch.setattr(sys.modules[__name__], "joint_angle", steady_angle)
    trace, model = _exchange(0, 1, 13_000, (1500, 500, 11_000, VEL.encode(0.5), 5, 3))
    trip = min(c for c in trace if trace[c][3] & Status.TRIPPED)
    engage = min(c for c in trace if trace[c][4])
    assert engage == trip + 1500 and trace[engage][3] & Status.STOP_LIMIT
    assert model.hold_fixed and model.hold_pos & 15 == 0
    assert model.hold_pos >> 4 in (trace[engage][0] - 3, trace[engage][0] - 4)
    assert model.hold_pos >> 4 > trace[trip][0] + 5           # it moved ~11 counts


def test_disciplined_timer_equals_the_reference_and_never_overruns():
    """CONFIG TC_DISCIPLINE on (target phase 40, the time-codes at phase 20: e = −20, kp 0 and
    ki 2 shorten the period by about 25 cycles, :func:`~protocol.discipline.loop_step`): torque,
    status, replies and every strobe equal the reference's in every cycle; the boundaries
    move off the PERIOD grid by the loop's adjustment; and no control tick is skipped, though
    the last tick of a period so shortened would still be running at its boundary (the tail
    rule: no tick within TICK cycles before a disciplined boundary)."""
    word = Discipline(target=40, kp=0, ki=2).word
    trace, model, replies = _exchange(1, 2, 11_500, None, discipline=word)
    tc = min(c for c, f in model.events if f == NodeEvent.TIMECODE)
    b = model.boundaries
    k = max(i for i, x in enumerate(b) if x <= tc)
    _, _, adj = loop_step(word, tc - b[k], 0, 0)
    assert b[k + 1] - b[k] == PERIOD + adj and adj < -2
    assert all(parse_comm_a(r[2])["overruns"] == 0 for r in replies
               if r[0] == PacketType.COMM_A)


def _exchange(mode, n_periods, end, safe, discipline=None):
    """mode 0 VDC, 1 PID, 2 torque-only. Periods of 2000 cycles on the node's own timer; the
    time-codes arrive inside the window, the last period has a late Comm D and an
    out-of-window time-code (a resynchronisation), then the master falls silent. With
    ``safe``, the node's safe stop runs after the trip and an ARM at cycle ``safe[2]``
    re-arms it."""
    dut = NodeCore(encoder=ENC)
    rng = np.random.default_rng(0)
    trace = {}              # cycle -> (count, velocity, torque, status, errors)
    strobes = []            # (cycle, NodeEvent) of the observation port
    events = []             # (cycle, kind)
    replies = []            # (request type, header, payload)
    period_starts = []
    marks = {}

    async def encoder_lines(ctx):
        for c in range(end + 10):
            cnt = math.floor(joint_angle(c + 1) * K_RAD)
            a, b = quadrature_levels(np.array([cnt]))
            ctx.set(dut.enc_a, int(a[0]))
            ctx.set(dut.enc_b, int(b[0]))
            await ctx.tick()

    async def monitor(ctx):
        for c in range(end):
            _, _, cnt, vel, tq, st, valid, ready, last, ps, ev, br = await ctx.tick().sample(
                dut.count, dut.velocity, dut.torque, dut.status, dut.rx.valid, dut.rx.ready,
                dut.rx.p.last, dut.period_start, dut.events, dut.brake)
            trace[c] = (cnt, vel, tq, st, br)
            if ev:
                strobes.extend((c, f) for f in NodeEvent if ev & f)
            if valid and ready and last:
                events.append((c, "packet"))
            if ps:
                events.append((c, "timecode"))

    sent = []
    timecodes = []

    async def send(ctx, ptype, payload, seq=0):
        header = Header(dest=1, src=0, type=int(ptype), seq=seq)
        await put_packet(ctx, dut.rx, header, payload)
        sent.append((int(ptype), bytes(payload)))

    async def wait_until(ctx, cycle):
        while ctx.get(dut_cycle) < cycle:
            await ctx.tick()

    async def timecode(ctx, value):
        ctx.set(dut.period, value)
        ctx.set(dut.period_start, 1)
        timecodes.append(value)
        await ctx.tick()
        ctx.set(dut.period_start, 0)

    async def master(ctx):
        ctx.set(dut.period, 0)
        timing = timing_config()
        if discipline is not None:
            timing[Config.TC_DISCIPLINE] = discipline
        for ptype, payload in [(PacketType.CONFIG, p) for p in
                               config_payloads(timing)] + uploads(mode, safe):
            await send(ctx, ptype, payload)
        marks["armed_sent"] = ctx.get(dut_cycle)
        first = (ctx.get(dut_cycle) // PERIOD + 1) * PERIOD
        for n in range(n_periods + 1):
            start = first + PERIOD * n
            period_starts.append(start)
            last = n == n_periods
            await wait_until(ctx, start + 20)
            await timecode(ctx, n + 1)                 # inside the window: no resync
            await ctx.tick().repeat(40)
            await send(ctx, PacketType.COMM_A, b"\0", seq=3 * n)
            replies.append((PacketType.COMM_A, *await get_packet(ctx, dut.tx)))
            b, d = period_packets(rng, n)
            await send(ctx, PacketType.COMM_B, b)
            await send(ctx, PacketType.COMM_C, b"\0", seq=3 * n + 1)
            replies.append((PacketType.COMM_C, *await get_packet(ctx, dut.tx)))
            if last:
                await wait_until(ctx, start + COMMIT + 200)
                marks["late_d"] = start
            await send(ctx, PacketType.COMM_D, d)
            if last:
                await wait_until(ctx, start + COMMIT + 500)
                await timecode(ctx, 63)                # outside the window: resync
                await ctx.tick().repeat(60)
                await send(ctx, PacketType.COMM_A, b"\0", seq=99)
                replies.append((PacketType.COMM_A, *await get_packet(ctx, dut.tx)))
        if safe is not None:
            await wait_until(ctx, safe[2])
            for p in config_payloads({Config.ARM: 1}):
                await send(ctx, PacketType.CONFIG, p)

    from amaranth import Signal
    dut_cycle = Signal(32)

    async def counter(ctx):
        for c in range(end + 10):
            ctx.set(dut_cycle, c + 1)
            await ctx.tick()

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_process(encoder_lines)
    sim.add_process(counter)
    sim.add_testbench(monitor)
    sim.add_testbench(master, background=True)
    run_simulation(sim, "node_core")

    # --- replay on the reference: every cycle's torque and status, every reply ---------------
    model = NodeModel(encoder=ENC, events=[])
    packets, tcs = iter(sent), iter(timecodes)
    by_cycle = {}
    for c, kind in events:
        by_cycle.setdefault(c, []).append(kind)

    def sample(c):
        return trace[c][0], trace[c][1], 0

    ref_replies = []
    for c in range(end - 1):
        model.run(c, sample)
        assert model.torque_at(c) == trace[c][2], f"torque in cycle {c}"
        assert model.brake_at(c) == trace[c][4], f"brake in cycle {c}"
        # FRESH rises when the VDC passes its MARK, the model has the forces at once; CONFIG
        # records apply as their bytes arrive, in the model at the packet's end (so compare
        # after the uploads)
        if c >= period_starts[0]:
            assert int(model.status) & ~Status.FRESH == trace[c][3] & ~Status.FRESH, \
                f"status in cycle {c}"
        model.run(c + 1)
        for kind in sorted(by_cycle.get(c, []), reverse=True):     # time-code first
            if kind == "timecode":
                model.timecode(c, next(tcs))
            else:
                ptype, payload = next(packets)
                reply = model.packet(c, ptype, payload)
                if reply is not None:
                    ref_replies.append(reply)
    assert [r[2] for r in replies] == ref_replies
    # the observation port: every strobe of the gateware is the reference's, cycle for cycle
    # (boundaries and the resync, packets, VDC start / MARK / end, replies leaving, commits)
    def upto(events):                   # the replay ran the model to cycle end - 2
        return sorted(e for e in events if e[0] < end - 1)

    assert upto(strobes) == upto(model.events)
    kinds = {f for _, f in strobes}
    assert {NodeEvent.BOUNDARY, NodeEvent.RX_A, NodeEvent.TX_A, NodeEvent.RX_D,
            NodeEvent.COMMIT} <= kinds
    if mode == 0:
        assert {NodeEvent.RX_B, NodeEvent.VDC_START, NodeEvent.VDC_DONE, NodeEvent.VDC_END,
                NodeEvent.RX_C, NodeEvent.TX_C} <= kinds
    assert NodeEvent.RESYNC in kinds
    if discipline is not None:
        return trace, model, replies

    # Boundaries on the timer's grid from reset, plus the resynchronisation.
    resync = max(c for c, kind in events if kind == "timecode")
    assert resync - resync // PERIOD * PERIOD >= WINDOW
    assert [b for b in model.boundaries if b < resync] == \
        list(range(0, resync, PERIOD))
    assert resync in model.boundaries
    # ARM takes effect at the first boundary after it arrived.
    armed = [c for c in range(end) if trace[c][3] & Status.ARMED]
    assert armed[0] == period_starts[0] + 1 and armed[0] - 1 > marks["armed_sent"]
    # Comm A reports the snapshot at the boundary, not at the request.
    a = parse_comm_a(replies[0][2])
    assert a["count"] == trace[period_starts[0]][0]
    assert a["period"] == 1 and a["sync_errors"] == 0 and a["late_d"] == 0
    first_a = next(i for i, (t, _) in enumerate(sent) if t == PacketType.COMM_A)
    ups = [p for t, p in sent[:first_a] if t in (PacketType.CONFIG, PacketType.PARAM)]
    assert (a["upload_crc"], a["upload_count"]) == (crc16(b"".join(ups)), len(ups))
    F_a, F_b, status, per = parse_comm_c(replies[1][2])
    assert status & Status.FRESH and per == 1
    assert replies[1][1].seq == 1 and replies[1][1].type == PacketType.COMM_C
    # The late Comm D and the resynchronisation are counted.
    last_a = parse_comm_a(replies[-1][2])
    assert last_a["sync_errors"] == 1 and last_a["late_d"] == 1 and last_a["period"] == 63
    assert last_a["count"] == trace[resync][0]
    if mode == 2:
        # torque-only: τ = τ_D, committed at phase COMMIT; the tick at COMMIT still has the old
        # word, the next one the new, which lands cycles("torque") + 1 later.
        from mrm_cosim.protocol.joint_program import joint_microcode

        land = period_starts[0] + COMMIT + TICK + joint_microcode().cycles("torque") + 1
        d0 = period_packets(np.random.default_rng(0), 0)[1]
        tau_d = int.from_bytes(d0[:3], "little", signed=True)
        assert trace[land][2] == tau_d != trace[land - 1][2]
    if safe is not None:
        check_safe_stop(trace, safe, end)
        return trace, model
    # Master silent after the last period: the watchdog trips and the torque ramps to zero.
    st_end = trace[end - 1][3]
    assert st_end & Status.TRIPPED and st_end & Status.SAFE
    assert trace[end - 1][2] == 0
    trip = min(c for c in trace if trace[c][3] & Status.TRIPPED)
    assert trip > period_starts[-1]


def check_safe_stop(trace, safe, end):
    """The safe stop's sequence in a gateware trace: HOLD from the trip with the commands
    still landing, BRAKE from STOP cycles on (or, with a standstill threshold the joint's
    speed is within, from the cycle after STANDSTILL_TICKS ticks of the hold, and STOP_LIMIT
    never), HOLD until BRAKE cycles after the brake, then STO (SAFE once the torque is zero)
    until the ARM's boundary releases it all."""
    stop, brake = safe[:2]
    trip = min(c for c in trace if trace[c][3] & Status.TRIPPED)
    rearmed = min(c for c in range(trip, end) if not trace[c][3] & Status.TRIPPED)
    hold = [c for c in range(trip, rearmed) if trace[c][3] & Status.HOLD]
    braked = [c for c in range(trip, rearmed) if trace[c][4]]
    limit = [c for c in range(trip, rearmed) if trace[c][3] & Status.STOP_LIMIT]
    engage = trip + stop
    if len(safe) > 3 and braked and braked[0] < engage:
        engage = braked[0]                              # standstill: ticks of the hold
        assert engage >= trip + (safe[4] - 1) * TICK
        if abs(VEL.decode(trace[trip][1])) <= VEL.decode(safe[3]):     # from the first tick
            assert engage <= trip + safe[4] * TICK + 1
        assert not limit
    elif len(safe) > 3:
        assert limit == list(range(engage, rearmed))
    else:
        assert not limit
    assert hold == list(range(trip, min(engage + brake, rearmed)))
    assert braked == list(range(engage, rearmed))
    assert all(bool(trace[c][3] & Status.BRAKE) == bool(trace[c][4]) for c in trace)
    torques = {trace[c][2] for c in hold}
    assert len(torques) > 2                             # the hold loop acts, tick by tick
    if trip + stop + brake < rearmed:                   # STO: ramped to zero, SAFE
        assert trace[rearmed - 1][2] == 0 and trace[rearmed - 1][3] & Status.SAFE
        assert not any(trace[c][3] & Status.SAFE for c in hold)
    after = range(rearmed, end)
    assert all(trace[c][3] & Status.ARMED and not trace[c][4] and
               not trace[c][3] & (Status.HOLD | Status.BRAKE) for c in after)


def test_pack_words_is_each_word_in_three_bytes():
    """pack_words (one integer, one conversion) against the word-by-word definition: any
    ints (numpy's too, out of range wrapped to 24 bits), any iterable, none at all."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from mrm_cosim.protocol.regs import pack_words, unpack_words

    def by_word(words):
        return b"".join((int(w) & 0xFFFFFF).to_bytes(3, "little") for w in words)

    @settings(max_examples=300, deadline=None)
    @given(st.lists(st.one_of(st.integers(-(1 << 23), (1 << 23) - 1),
                              st.sampled_from([-(1 << 23), (1 << 23) - 1, 0, -1]),
                              st.integers(-(1 << 40), 1 << 40)), max_size=14))
    def check(words):
        out = pack_words(words)
        assert out == by_word(words) == pack_words(iter(words)) == pack_words(tuple(words))
        assert out == pack_words(np.array(words, dtype=np.int64))
        assert unpack_words(out, len(words)) == [
            ((w & 0xFFFFFF) ^ 0x800000) - 0x800000 for w in words]

    check()


def test_payload_helpers_round_trip_and_refuse_bad_uploads():
    from mrm_cosim.protocol.fixed import VEL
    from mrm_cosim.protocol.regs import Bank, param_payloads, unpack_words
    from mrm_cosim.errors import InputError

    b = pack_comm_b(0.5, [1, 2, 3, 4, 5, 6], [-1, -2, -3, -4, -5, -6], prime=True)
    assert len(b) == 40 and b[-1] == 1
    w = unpack_words(b, 13)
    assert w[0] == VEL.encode(0.5) and w[7] == VEL.encode(-1) and w[12] == VEL.encode(-6)
    runs = param_payloads(Bank.VDC, {5: 1, 6: -1, 7: 2, 100: 3})
    assert [p[:3] for p in runs] == [bytes([0, 5, 0]), bytes([0, 100, 0])]
    assert unpack_words(runs[0], 3, 3) == [1, -1, 2]
    theta = load_robot("mrm3").nominal_theta[0]
    with pytest.raises(InputError, match="lower ≤ theta"):
        vdc_upload(theta, np.ones((2, 6)), np.zeros((2, 13)), theta * 1.1 + 1, theta * 1.2 + 2)
    with pytest.raises(InputError, match=r"vdc.K\[0\]\[0\]"):
        vdc_upload(theta, np.full((2, 6), 1e5), np.zeros((2, 13)), theta - 1, theta + 1)


def _random_upload(rng):
    """A CONFIG or PARAM payload of random length and bytes that leaves the node's behaviour
    alone (CONFIG records with ids no register has; PARAM words anywhere)."""
    n = int(rng.integers(1, 41))
    data = bytearray(rng.integers(0, 256, n, dtype=np.uint8).tobytes())
    if rng.random() < 0.5:
        for k in range(0, n, 5):
            data[k] = int(rng.choice([0, *range(13, 256)]))
        return PacketType.CONFIG, bytes(data)
    return PacketType.PARAM, bytes(data)


def test_upload_crc_and_count_equal_the_link_crc_over_the_payloads():
    """Random CONFIG / PARAM uploads with Comm D packets (not counted) between them and bytes
    offered with idle gaps; every Comm A reports the CRC-16 of the concatenated upload payloads
    (the link's CRC reference, computed here from the bytes) and their count, as the request
    found them, equal to the reference model's reply; one dropped or corrupted upload changes
    the CRC (and a dropped one the count)."""
    from mrm_cosim.protocol.regs import upload_check

    rng = np.random.default_rng(5)
    plan = []                       # (type, payload) in order
    for _ in range(4):
        for _ in range(int(rng.integers(1, 5))):
            plan.append(_random_upload(rng))
            if rng.random() < 0.3:
                plan.append((PacketType.COMM_D, rng.integers(0, 256, 40, dtype=np.uint8)
                             .tobytes()))
        plan.append((PacketType.COMM_A, b"\0"))
    dut = NodeCore(encoder=ENC)
    ends = []
    replies = []

    async def master(ctx):
        send_rng = np.random.default_rng(6)
        for i, (ptype, payload) in enumerate(plan):
            await put_packet(ctx, dut.rx, Header(dest=1, src=0, type=int(ptype), seq=i),
                             payload, rng=send_rng, p_idle=0.2)
            if ptype == PacketType.COMM_A:
                replies.append(await get_packet(ctx, dut.tx))

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(packet_ends(dut.rx, ends), background=True)
    sim.add_testbench(master)
    run_simulation(sim, "node_core_upload")

    model = NodeModel(encoder=ENC)
    ref_replies = []
    for c, (ptype, payload) in zip(ends, plan, strict=True):
        r = model.packet(c, ptype, payload, sample=lambda _c: (0, 0, 0))
        if r is not None:
            ref_replies.append(r)
    assert [p for _, p in replies] == ref_replies
    k = 0
    for i, (ptype, _) in enumerate(plan):
        if ptype != PacketType.COMM_A:
            continue
        ups = [p for t, p in plan[:i] if t in (PacketType.CONFIG, PacketType.PARAM)]
        a = parse_comm_a(replies[k][1])
        assert replies[k][0].seq == i
        assert (a["upload_crc"], a["upload_count"]) == (crc16(b"".join(ups)), len(ups))
        assert upload_check(ups) == (a["upload_crc"], a["upload_count"])
        # what the master would expect had one upload been lost or corrupted on the way
        j = int(rng.integers(len(ups)))
        assert upload_check(ups[:j] + ups[j + 1:]) != (a["upload_crc"], a["upload_count"])
        bad = bytearray(ups[j])
        bad[int(rng.integers(len(bad)))] ^= 1 << int(rng.integers(8))
        assert upload_check(ups[:j] + [bytes(bad)] + ups[j + 1:])[0] != a["upload_crc"]
        k += 1
    assert k == 4


def test_references_run_on_across_the_boundary_until_the_next_commit():
    """A Comm D's references are for the start of the period it arrived in. Between the next
    boundary and the next commit point the ticks still use them, so their time keeps counting
    from that start: the interpolated velocity reference grows steadily through the boundary
    (before the fix it fell back by a whole period's acceleration there)."""
    model = NodeModel(encoder=ENC)
    sample = lambda c: (0, 0, 0)        # noqa: E731 - a joint at rest
    for k, (ptype, payload) in enumerate([(PacketType.CONFIG, p)
                                          for p in config_payloads(timing_config())]
                                         + uploads(mode=1)):
        model.packet(10 + k, ptype, payload, sample=sample)
    model.run(PERIOD + 1, sample)                   # ARM takes effect at the boundary
    assert model.armed
    d = pack_comm_d(0.0, [0.0, 0.0, 9.81], 0.0, 0.5, 40.0)      # q̈_d0 = 40 rad/s²
    model.packet(PERIOD + 200, PacketType.COMM_D, d, sample=sample)
    v = {}
    for c in range(PERIOD + COMMIT + TICK, 2 * PERIOD + COMMIT, TICK):
        model.run(c + 1, sample)
        v[c] = model.joint.v_des
    steps = np.diff([v[c] for c in sorted(v)])
    assert steps.min() > 0, "the reference must not step back at the boundary"
    assert steps.max() - steps.min() <= 2                 # rounding of the two products only
    assert model.d_base == PERIOD
