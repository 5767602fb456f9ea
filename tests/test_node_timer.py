# amaranth: UnusedElaboratable=no
"""The period timer and its time-code discipline: RTL == the timer reference
(:class:`~hdl.node.timer_ref.TimerModel`) cycle by cycle, over time-code sequences from a master
whose period is off by a few cycles (drift), with jitter, lost time-codes and register writes;
the loop's arithmetic against its closed form; the register word."""

import math

import pytest
from amaranth.sim import Simulator
from hypothesis import given, settings
from hypothesis import strategies as st

from mrm_cosim.errors import InputError
from mrm_cosim.hdl.node.timer import PeriodTimer
from mrm_cosim.hdl.node.timer_ref import TimerModel
from mrm_cosim.protocol.discipline import (FRAC, LATENCY, STEP_MAX, Discipline, arrival,
                                           loop_step)
from mrm_cosim.testbench import run_simulation

PERIOD, TICK = 256, 16


def arrivals(n, drift, latency, jitter, lost=()):
    """Cycles of the time-codes of a master whose period is ``PERIOD + drift`` cycles of the
    node's clock: ``latency`` + ``jitter[k]`` after each of its period starts (k ≥ 1)."""
    return [k * (PERIOD + drift) + latency + jitter[k % len(jitter)]
            for k in range(1, n + 1) if k not in lost]


def run_both(cycles, timecodes, writes, window):
    """``writes``: {cycle: TC_DISCIPLINE word}. Per cycle (phase, boundary, resync,
    pre_boundary, tail) of the gateware and of the reference."""
    dut = PeriodTimer()
    ref = TimerModel(period=PERIOD, window=window, tick=TICK, armed=True)
    tcs = set(timecodes)
    rtl, exp = [], []

    async def tb(ctx):
        for name, value in (("period", PERIOD), ("window", window), ("tick", TICK)):
            ctx.set(getattr(dut, name), value)
        ctx.set(dut.window_next, window)
        ctx.set(dut.pm1_next, PERIOD - 1)
        ctx.set(dut.pmw_next, PERIOD - window)
        ctx.set(dut.pmt_next, PERIOD - TICK + 1)
        ctx.set(dut.armed, 1)
        for c in range(cycles):
            tc = c in tcs
            ctx.set(dut.time_code, tc)
            ctx.set(dut.restart, c in writes)
            rtl.append((ctx.get(dut.phase), ctx.get(dut.boundary), ctx.get(dut.resync),
                        ctx.get(dut.pre_boundary), ctx.get(dut.tail)))
            ph = ref.phase(c)
            resync = tc and arrival(ref.word, ph, window, ref.period + ref.adj)[0]
            exp.append((ph, int(ph == 0 or resync), int(resync), int(ref.rem(c) == 1),
                        int(ref.tail(c))))
            if tc:
                ref.timecode(c)
            if c in writes:
                ref.config(c, writes[c])
            await ctx.tick()
            if c in writes:
                ctx.set(dut.discipline.as_value(), writes[c])

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(tb)
    run_simulation(sim, "timer")
    return rtl, exp, ref


def assert_same(rtl, exp):
    for c, (r, e) in enumerate(zip(rtl, exp, strict=True)):
        assert r == e, f"cycle {c}: RTL (phase, boundary, resync, pre, tail) {r} != ref {e}"


@settings(max_examples=12, deadline=None)
@given(drift=st.integers(-4, 4), latency=st.integers(0, 30), target=st.integers(0, 40),
       kp=st.integers(0, 4), ki=st.integers(0, 7),
       jitter=st.lists(st.integers(0, 3), min_size=1, max_size=7),
       window=st.sampled_from([24, 60, 200]),
       lost=st.sets(st.integers(1, 24), max_size=3))
def test_rtl_equals_reference_over_drifting_time_codes(drift, latency, target, kp, ki, jitter,
                                                       window, lost):
    word = Discipline(target=target, kp=kp, ki=ki).word
    tcs = arrivals(24, drift, latency, jitter, lost)
    rtl, exp, _ = run_both(25 * PERIOD, tcs, {3: word}, window)
    assert_same(rtl, exp)


