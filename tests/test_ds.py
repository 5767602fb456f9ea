# amaranth: UnusedElaboratable=no
"""Data-strobe SERDES: line encoding, bit timing at both rates, decoding at any rate."""

from itertools import pairwise

import numpy as np
import pytest
from amaranth.sim import Simulator

from mrm_cosim.hdl.link.ds import DSReceiver, DSTransmitter

from mrm_cosim.testbench import run_simulation


def ds_line(bits):
    """Closed-form DS encoding from idle (D = S = 0): D is the bit, D xor S = (k + 1) mod 2."""
    return [(b, b ^ ((k + 1) & 1)) for k, b in enumerate(bits)]


def slots_of(words, slots):
    """Flatten per-cycle ``slots``-bit words into one sample per slot, earliest first."""
    return [(w >> i) & 1 for w in words for i in range(slots)]


@pytest.mark.parametrize("slots,start_div,run_div", [(1, 5, 1), (2, 10, 1), (3, 15, 1),
                                                      (3, 15, 2), (4, 20, 3), (6, 30, 2),
                                                      (8, 40, 3)])
@pytest.mark.parametrize("fast", [0, 1])
def test_transmitter_encodes_groups_back_to_back(slots, start_div, run_div, fast):
    rng = np.random.default_rng(slots * 100 + start_div + fast)
    div = run_div if fast else start_div
    groups = []
    for _ in range(12):
        length = int(rng.choice([4, 8, 10, 14]))
        groups.append((int(rng.integers(0, 1 << length)), length))
    sent_bits = [(v >> i) & 1 for v, n in groups for i in range(n)]
    n_cycles = (len(sent_bits) * div) // slots + 8
    dut = DSTransmitter(slots=slots, start_div=start_div, max_run_div=start_div)
    d_words, s_words = [], []

    async def feed(ctx):
        ctx.set(dut.enable, 1)
        ctx.set(dut.fast, fast)
        ctx.set(dut.run_div, run_div)
        for value, length in groups:
            ctx.set(dut.groups.p.bits, value)
            ctx.set(dut.groups.p.length, length)
            ctx.set(dut.groups.valid, 1)
            await ctx.tick().until(dut.groups.ready)
        ctx.set(dut.groups.valid, 0)

    async def watch(ctx):
        for _ in range(n_cycles):
            await ctx.tick()
            d_words.append(ctx.get(dut.d_out))
            s_words.append(ctx.get(dut.s_out))

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(feed)
    sim.add_testbench(watch)
    run_simulation(sim, f"ds_tx_w{slots}_f{fast}")

    d, s = slots_of(d_words, slots), slots_of(s_words, slots)
    # Bit boundaries: slots where exactly one line changed; never both at once.
    edges = []
    prev = (0, 0)
    for t, cur in enumerate(zip(d, s, strict=True)):
        assert not (cur[0] != prev[0] and cur[1] != prev[1]), f"D and S both changed at {t}"
        if cur != prev:
            edges.append(t)
        prev = cur
    # After the last group the line holds; everything before is bits at exactly `div` slots.
    edges = edges[:len(sent_bits)]
    assert len(edges) == len(sent_bits), "not all bits were sent"
    assert all(b - a == div for a, b in pairwise(edges)), "bit period or gap wrong"
    line = [(d[t], s[t]) for t in edges]
    assert line == ds_line(sent_bits)


def test_transmitter_idles_low_and_resets_when_disabled():
    dut = DSTransmitter(slots=3, start_div=15, max_run_div=15)

    async def testbench(ctx):
        ctx.set(dut.groups.valid, 1)
        ctx.set(dut.groups.p.bits, 0b1111)
        ctx.set(dut.groups.p.length, 4)
        ctx.set(dut.run_div, 1)
        for _ in range(5):
            assert not ctx.get(dut.groups.ready), "ready while disabled"
            assert ctx.get(dut.d_out) == 0 and ctx.get(dut.s_out) == 0
            await ctx.tick()
        ctx.set(dut.enable, 1)
        await ctx.tick().repeat(10)
        assert ctx.get(dut.d_out) or ctx.get(dut.s_out)
        ctx.set(dut.enable, 0)
        await ctx.tick().repeat(2)
        assert ctx.get(dut.d_out) == 0 and ctx.get(dut.s_out) == 0, "disable must drop the line"

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, "ds_tx_disable")


