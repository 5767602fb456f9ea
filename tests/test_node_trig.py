# amaranth: UnusedElaboratable=no
"""Sine/cosine unit: reference against math.sin/cos, RTL equal to the reference."""

import math

import numpy as np
import pytest
from amaranth.sim import Simulator
from hypothesis import given, settings
from hypothesis import strategies as st

from mrm_cosim.protocol.fixed import TRIG
from mrm_cosim.hdl.node.trig import LATENCY, SinCos
from mrm_cosim.hdl.node.trig_ref import binary_angle, sin_cos

from mrm_cosim.testbench import run_simulation

CPR = 800_000


def test_reference_is_accurate_over_the_count_range():
    rng = np.random.default_rng(0)
    counts = [int(c) for c in rng.integers(-2**23, 2**23, 5000)]
    counts += [0, CPR // 8, CPR // 4, CPR // 2, -CPR // 4, 2**23 - 1, -2**23]
    worst = 0.0
    for c in counts:
        co, si = sin_cos(c, CPR)
        q = c * 2 * math.pi / CPR
        worst = max(worst, abs(TRIG.decode(co) - math.cos(q)), abs(TRIG.decode(si) - math.sin(q)))
    assert worst < 7e-7            # ≈ 3 TRIG LSB; the count itself resolves 7.9e-6 rad


def test_binary_angle_wraps_per_turn():
    assert binary_angle(0, CPR) == 0
    assert binary_angle(CPR // 4, CPR) == 1 << 22
    assert binary_angle(-CPR // 4, CPR) == 3 << 22
    assert binary_angle(CPR, CPR) == 0


def run_rtl(counts):
    dut = SinCos(counts_per_rev=CPR)
    out = []

    async def tb(ctx):
        for c in counts:
            ctx.set(dut.count, c)
            ctx.set(dut.start, 1)
            await ctx.tick()
            ctx.set(dut.start, 0)
            n = 1
            while not ctx.get(dut.done):
                assert ctx.get(dut.busy)
                await ctx.tick()
                n += 1
            assert n == LATENCY
            out.append((ctx.get(dut.cos), ctx.get(dut.sin)))

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(tb)
    run_simulation(sim, "sincos")
    return out


def test_rtl_equals_reference_at_quadrant_edges():
    counts = [0, 1, -1, CPR // 4, CPR // 4 + 1, CPR // 4 - 1, CPR // 2, -CPR // 2, 3 * CPR // 4,
              2**23 - 1, -2**23, 2**31 - 1, -2**31]
    assert run_rtl(counts) == [sin_cos(c, CPR) for c in counts]


@settings(max_examples=20, deadline=None)
@given(st.lists(st.integers(-2**31, 2**31 - 1), min_size=1, max_size=4))
def test_rtl_equals_reference_on_any_count(counts):
    assert run_rtl(counts) == [sin_cos(c, CPR) for c in counts]


def test_rejects_bad_resolution():
    with pytest.raises(ValueError, match="positive integer"):
        SinCos(counts_per_rev=0)