def test_rtl_equals_reference_with_the_loop_rewritten_and_switched_off():
    """A rewrite clears the loop mid-period (the period's length back to PERIOD at once), a
    write of 0 stops it: from then on the free-running timer, drifting into resyncs."""
    w = Discipline(target=12, kp=1, ki=4).word
    tcs = arrivals(30, 5, 10, [0, 2, 1])
    rtl, exp, ref = run_both(31 * PERIOD, tcs, {5: w, 8 * PERIOD + 100: w,
                                                15 * PERIOD + 40: 0}, 60)
    assert_same(rtl, exp)
    assert ref.resyncs, "off again, the drift of 5 cycles per period must leave the window"


def test_rtl_equals_reference_with_time_codes_and_a_write_during_a_step():
    """The loop's step takes LATENCY cycles (serial shifts for the gains): its adj applies
    then; a time-code during it is not taken (three here, one cycle after the step's start,
    and LATENCY − 1 and LATENCY − 2 after it), one LATENCY after is; a rewrite during a step
    drops it."""
    w = Discipline(target=12, kp=0, ki=1).word
    base = arrivals(12, 3, 10, [0, 2, 1])
    busy = [base[2] + 1, base[3] + LATENCY - 1, base[6] + LATENCY - 2]
    tcs = sorted(base + busy + [base[4] + LATENCY])
    rtl, exp, ref = run_both(13 * PERIOD, tcs, {3: w, base[5] + 4: w}, 60)
    assert_same(rtl, exp)
    assert not ref.resyncs
    assert len(ref.errors) == len(base) + 1             # all but the three during a step
    assert len(ref.rates) == len(base)                  # and the one the rewrite dropped


def test_off_is_the_free_running_timer():
    """TC_DISCIPLINE 0: boundaries every PERIOD cycles from reset, a time-code outside the
    window re-synchronises, never a tail."""
    tcs = arrivals(12, -5, 2, [0])
    rtl, exp, ref = run_both(13 * PERIOD, tcs, {}, 40)
    assert_same(rtl, exp)
    assert not any(r[4] for r in rtl)
    # the master's period is 5 cycles short: every time-code comes before the node's boundary
    # (phase PERIOD − 3, outside the window) and re-synchronises: a short period each time
    assert ref.resyncs == tcs
    b = ref.boundaries
    assert b[0] == 0
    steps = list(zip(b[1:], b[2:], strict=False))
    assert all(y - x == PERIOD for x, y in steps if y not in ref.resyncs)
    assert all(y - x == PERIOD - 5 for x, y in steps if y in ref.resyncs)


def test_a_resync_with_the_loop_on_restarts_at_the_target_and_locks():
    """A slow node (the master's period 5 cycles shorter) that left reset 100 cycles late: off,
    it re-synchronises at every time-code (test above); on, the first time-code re-synchronises
    it with the phase restarted at the target, and from then on every time-code arrives in
    the window and the loop takes up the drift."""
    w = Discipline(target=10, kp=1, ki=4).word
    tcs = [c - 100 for c in arrivals(24, -5, 10, [0, 3, 1, 2])]
    rtl, exp, ref = run_both(25 * PERIOD, tcs, {2: w}, 40)
    assert_same(rtl, exp)
    assert ref.resyncs == tcs[:1]
    assert max(abs(e) for e in ref.errors[-10:]) <= 3


@pytest.mark.parametrize("drift", [-5, 5])
def test_locked_loop_holds_the_arrival_at_the_target(drift):
    """With the loop on, a drift of ±5 cycles per period (100 ppm of a 50,000-cycle period)
    is taken up by the rate estimate: the arrival phase settles at the target, the rate
    estimate at the drift (FRAC fraction bits), and no resync once locked."""
    w = Discipline(target=20, kp=2, ki=4).word
    ref = TimerModel(period=PERIOD, window=60, tick=TICK, armed=True)
    ref.config(1, w)
    for c in arrivals(200, drift, 20, [0]):
        ref.timecode(c)
    assert ref.errors[-50:] == [0] * 50
    assert ref.f >> FRAC in (drift - 1, drift)
    assert abs(ref.f - drift * (1 << FRAC)) < (1 << FRAC)
    assert not [r for r in ref.resyncs if r > 20 * PERIOD]


