# amaranth: UnusedElaboratable=no

import numpy as np
import pytest
from amaranth.lib.crc import catalog
from amaranth.sim import Simulator

from mrm_cosim.hdl.link.crc import CRC16
from mrm_cosim.protocol.crc import CRC16_CHECK, CRC16_INIT, crc16


def bitwise_crc16(data):
    """Textbook MSB-first long division, one bit at a time (the definition, no table)."""
    crc = 0xFFFF
    for byte in data:
        for bit in range(7, -1, -1):
            feedback = ((crc >> 15) & 1) ^ ((byte >> bit) & 1)
            crc = (crc << 1) & 0xFFFF
            if feedback:
                crc ^= 0x1021
    return crc


def test_check_value():
    # Published check value of CRC-16/CCITT-FALSE (reveng: CRC-16/IBM-3740).
    assert crc16(b"123456789") == CRC16_CHECK == 0x29B1
    assert bitwise_crc16(b"123456789") == 0x29B1


def test_reference_matches_definition_and_amaranth_catalog():
    rng = np.random.default_rng(0)
    params = catalog.CRC16_CCITT_FALSE(8)
    for length in [0, 1, 2, 5, 40, 46, 200]:
        data = rng.integers(0, 256, size=length).tolist()
        assert crc16(data) == bitwise_crc16(data) == params.compute(data), length


def test_residue_is_zero_after_appended_crc():
    rng = np.random.default_rng(1)
    for length in range(1, 70):
        data = rng.integers(0, 256, size=length).tolist()
        crc = crc16(data)
        assert crc16([*data, crc >> 8, crc & 0xFF]) == 0


def test_any_single_or_double_bit_error_is_detected():
    # CRC-16/CCITT has Hamming distance 4 up to 32751 bits: every 1..3-bit error in a
    # 46-byte frame must show up in the residue. Check all single and many double flips.
    rng = np.random.default_rng(2)
    data = rng.integers(0, 256, size=44).tolist()
    crc = crc16(data)
    frame = [*data, crc >> 8, crc & 0xFF]
    n_bits = 8 * len(frame)
    for bit in range(n_bits):
        bad = list(frame)
        bad[bit // 8] ^= 1 << (bit % 8)
        assert crc16(bad) != 0, bit
    for _ in range(2000):
        a, b = rng.choice(n_bits, size=2, replace=False)
        bad = list(frame)
        bad[a // 8] ^= 1 << (a % 8)
        bad[b // 8] ^= 1 << (b % 8)
        assert crc16(bad) != 0, (a, b)


def test_rtl_matches_reference():
    rng = np.random.default_rng(3)
    # Three messages, each started with `start` on its first byte; idle cycles in between.
    messages = [rng.integers(0, 256, size=n).tolist() for n in (9, 40, 17)]
    messages[0] = list(b"123456789")
    dut = CRC16()

    async def testbench(ctx):
        assert ctx.get(dut.crc) == CRC16_INIT
        for message in messages:
            for index, byte in enumerate(message):
                ctx.set(dut.start, index == 0)
                ctx.set(dut.valid, 1)
                ctx.set(dut.data, byte)
                await ctx.tick()
                ctx.set(dut.valid, 0)
                ctx.set(dut.start, 0)
                if rng.random() < 0.3:
                    await ctx.tick()
                assert ctx.get(dut.crc) == crc16(message[:index + 1])
        # A bare start resets to the initial value.
        ctx.set(dut.start, 1)
        await ctx.tick()
        assert ctx.get(dut.crc) == CRC16_INIT

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    sim.run()


@pytest.mark.parametrize("byte", [0x00, 0x01, 0x80, 0xFF])
def test_rtl_single_byte(byte):
    dut = CRC16()

    async def testbench(ctx):
        ctx.set(dut.start, 1)
        ctx.set(dut.valid, 1)
        ctx.set(dut.data, byte)
        await ctx.tick()
        assert ctx.get(dut.crc) == bitwise_crc16([byte])

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    sim.run()
