# amaranth: UnusedElaboratable=no
"""Flow control, throughput, time-codes, and what happens to packets cut by a link error.

# Ref: ECSS-E-ST-50-12C §8.5 / flow control (FCT = 8 N-chars, at most 56 outstanding),
#      §8.12 (time-codes), link error recovery (EEP at the receiver, spill at the sender).
"""

import random

import pytest

from mrm_cosim.hdl.link.chars import CharKind, LinkState
from mrm_cosim.hdl.link.codec_ref import char_value
from mrm_cosim.protocol.link import DEFAULT_SLOTS

from mrm_cosim.testbench import PairBench

SHORT = {"reset_cycles": 60, "wait_cycles": 150}
SLOTS = DEFAULT_SLOTS
ALL = (1 << SLOTS) - 1             # every slot of a cycle
DATA, EOP, EEP = (k.value for k in CharKind)


def data(values):
    return [char_value(DATA, v & 0xFF) for v in values]


@pytest.mark.parametrize("depth,limit", [(64, 56), (24, 16), (16, 8)])
def test_sender_stops_when_credit_runs_out_and_resumes(depth, limit):
    """rx never read: the sender stops after the credit the FIFO can back, then resumes."""
    bench = PairBench(**SHORT, rx_fifo_depth=depth)
    chars = data(range(150))
    result = {}

    async def testbench(ctx):
        bench.rx_ready["b"] = 0
        await bench.bring_up(ctx)
        bench.tx["a"] = list(chars)
        await bench.run(ctx, 400)
        result["stopped_at"] = len(bench.sent["a"])
        await bench.run(ctx, 300)
        result["still"] = len(bench.sent["a"])
        result["credits"] = (ctx.get(bench.pair.a.tx_credit), ctx.get(bench.pair.b.rx_credit))
        bench.rx_ready["b"] = 1
        await bench.until(ctx, lambda: len(bench.received["b"]) == len(chars), limit=2000)
        result["errors"] = (bench.errors(ctx, "a"), bench.errors(ctx, "b"))

    bench.simulate(testbench, f"credit_{depth}")
    assert result["stopped_at"] == limit == min(56, 8 * ((depth - 1) // 8))
    assert result["still"] == limit, "no N-char may go out without credit"
    assert result["credits"] == (0, 0)
    assert bench.received["b"] == chars
    assert all(n == 0 for e in result["errors"] for n in e.values())


@pytest.mark.parametrize("both_ways", [False, True])
def test_run_rate_is_150_mbit_per_s(both_ways):
    """Saturated link at 3 slots/cycle: 10 line bits per data character, plus one 4-bit FCT
    per 8 characters received when the line also carries the other direction's credit."""
    bench = PairBench(**SHORT)
    window = 840
    result = {}

    async def testbench(ctx):
        await bench.bring_up(ctx)
        bench.tx["a"] = data(range(600))
        if both_ways:
            bench.tx["b"] = data(range(600))
        await bench.run(ctx, 200)
        start = len(bench.received["b"])
        await bench.run(ctx, window)
        result["count"] = len(bench.received["b"]) - start

    bench.simulate(testbench, f"rate_{both_ways}")
    bits_per_char = 10 + (4 / 8 if both_ways else 0)
    expected = window * 3 / bits_per_char          # 240 or 252 characters
    assert abs(result["count"] - expected) <= 2
    assert bench.received["b"] == bench.sent["a"][:len(bench.received["b"])]


def test_time_codes_arrive_once_each_and_do_not_disturb_packets():
    bench = PairBench(**SHORT)
    values = [0x00, 0x01, 0x3F, 0x40 | 0x05, 0xC0 | 0x2A]
    sent_at = []

    async def testbench(ctx):
        # A tick before Run is ignored (the standard sends time-codes only in Run).
        await bench.until(ctx, lambda: bench.state(ctx, "a") == LinkState.CONNECTING)
        await bench.cycle(ctx, tick=("a", 0x3E))
        await bench.bring_up(ctx)
        bench.tx["a"] = data(range(100)) + [char_value(EOP)]
        bench.tx["b"] = data(range(100)) + [char_value(EOP)]
        for value in values:
            await bench.run(ctx, 37)
            sent_at.append(bench.cycles)
            await bench.cycle(ctx, tick=("a", value))
        await bench.run(ctx, 400)

    bench.simulate(testbench, "time_codes")
    assert [v for _, v in bench.ticks["b"]] == values
    latencies = [t - s for (t, _), s in zip(bench.ticks["b"], sent_at, strict=True)]
    # tick_in is registered (1 cycle); the queue ahead drains to under 3 bits (a data
    # character just queued: <= 4 cycles); then 2 + 14 bits of ESC + data and 2 more to the
    # next flag, which commits it (18 bits, 6 cycles); output, input and receiver registers
    # (3 cycles): at most 14 cycles (10-13 measured).
    assert max(latencies) <= 14
    assert bench.ticks["a"] == []
    assert bench.received["b"] == bench.sent["a"]
    assert bench.received["a"] == bench.sent["b"]


def test_cut_packet_ends_in_eep_and_its_rest_is_spilled_at_the_sender():
    bench = PairBench(**SHORT)
    first = data(range(200)) + [char_value(EOP)]
    second = data(range(50, 60)) + [char_value(EOP)]
    result = {}

    async def testbench(ctx):
        await bench.bring_up(ctx)
        bench.tx["a"] = first + second
        await bench.run(ctx, 100)                       # part of the first packet is across
        bench.faults["ab"] = ((ALL, 0, 0), (ALL, 0, 0))    # cut, longer than the 850 ns timeout
        await bench.run(ctx, 100)
        bench.faults.clear()
        await bench.until(ctx, lambda: len(bench.received["b"]) >= 2 and
                          bench.received["b"][-1] == char_value(EOP) and
                          len(bench.sent["a"]) == len(first) + len(second), limit=3000)
        result["errors"] = (bench.errors(ctx, "a"), bench.errors(ctx, "b"))

    bench.simulate(testbench, "cut_packet")
    received = bench.received["b"]
    eep_at = received.index(char_value(EEP))
    assert 0 < eep_at < 200
    assert received[:eep_at] == first[:eep_at], "what arrived of the cut packet is intact"
    assert received[eep_at + 1:] == second, "the next packet arrives whole, nothing between"
    assert bench.sent["a"] == first + second, "the rest of the cut packet was taken and dropped"
    errors_a, errors_b = result["errors"]
    assert errors_b["disconnect"] == 1 and errors_a["disconnect"] == 1
    assert sum(errors_a.values()) + sum(errors_b.values()) == 2


def test_disconnect_detected_within_the_standard_window():
    """Cut a -> b: b flags the disconnect 727-1000 ns after the last transition it saw."""
    bench = PairBench(**SHORT)
    seen = []                       # (cycle, slot) of each change at b's input
    result = {}

    async def testbench(ctx):
        await bench.bring_up(ctx)
        prev = None
        for n in range(200):
            if n == 50:
                bench.faults["ab"] = ((ALL, 0, 0), (ALL, 0, 0))
            bench.apply_faults(ctx)
            word = (ctx.get(bench.pair.ab.d_out), ctx.get(bench.pair.ab.s_out))
            for i in range(SLOTS):
                bit = ((word[0] >> i) & 1, (word[1] >> i) & 1)
                if prev is not None and bit != prev:
                    seen.append((bench.cycles, i))
                prev = bit
            if bench.state(ctx, "b") != LinkState.RUN and "left_run" not in result:
                result["left_run"] = bench.cycles
            await bench.cycle(ctx)
        result["errors"] = bench.errors(ctx, "b")

    bench.simulate(testbench, "disconnect_window")
    last_cycle, last_slot = max(c for c in seen if c[0] < result["left_run"])
    # The error is flagged in the cycle before b enters Error-Reset.
    flagged = result["left_run"] - 1
    detect_ns = (flagged - last_cycle) * 20 - last_slot * 20 / SLOTS
    assert 727 <= detect_ns <= 1000
    assert 843 < detect_ns <= 860, "43 cycles from the last transition's cycle"
    assert result["errors"]["disconnect"] == 1


@pytest.mark.parametrize("seed", [1, 2])
def test_occupied_register_is_fifo_level_plus_rx_credit_every_cycle(seed):
    """``fct_room`` compares ``occupied``, a register kept equal to ``fifo.level +
    rx_credit`` (the sum's adder was on the node's slowest path, docs/node.md "Clock"). Every
    cycle, on both codecs, through a small FIFO filled to its bound, throttled reading, a
    cut mid-packet (the EEP written while the link is down and the reader still reading)
    and the reconnection: the register equals the sum."""
    rng = random.Random(seed)
    bench = PairBench(**SHORT, rx_fifo_depth=16)
    seen = {"checked": 0, "eep": False, "down": 0}

    async def check(ctx, n, p_ready):
        for _ in range(n):
            for who in ("a", "b"):
                bench.rx_ready[who] = int(rng.random() < p_ready)
                occupied, level, credit = bench.codecs[who]._occupancy
                assert ctx.get(occupied) == ctx.get(level) + ctx.get(credit), (
                    who, bench.cycles)
                seen["down"] += not ctx.get(bench.codecs[who].running)
            seen["checked"] += 1
            await bench.cycle(ctx)

    async def testbench(ctx):
        await check(ctx, 400, 0.3)                       # start-up, then the link runs
        bench.tx["a"] = data(range(120)) + [char_value(EOP)] + data(range(40))
        bench.tx["b"] = data(range(60)) + [char_value(EOP)]
        await check(ctx, 300, 0.2)                       # FIFO at its bound, slow reads
        bench.faults["ab"] = ((ALL, 0, 0), (ALL, 0, 0))   # cut, longer than the timeout
        await check(ctx, 120, 0.5)
        bench.faults.clear()
        await check(ctx, 900, 0.4)                       # reconnect, the rest crosses
        seen["eep"] = char_value(EEP) in bench.received["b"]

    bench.simulate(testbench, f"occupied_{seed}")
    assert seen["eep"] and seen["down"] > 0 and seen["checked"] == 1720