@settings(max_examples=200, deadline=None)
@given(phase=st.integers(-(1 << 13), 1 << 13), target=st.integers(0, 4095),
       kp=st.integers(0, 7), ki=st.integers(0, 7), f=st.integers(-(1 << 15), (1 << 15) - 1),
       a=st.integers(0, 255))
def test_loop_step_is_its_closed_form(phase, target, kp, ki, f, a):
    """The loop's step in real numbers: e saturated to [−128, 128), the phase step the floored
    share 2^−kp of it, the rate estimate + e·2^(8−ki) (floored, saturated to 16 bits;
    unchanged where e saturated), and the period's adjustment the integer carry of fraction
    + rate, plus the step; the fraction keeps the rest, so adj + a/256 = step + (a_old +
    f_new)/256 exactly."""
    f2, a2, adj = loop_step(Discipline(target=target, kp=kp, ki=ki).word, phase, f, a)
    e = max(-STEP_MAX, min(STEP_MAX - 1, phase - target))
    step = math.floor(e / 2**kp)
    expect_f = f if e != phase - target else \
        max(-(1 << 15), min((1 << 15) - 1, f + math.floor(e * 256 / 2**ki)))
    assert f2 == expect_f
    assert 0 <= a2 < 256
    assert (adj - step) * 256 + a2 == a + f2
    assert abs(adj - math.floor((a + f2) / 256)) <= STEP_MAX >> kp


def test_word_round_trips_and_rejects_bad_fields():
    d = Discipline(target=4095, kp=7, ki=3, enable=True)
    assert Discipline.from_word(d.word) == d
    assert d.word < (1 << 19)
    assert Discipline.from_word(0) == Discipline(0, 0, 0, False)
    with pytest.raises(InputError, match="discipline.target"):
        Discipline(target=4096)
    with pytest.raises(InputError, match="discipline.ki"):
        Discipline(ki=-1)


@pytest.mark.parametrize("window", [24, 60])
def test_rtl_equals_reference_with_time_codes_at_the_early_windows_edge(window):
    """Time-codes just inside, at and just outside the early side of the two-sided window
    (``rem`` = SYNC_WINDOW − 1, SYNC_WINDOW, SYNC_WINDOW + 1 cycles before the boundary): the
    window compare against its registered threshold (``PERIOD + adj − SYNC_WINDOW``)
    decides take or resync in the cycle the reference does."""
    word = Discipline(target=0, kp=7, ki=7).word
    tcs, c = [], 0
    for k in range(1, 25):
        c = k * PERIOD - (window - 1 + k % 3)
        tcs.append(c)
    rtl, exp, _ = run_both(26 * PERIOD, tcs, {3: word}, window)
    assert_same(rtl, exp)


@pytest.mark.parametrize("window", range(118, 136, 2))
def test_rtl_equals_reference_with_a_time_code_where_the_new_adj_moves_the_threshold(window):
    """A loop step's new ``adj`` moves the early window's threshold (``PERIOD + adj −
    SYNC_WINDOW``) in the cycle a second time-code arrives, at a phase on that threshold for
    one of these windows: the registered window flags are formed from the next threshold,
    not the one in force (an off-by-a-cycle there passes the drifting cases, fails here)."""
    word = Discipline(target=118, kp=0, ki=7).word
    tcs = [PERIOD + 120, PERIOD + 120 + LATENCY, 2 * PERIOD + 125, 2 * PERIOD + 125 + LATENCY]
    rtl, exp, _ = run_both(4 * PERIOD, tcs, {3: word}, window)
    assert_same(rtl, exp)
