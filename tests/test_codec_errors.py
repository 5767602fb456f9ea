# amaranth: UnusedElaboratable=no
"""Each link error class is detected, counted, and followed by reset and restart.

# Ref: ECSS-E-ST-50-12C §7.4 (parity), §8.5.3 (disconnect, parity, escape and credit errors;
#      gotFCT / gotN-Char / gotTime-Code where they are not allowed).
"""

import pytest
from amaranth.sim import Simulator

from mrm_cosim.hdl.link.chars import CharKind, LinkState
from mrm_cosim.hdl.link.codec_ref import char_value

from mrm_cosim.testbench import PeerBench, run_simulation

SHORT = {"reset_cycles": 60, "wait_cycles": 150}
DATA, EOP, EEP = (k.value for k in CharKind)


def run_bench(bench, testbench, name):
    sim = Simulator(bench.dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, name)


def only(errors, name):
    """The error counters show exactly one error, of class ``name``."""
    return errors == {k: int(k == name) for k in errors}


def test_parity_error_drops_the_bad_character_and_ends_the_packet_with_eep():
    bench = PeerBench(**SHORT)
    result = {}

    async def testbench(ctx):
        await bench.bring_up(ctx)
        bench.peer.send(("DATA", 0x11), ("DATA", 0x22), ("DATA", 0x33, "corrupt"),
                        ("DATA", 0x44), ("EOP",))
        await bench.until(ctx, lambda: not ctx.get(bench.dut.running), limit=400)
        result["errors"] = bench.errors(ctx)
        await bench.run(ctx, 5)

    run_bench(bench, testbench, "parity_error")
    assert only(result["errors"], "parity")
    # 0x33 arrived with a flipped bit: the parity of the next character exposed it, so it was
    # never delivered; the cut packet ends with EEP.
    assert bench.received == [char_value(DATA, 0x11), char_value(DATA, 0x22), char_value(EEP)]


@pytest.mark.parametrize("second", ["ESC", "EOP", "EEP"])
def test_escape_error_on_esc_followed_by_other_than_fct_or_data(second):
    bench = PeerBench(**SHORT)
    result = {}

    async def testbench(ctx):
        await bench.bring_up(ctx)
        bench.peer.send(("ESC",), (second,))
        await bench.until(ctx, lambda: not ctx.get(bench.dut.running), limit=200)
        result["errors"] = bench.errors(ctx)
        result["state"] = ctx.get(bench.dut.state)

    run_bench(bench, testbench, f"escape_{second}")
    assert only(result["errors"], "escape")
    assert result["state"] == LinkState.ERROR_RESET


def test_credit_error_when_peer_sends_more_than_it_was_given():
    """The DUT grants 56 N-chars (rx not read); the 57th is a credit error, not data."""
    bench = PeerBench(**SHORT)
    result = {}

    async def testbench(ctx):
        bench.rx_ready = 0
        await bench.bring_up(ctx)
        await bench.run(ctx, 100)                  # let all seven FCTs go out
        result["rx_credit"] = ctx.get(bench.dut.rx_credit)
        bench.peer.send(*[("DATA", n) for n in range(57)])
        await bench.until(ctx, lambda: not ctx.get(bench.dut.running), limit=2000)
        result["errors"] = bench.errors(ctx)
        bench.rx_ready = 1
        await bench.run(ctx, 70)

    run_bench(bench, testbench, "credit_rx")
    assert result["rx_credit"] == 56
    assert only(result["errors"], "credit")
    assert bench.received == [char_value(DATA, n) for n in range(56)] + [char_value(EEP)]


def test_credit_error_when_peer_grants_more_than_56():
    """Seven FCTs after the first (64 N-chars outstanding) overflow the transmit credit."""
    bench = PeerBench(**SHORT)
    result = {}

    async def testbench(ctx):
        await bench.bring_up(ctx)                  # the first FCT: 8 credits
        bench.peer.send(*[("FCT",)] * 6)           # 56
        await bench.run(ctx, 60)
        result["credit"] = ctx.get(bench.dut.tx_credit)
        result["running"] = ctx.get(bench.dut.running)
        bench.peer.send(("FCT",))                  # 64: too many
        await bench.until(ctx, lambda: not ctx.get(bench.dut.running), limit=200)
        result["errors"] = bench.errors(ctx)

    run_bench(bench, testbench, "credit_tx")
    assert result["credit"] == 56 and result["running"]
    assert only(result["errors"], "credit")


def test_fct_before_connecting_is_a_sequence_error():
    """NULL then FCT while the DUT waits in Error-Wait: gotFCT there sends it back to reset."""
    bench = PeerBench(**SHORT)
    result = {}

    async def testbench(ctx):
        await bench.until(ctx, lambda: ctx.get(bench.dut.state) == LinkState.ERROR_WAIT)
        bench.peer.fill_nulls = False
        bench.peer.silent = False
        bench.peer.send(("NULL",), ("FCT",), ("NULL",))
        await bench.until(ctx, lambda: ctx.get(bench.dut.state) != LinkState.ERROR_WAIT,
                          limit=200)
        result["state"] = ctx.get(bench.dut.state)
        result["errors"] = bench.errors(ctx)

    run_bench(bench, testbench, "fct_in_error_wait")
    assert result["state"] == LinkState.ERROR_RESET
    assert only(result["errors"], "sequence")


@pytest.mark.parametrize("token", [("DATA", 0x5A), ("TIME", 7)])
def test_nchar_or_time_code_in_connecting_is_a_sequence_error(token):
    bench = PeerBench(**SHORT)
    result = {}

    async def testbench(ctx):
        ctx.set(bench.dut.link_start, 1)
        await bench.until(ctx, lambda: ctx.get(bench.dut.state) == LinkState.STARTED)
        bench.peer.silent = False
        await bench.until(ctx, lambda: ctx.get(bench.dut.state) == LinkState.CONNECTING)
        bench.peer.send(token)
        await bench.until(ctx, lambda: ctx.get(bench.dut.state) != LinkState.CONNECTING,
                          limit=300)
        result["state"] = ctx.get(bench.dut.state)
        result["errors"] = bench.errors(ctx)

    run_bench(bench, testbench, f"sequence_{token[0]}")
    assert result["state"] == LinkState.ERROR_RESET
    assert only(result["errors"], "sequence")


def test_parity_is_not_checked_before_the_first_null():
    """Garbage with bad parity before the first NULL is ignored; the link still comes up."""
    bench = PeerBench(**SHORT)
    result = {}

    async def testbench(ctx):
        await bench.until(ctx, lambda: ctx.get(bench.dut.state) == LinkState.READY)
        bench.peer.fill_nulls = False
        bench.peer.silent = False
        bench.peer.send(("DATA", 0xA5, "bad-parity"), ("EOP", "bad-parity"))
        bench.peer.fill_nulls = True
        await bench.bring_up(ctx)
        result["errors"] = bench.errors(ctx)

    run_bench(bench, testbench, "no_parity_before_null")
    assert all(n == 0 for n in result["errors"].values())
