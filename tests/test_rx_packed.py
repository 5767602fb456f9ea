# amaranth: UnusedElaboratable=no
"""The receiver's packed bits: the front end packs every slot pattern, and the character
receiver's closed-form decode of packed bits equals the reference's walk over the slots."""

import itertools

import numpy as np
import pytest
from amaranth.sim import Simulator

from mrm_cosim.hdl.link.codec_ref import CodecRef
from mrm_cosim.hdl.link.ds import DSReceiver
from mrm_cosim.hdl.link.rx import CharReceiver
from mrm_cosim.protocol.link import ControlCode
from mrm_cosim.testbench import run_simulation


def pack(valid: int, data: int, slots: int) -> tuple[int, int]:
    """The bits of the set slots of ``valid``, first in bit 0, and their thermometer code."""
    bits = [(data >> i) & 1 for i in range(slots) if (valid >> i) & 1]
    return (1 << len(bits)) - 1, sum(b << k for k, b in enumerate(bits))


@pytest.mark.parametrize("slots", [3, 6])
def test_front_end_packs_every_slot_pattern(slots):
    """Every pattern of new bits (D xor S changes) with every data word, after either last
    line state of the cycle before: the packed outputs are the sparse ones, packed."""
    seen = set()
    words = [(x_prev, d, s) for x_prev in (0, 1)
             for d, s in itertools.product(range(1 << slots), repeat=2)]
    dut = DSReceiver(slots=slots)
    top = (1 << slots) - 1

    async def testbench(ctx):
        for x_prev, d, s in words:
            ctx.set(dut.d_in, top * x_prev)     # the previous cycle ends with D xor S = x_prev
            ctx.set(dut.s_in, 0)
            await ctx.tick()
            ctx.set(dut.d_in, d)
            ctx.set(dut.s_in, s)
            await ctx.tick()
            valid, data = ctx.get(dut.bit_valid), ctx.get(dut.bit_data)
            x = d ^ s
            assert valid == x ^ (((x << 1) | x_prev) & top), (x_prev, d, s)
            assert (ctx.get(dut.packed_valid), ctx.get(dut.packed_data)) == \
                pack(valid, data, slots), (x_prev, d, s)
            seen.add((valid, data))

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, f"ds_rx_pack_{slots}")
    assert len(seen) == 1 << (2 * slots), "every valid pattern with every data word"


def char_bits(chars, rng, error_rate):
    """Line bits of a character sequence (``("ctrl", code)`` or ``("data", byte)``) with odd
    parity, and bit errors at ``error_rate`` per character: a flipped, dropped or extra bit."""
    bits, prev = [], []
    for kind, value in chars:
        flag = int(kind == "ctrl")
        payload = ([(value >> i) & 1 for i in range(2)] if flag
                   else [(value >> i) & 1 for i in range(8)])
        parity = 1 ^ flag ^ (sum(prev) & 1)
        char = [parity, flag, *payload]
        if rng.random() < error_rate:
            at = int(rng.integers(0, len(char)))
            error = rng.integers(0, 3)
            if error == 0:
                char[at] ^= 1
            elif error == 1:
                del char[at]
            else:
                char.insert(at, int(rng.integers(0, 2)))
        bits += char
        prev = payload
    return bits


def random_chars(rng, n):
    """NULLs, FCTs, EOP/EEP, data, time-codes and stray ESCs."""
    esc, fct = ("ctrl", ControlCode.ESC), ("ctrl", ControlCode.FCT)
    out = []
    for _ in range(n):
        pick = rng.integers(0, 8)
        if pick == 0:
            out += [esc, fct]
        elif pick == 1:
            out.append(fct)
        elif pick == 2:
            out.append(("ctrl", int(rng.choice([ControlCode.EOP, ControlCode.EEP]))))
        elif pick == 3:
            out += [esc, ("data", int(rng.integers(0, 256)))]
        elif pick == 4:
            out += [esc, ("ctrl", int(rng.integers(0, 4)))]       # ESC ESC/EOP/EEP/FCT
        else:
            out.append(("data", int(rng.integers(0, 256))))
    return out


def run_receiver(slots, stream, rng, reset_rate):
    """Feed ``stream`` in random cycles of 0..slots bits (on random slots for the reference,
    packed for the gateware), with random receiver resets; compare every output each cycle."""
    dut = CharReceiver(slots=slots, disconnect_limit=40)
    ref = CodecRef(slots=slots)
    ref._reset_receiver()
    outputs = ("got_null", "got_fct", "got_nchar", "got_time", "time", "err_parity",
               "err_escape")
    counts = {"got_fct": 0, "got_nchar": 0, "got_time": 0, "err_parity": 0, "err_escape": 0}

    async def testbench(ctx):
        pos, cycle = 0, 0
        while pos < len(stream):
            enable = int(rng.random() >= reset_rate)
            k = min(int(rng.integers(0, slots + 1)), len(stream) - pos)
            places = sorted(rng.choice(slots, size=k, replace=False))
            valid = sum(1 << int(i) for i in places)
            data = sum(b << int(i) for b, i in zip(stream[pos:pos + k], places, strict=True))
            data |= int(rng.integers(0, 1 << slots)) & ~valid       # noise in empty slots
            pos += k
            packed_valid, packed_data = pack(valid, data, slots)
            ctx.set(dut.enable, enable)
            ctx.set(dut.bit_valid, packed_valid)
            ctx.set(dut.bit_data, packed_data)
            await ctx.tick()
            if enable:
                ref._receive(valid, data)
            else:
                ref._reset_receiver()
            for name in outputs:
                assert ctx.get(getattr(dut, name)) == getattr(ref, name), (name, cycle)
            kind, value = ctx.get(dut.nchar.kind), ctx.get(dut.nchar.data)
            assert int(kind.value) | value << 2 == ref.nchar, ("nchar", cycle)
            for name in counts:
                counts[name] += getattr(ref, name)
            cycle += 1

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, f"rx_packed_{slots}")
    return counts


@pytest.mark.parametrize("slots", [1, 3, 4, 6, 8])
def test_packed_decode_equals_the_walk_over_slots(slots):
    """Characters with bit errors (parity, escape errors, lost and extra bits), noise before
    the first NULL, resets: the gateware equals the reference's walk in every output, every
    cycle, whatever slots the bits arrived in."""
    rng = np.random.default_rng(slots)
    noise = [int(b) for b in rng.integers(0, 2, 30)]
    stream = noise + char_bits(random_chars(rng, 1500), rng, error_rate=0.02)
    counts = run_receiver(slots, stream, rng, reset_rate=0.002)
    assert all(counts.values()), counts      # every event and error class was exercised


@pytest.mark.parametrize("slots", [6, 8])
def test_packed_decode_of_random_bits_equals_the_walk(slots):
    """Random bits after a NULL: the decode's closed forms hold off the characters' path."""
    rng = np.random.default_rng(10 + slots)
    esc, fct = ("ctrl", ControlCode.ESC), ("ctrl", ControlCode.FCT)
    stream = char_bits([esc, fct], rng, 0) + [int(b) for b in rng.integers(0, 2, 6000)]
    counts = run_receiver(slots, stream, rng, reset_rate=0)
    assert counts["got_nchar"] and counts["err_parity"], counts