@pytest.mark.parametrize("slots,div", [(3, 1), (6, 2)])
def test_reset_is_controlled_s_before_d(slots, div):
    """ECSS-E-ST-50-12C Rev.1 (controlled reset of an output port): when the link enters
    Error-Reset, D and S are reset with a delay between them, never with a simultaneous
    transition; the delay lies between the bit period at the fastest rate and 500 ns. Disabled
    at every phase of a random bit stream: no slot where both lines change, S falls first, D
    (if it was high) exactly one cycle later, the line then stays low."""
    rng = np.random.default_rng(slots)
    dut = DSTransmitter(slots=slots, start_div=5 * slots, max_run_div=5 * slots)
    cases = []

    async def testbench(ctx):
        ctx.set(dut.fast, 1)
        ctx.set(dut.run_div, div)
        ctx.set(dut.groups.valid, 1)
        for _ in range(40):
            ctx.set(dut.enable, 1)
            for _ in range(int(rng.integers(3, 12))):
                ctx.set(dut.groups.p.bits, int(rng.integers(0, 1 << 10)))
                ctx.set(dut.groups.p.length, 10)
                await ctx.tick()
            before = (ctx.get(dut.d_out) >> (slots - 1), ctx.get(dut.s_out) >> (slots - 1))
            ctx.set(dut.enable, 0)
            words = []
            for _ in range(4):
                await ctx.tick()
                words.append((ctx.get(dut.d_out), ctx.get(dut.s_out)))
            cases.append((before, words))

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, f"ds_tx_reset_{slots}")

    seen = set()
    for (d0, s0), words in cases:
        seen.add((d0, s0))
        line = [(d0, s0)] + [((d >> i) & 1, (s >> i) & 1) for d, s in words
                             for i in range(slots)]
        changes = [t for t in range(1, len(line)) if line[t] != line[t - 1]]
        for t in changes:
            assert not (line[t][0] != line[t - 1][0] and line[t][1] != line[t - 1][1]), \
                f"simultaneous transition of D and S from {(d0, s0)}"
        assert line[-1] == (0, 0) and all(w == (0, 0) for w in words[2:])
        if (d0, s0) == (1, 1):
            assert [line[t] for t in changes] == [(1, 0), (0, 0)], "S first, then D"
            gap_ns = (changes[1] - changes[0]) * 20 / slots
            assert gap_ns == 20, gap_ns
            assert div * 20 / slots <= gap_ns <= 500
        else:
            assert len(changes) == int(d0) + int(s0)
    assert seen == {(0, 0), (0, 1), (1, 0), (1, 1)}, "every line phase must be exercised"


@pytest.mark.parametrize("slots", [1, 2, 3, 4])
def test_receiver_recovers_bits_at_any_rate_up_to_one_per_slot(slots):
    """Bits with random periods of 1..7 slots (a drifting peer) decode exactly, in order."""
    rng = np.random.default_rng(slots)
    bits = [int(b) for b in rng.integers(0, 2, 300)]
    samples = [(0, 0)] * 5
    for line in ds_line(bits):
        samples += [line] * int(rng.integers(1, 8))
    samples += [samples[-1]] * (2 * slots)
    samples += [samples[-1]] * (-len(samples) % slots)
    words = [(sum(samples[c * slots + i][0] << i for i in range(slots)),
              sum(samples[c * slots + i][1] << i for i in range(slots)))
             for c in range(len(samples) // slots)]
    dut = DSReceiver(slots=slots)
    got, activity = [], 0

    async def testbench(ctx):
        nonlocal activity
        for d, s in words:
            ctx.set(dut.d_in, d)
            ctx.set(dut.s_in, s)
            await ctx.tick()
            valid, data = ctx.get(dut.bit_valid), ctx.get(dut.bit_data)
            activity += ctx.get(dut.activity)
            got.extend((data >> i) & 1 for i in range(slots) if (valid >> i) & 1)
        for _ in range(2):
            await ctx.tick()
            valid, data = ctx.get(dut.bit_valid), ctx.get(dut.bit_data)
            got.extend((data >> i) & 1 for i in range(slots) if (valid >> i) & 1)

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, f"ds_rx_w{slots}")
    assert got == bits
    assert activity > 0


def test_receiver_ignores_simultaneous_change_of_both_lines():
    """D and S flipping together is no bit (D xor S unchanged) but is line activity."""
    dut = DSReceiver(slots=1)

    async def testbench(ctx):
        ctx.set(dut.d_in, 1)
        ctx.set(dut.s_in, 1)
        await ctx.tick()
        assert ctx.get(dut.bit_valid) == 0
        assert ctx.get(dut.activity) == 1

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, "ds_rx_both")


@pytest.mark.parametrize("args,match", [
    ({"slots": 0, "start_div": 5, "max_run_div": 1}, "Slots"),
    ({"slots": 9, "start_div": 45, "max_run_div": 9}, "Slots"),
    ({"slots": 3, "start_div": 0, "max_run_div": 1}, "Start bit period"),
    ({"slots": 3, "start_div": 15, "max_run_div": 0}, "Slowest run bit period"),
    ({"slots": 6, "start_div": 30, "max_run_div": 1}, "at least 2"),
])
def test_rejects_bad_parameters(args, match):
    with pytest.raises(ValueError, match=match):
        DSTransmitter(**args)
