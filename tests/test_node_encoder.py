# amaranth: UnusedElaboratable=no
"""Quadrature encoder interface: RTL == cycle-level reference; estimator accuracy."""

import numpy as np
import pytest
from amaranth.sim import Simulator
from hypothesis import given, settings
from hypothesis import strategies as st

from mrm_cosim.hdl.node.encoder import QuadratureEncoder
from mrm_cosim.hdl.node.encoder_ref import VEL_LATENCY, EncoderModel, reciprocal, velocity_word
from mrm_cosim.protocol.encoder import AGE_MAX, EncoderParams
from mrm_cosim.protocol.fixed import VEL
from mrm_cosim.models.encoder import counts_per_rad, quadrature_levels

from mrm_cosim.testbench import run_simulation

CYCLE = 20e-9
K = float(counts_per_rad(800_000))


def lines_for(q_of_t, n):
    """Line levels for n cycles of a joint angle function (rad of s), as the plant drives."""
    t = np.arange(1, n + 1) * CYCLE
    c = np.floor(q_of_t(t) * K).astype(np.int64)
    assert np.all(np.abs(np.diff(c)) <= 1)
    a, b = quadrature_levels(c)
    return a.astype(int), b.astype(int), c


def run_ref(params, a, b, sample_every, presets=None):
    enc = EncoderModel(params)
    presets = presets or {}
    out = []
    for k in range(len(a)):
        enc.cycle(int(a[k]), int(b[k]), sample=(k % sample_every == 0), preset=presets.get(k))
        out.append((enc.count, enc.velocity, enc.errors))
    return out


def run_rtl(params, a, b, sample_every, name, presets=None):
    dut = QuadratureEncoder(params)
    presets = presets or {}
    out = []

    async def tb(ctx):
        for k in range(len(a)):
            ctx.set(dut.a, int(a[k]))
            ctx.set(dut.b, int(b[k]))
            ctx.set(dut.sample, int(k % sample_every == 0))
            ctx.set(dut.preset, int(k in presets))
            ctx.set(dut.preset_count, presets.get(k, 0))
            await ctx.tick()
            out.append((ctx.get(dut.count), ctx.get(dut.velocity), ctx.get(dut.errors)))

    sim = Simulator(dut)
    sim.add_clock(CYCLE)
    sim.add_testbench(tb)
    run_simulation(sim, name)
    return out


def test_reciprocal_and_velocity_word():
    for den in [1, 2, 3, 1000, 2048, 65537, 10**6, AGE_MAX]:
        y1, p = reciprocal(den)
        assert abs(y1 * 2.0**(-17 - p) * den - 1) < 2.5e-5
    kv = EncoderParams().kv
    # 1 count per 65 cycles is 392.7/65 rad/s.
    assert abs(VEL.decode(velocity_word(16, 16 * 65, kv)) - 392.699 / 65) < 1e-4


@pytest.mark.parametrize("name, q_of_t, n", [
    ("fast", lambda t: 0.3 + 5.5 * t, 5_000),                         # near max speed
    ("slow_start", lambda t: 5e7 * t**3, 8_000),                      # a fast rest-to-move
    ("reversal", lambda t: 1e-3 * np.sin(2 * np.pi * 1e4 * t), 6_000),
    ("stop", lambda t: 0.01 + 4.0 * np.minimum(t, 4e-5), 6_000),
])
def test_rtl_equals_reference(name, q_of_t, n):
    params = EncoderParams(min_window=256, stop_cycles=3_000)
    a, b, c = lines_for(q_of_t, n)
    presets = {5: int(c[0]), n // 2: -12345}
    out = run_rtl(params, a, b, 50, f"encoder_{name}", presets)
    assert out == run_ref(params, a, b, 50, presets)


def test_rtl_equals_reference_when_the_count_difference_saturates():
    """0.38 counts per cycle over a 2048-cycle window: more than 512 counts between samples."""
    params = EncoderParams(min_window=2048, stop_cycles=3_000)
    a, b, _ = lines_for(lambda t: 150.0 * t, 7_000)
    out = run_rtl(params, a, b, 2500, "encoder_saturating")
    assert out == run_ref(params, a, b, 2500)
    assert any(o[1] != 0 for o in out)


@settings(max_examples=8, deadline=None)
@given(seq=st.lists(st.tuples(st.integers(0, 1), st.integers(0, 1), st.integers(1, 40)),
                    min_size=5, max_size=60),
       filt=st.integers(1, 4), every=st.integers(1, 60))
def test_rtl_equals_reference_on_glitches_and_illegal_steps(seq, filt, every):
    """Arbitrary line levels held for 1..40 cycles: glitches, illegal jumps, any strobe rate."""
    a = np.concatenate([[x] * n for x, _, n in seq])
    b = np.concatenate([[y] * n for _, y, n in seq])
    params = EncoderParams(filter_cycles=filt, min_window=64, stop_cycles=500)
    assert run_rtl(params, a, b, every, "encoder_glitch") == run_ref(params, a, b, every)


def test_glitch_shorter_than_filter_is_ignored_and_illegal_steps_counted():
    params = EncoderParams(filter_cycles=3)
    a = [0] * 10 + [1] * 2 + [0] * 10 + [1] * 10 + [0] * 10   # 2-cycle glitch, then a real edge
    b = [0] * 32 + [1] * 10                                   # A falls as B rises: illegal
    out = run_ref(params, a, b, 1000)
    assert out[25][0] == 0                  # glitch filtered out
    assert out[38][0] == 1                  # edge seen (2 sync + 3 filter cycles later)
    assert out[-1][2] == 1                  # one illegal transition, count unchanged
    assert out[-1][0] == 1


@pytest.mark.parametrize("speed", [6.0, 1.0, 0.1, 0.01])
def test_estimate_accuracy_at_constant_speed(speed):
    """After settling, the estimate is within 0.2 % (plus one VEL LSB) of the true speed."""
    n = int(max(4 / (speed * K) / CYCLE, 4 * EncoderParams().min_window))
    q0 = 0.123
    enc = EncoderModel(EncoderParams())
    t = np.arange(1, n + 1) * CYCLE
    c = np.floor((q0 + speed * t) * K).astype(np.int64)
    a, b = quadrature_levels(c)
    for k in range(n):
        enc.cycle(int(a[k]), int(b[k]), sample=(k % 50 == 0))
    assert abs(enc.velocity_rad_s - speed) <= 2e-3 * speed + VEL.resolution


def test_estimate_decays_to_zero_after_stop():
    params = EncoderParams(stop_cycles=100_000)
    a, b, _ = lines_for(lambda t: 0.05 + 2.0 * np.minimum(t, 2e-4), 140_000)
    out = run_ref(params, a, b, 50)
    v = [VEL.decode(o[1]) for o in out]
    assert abs(v[9_000] - 2.0) < 0.01                 # moving
    assert 0 < v[60_000] < 0.2                        # bounded by 1 count / time since edge
    assert v[-1] == 0.0                               # stopped


def test_latency_of_the_estimate():
    params = EncoderParams(min_window=64)
    a, b, _ = lines_for(lambda t: 1.0 * t, 6000)
    enc = EncoderModel(params)
    changes = []
    for k in range(len(a)):
        before = enc.velocity
        enc.cycle(int(a[k]), int(b[k]), sample=(k == 3000))
        if enc.velocity != before:
            changes.append(k + 1)                      # visible from this cycle on
    assert changes == [3000 + VEL_LATENCY]
