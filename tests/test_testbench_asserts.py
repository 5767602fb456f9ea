"""The kit's link assertions pass on the state and counters a codec has, and fail otherwise."""

import pytest
from amaranth.sim import Simulator

from mrm_cosim.testbench import PeerBench, assert_error_counts, assert_link_state


def test_link_assertions_pass_and_fail():
    bench = PeerBench(reset_cycles=60, wait_cycles=150)
    dut = bench.dut
    seen = []

    async def testbench(ctx):
        await bench.run(ctx, 5)
        assert_link_state(ctx, dut, "ERROR_RESET")
        with pytest.raises(AssertionError, match="expected RUN"):
            assert_link_state(ctx, dut, "RUN")
        await bench.bring_up(ctx)
        assert_link_state(ctx, dut, "RUN")
        assert_error_counts(ctx, dut)
        with pytest.raises(AssertionError, match="error counters"):
            assert_error_counts(ctx, dut, parity=1)
        with pytest.raises(ValueError, match="unknown error classes"):
            assert_error_counts(ctx, dut, bogus=1)
        seen.append(True)

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    sim.run()
    assert seen == [True]
