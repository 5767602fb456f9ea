# amaranth: UnusedElaboratable=no

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from amaranth import *
from amaranth.lib import wiring
from amaranth.sim import Simulator

from mrm_cosim.hdl.link import packet_ref as ref
from mrm_cosim.hdl.link.chain import get_chars, get_packet, put_chars, put_packet, read_stats
from mrm_cosim.hdl.link.packet import Depacketizer, Packetizer
from mrm_cosim.protocol import packet as proto
from mrm_cosim.protocol.crc import crc16
from mrm_cosim.testbench import run_simulation

ADDRESS = 0x05


def random_header(rng, *, dest=None):
    return proto.Header(int(rng.integers(256)) if dest is None else dest, int(rng.integers(256)),
                      int(rng.choice([*map(int, proto.PacketType), int(rng.integers(256))])),
                      int(rng.integers(256)))


def random_payload(rng, max_payload=proto.DEFAULT_MAX_PAYLOAD):
    n = int(rng.choice([1, 2, proto.DATA_PAYLOAD, max_payload, rng.integers(1, max_payload + 1)]))
    return bytes(rng.integers(0, 256, size=n).tolist())


def bad_packets(rng, max_payload=proto.DEFAULT_MAX_PAYLOAD):
    """A good frame and one of each kind of damaged frame, in random order."""
    def good():
        return proto.encode(random_header(rng), random_payload(rng, max_payload),
                          max_payload=max_payload)
    flipped = good()
    position = int(rng.integers(len(flipped) - 1))
    flipped[position] ^= 1 << int(rng.integers(8))
    short = good()[:int(rng.integers(0, proto.HEADER_BYTES + proto.CRC_BYTES + 1))] + [proto.EOP]
    body = proto.Header(1, 2, 3, 4).to_bytes() + bytes(range(max_payload + 1))
    crc = crc16(body)
    too_long = [*body, crc >> 8, crc & 0xFF, proto.EOP]  # correct CRC, one byte too many
    eep = good()[:-1] + [proto.EEP]
    truncated = good()
    del truncated[int(rng.integers(len(truncated) - 1))]
    packets = [good(), flipped, short, too_long, eep, truncated, good(), [proto.EOP]]
    order = rng.permutation(len(packets))
    return [packets[i] for i in order]


def test_reference_frame_layout():
    header = proto.Header(dest=3, src=0, type=proto.PacketType.COMM_B, seq=0x7E)
    frame = proto.encode(header, bytes(range(40)))
    assert len(frame) == 4 + 40 + 2 + 1, "a 40-byte package is 46 data characters and an EOP"
    assert frame[:4] == [3, 0, 0x0B, 0x7E]
    assert frame[4:44] == list(range(40))
    crc = crc16(bytes([3, 0, 0x0B, 0x7E, *range(40)]))
    assert frame[44:] == [crc >> 8, crc & 0xFF, proto.EOP]
    assert proto.check_frame(frame) == (proto.Verdict.GOOD, header, bytes(range(40)))


def test_reference_classifies_bad_frames():
    good = proto.encode(proto.Header(1, 0, 0x10, 9), b"\x01\x02\x03")
    assert proto.check_frame(good)[0] is proto.Verdict.GOOD
    assert proto.check_frame(good[:-1] + [proto.EEP])[0] is proto.Verdict.EEP
    assert proto.check_frame([proto.EEP])[0] is proto.Verdict.EEP
    assert proto.check_frame([proto.EOP])[0] is proto.Verdict.LENGTH
    assert proto.check_frame(good[:6] + [proto.EOP])[0] is proto.Verdict.LENGTH
    corrupt = list(good)
    corrupt[5] ^= 0x40
    assert proto.check_frame(corrupt)[0] is proto.Verdict.CRC
    body = bytes(4 + 9)
    crc = crc16(body)
    frame = [*body, crc >> 8, crc & 0xFF, proto.EOP]
    assert proto.check_frame(frame, max_payload=9)[0] is proto.Verdict.GOOD
    assert proto.check_frame(frame, max_payload=8)[0] is proto.Verdict.LENGTH


def test_reference_rejects_bad_input():
    with pytest.raises(ValueError, match="Payload must hold"):
        proto.encode(proto.Header(1, 0, 0, 0), b"")
    with pytest.raises(ValueError, match="Payload must hold"):
        proto.encode(proto.Header(1, 0, 0, 0), bytes(65))
    with pytest.raises(ValueError, match="Header.seq"):
        proto.Header(1, 0, 0, 256)
    with pytest.raises(ValueError, match="end with EOP"):
        proto.check_frame([1, 2, 3])


headers = st.builds(proto.Header, *[st.integers(0, 255)] * 4)
payloads = st.binary(min_size=1, max_size=proto.DEFAULT_MAX_PAYLOAD)


@settings(max_examples=200, deadline=None)
@given(headers, payloads, st.data())
def test_reference_round_trip_and_any_single_corruption_is_rejected(header, payload, data):
    frame = proto.encode(header, payload)
    assert proto.check_frame(frame) == (proto.Verdict.GOOD, header, payload)
    index = data.draw(st.integers(0, len(frame) - 2))
    bad = list(frame)
    bad[index] ^= data.draw(st.integers(1, 255))   # any error burst within one character
    assert proto.check_frame(bad)[0] is proto.Verdict.CRC


@settings(max_examples=200, deadline=None)
@given(st.lists(st.one_of(st.integers(0, 255), st.sampled_from([proto.EOP, proto.EEP])),
                max_size=200))
def test_reference_delivers_only_well_formed_frames(chars):
    model = ref.DepacketizerModel()
    for header, payload in model.feed(chars):
        frame = proto.encode(header, payload)
        assert any(chars[i:i + len(frame)] == frame for i in range(len(chars)))
    ends = sum(char in (proto.EOP, proto.EEP) for char in chars)
    assert sum(model.counts.values()) == ends


def test_reference_counters_saturate():
    model = ref.DepacketizerModel()
    model.counts["eep"] = proto.COUNTER_MAX - 1
    model.feed([proto.EEP, proto.EEP, proto.EEP])
    assert model.counts["eep"] == proto.COUNTER_MAX


def test_packetizer_matches_reference():
    rng = np.random.default_rng(10)
    packets = [(random_header(rng), random_payload(rng)) for _ in range(12)]
    expected = []
    for header, payload in packets:
        expected += proto.encode(proto.Header(header.dest, ADDRESS, header.type, header.seq),
                               payload)
    dut = Packetizer()

    async def host(ctx):
        ctx.set(dut.address, ADDRESS)
        for header, payload in packets:
            await put_packet(ctx, dut.beats, header, payload, rng=rng, p_idle=0.3)

    async def link(ctx):
        chars = await get_chars(ctx, dut.chars, len(packets), rng=rng, p_stall=0.4)
        assert chars == expected

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(host)
    sim.add_testbench(link)
    run_simulation(sim, "packetizer_ref")


@pytest.mark.parametrize("max_payload, slots", [(64, 2), (40, 1), (100, 4)])
def test_depacketizer_matches_reference(max_payload, slots):
    rng = np.random.default_rng(max_payload + slots)
    chars = []
    for _ in range(3):
        for packet in bad_packets(rng, max_payload):
            chars += packet
    model = ref.DepacketizerModel(max_payload=max_payload)
    expected = model.feed(chars)
    counts = model.counts
    assert len(expected) == counts["good"] == 6 and counts["eep"] == 3
    assert counts["length"] >= 9 and counts["crc"] >= 3 and counts["crc"] + counts["length"] == 15
    dut = Depacketizer(max_payload=max_payload, slots=slots)

    async def link(ctx):
        await put_chars(ctx, dut.chars, chars, rng=rng, p_idle=0.2)
        await ctx.tick().repeat(4)
        assert read_stats(ctx, dut.stats) == model.counts

    async def host(ctx):
        for header, payload in expected:
            assert await get_packet(ctx, dut.beats, rng=rng, p_stall=0.3) == (header, payload)
        for _ in range(100):       # nothing else comes out
            ctx.set(dut.beats.ready, 1)
            assert not ctx.get(dut.beats.valid)
            await ctx.tick()

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(link)
    sim.add_testbench(host)
    run_simulation(sim, f"depacketizer_ref_{max_payload}_{slots}")


class _Loopback(wiring.Component):
    """Packetizer straight into a depacketizer."""

    def __init__(self):
        self.pack = Packetizer()
        self.depack = Depacketizer()
        super().__init__({})

    def elaborate(self, platform):
        m = Module()
        m.submodules.pack = self.pack
        m.submodules.depack = self.depack
        wiring.connect(m, self.pack.chars, self.depack.chars)
        return m


def test_round_trip_through_packetizer_and_depacketizer():
    rng = np.random.default_rng(11)
    packets = [(random_header(rng), random_payload(rng)) for _ in range(10)]
    dut = _Loopback()

    async def host_tx(ctx):
        ctx.set(dut.pack.address, ADDRESS)
        for header, payload in packets:
            await put_packet(ctx, dut.pack.beats, header, payload, rng=rng, p_idle=0.2)

    async def host_rx(ctx):
        for header, payload in packets:
            got = await get_packet(ctx, dut.depack.beats, rng=rng, p_stall=0.5)
            assert got == (proto.Header(header.dest, ADDRESS, header.type, header.seq), payload)
        assert read_stats(ctx, dut.depack.stats) == {"good": 10, "crc": 0, "length": 0,
                                                      "eep": 0}

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(host_tx)
    sim.add_testbench(host_rx)
    run_simulation(sim, "packet_round_trip")


def test_full_buffers_stop_the_link_instead_of_overwriting():
    payloads = [bytes([n] * (n + 1)) for n in range(3)]
    frames = [proto.encode(proto.Header(1, 0, proto.PacketType.CONFIG, n), p)
              for n, p in enumerate(payloads)]
    dut = Depacketizer(slots=2)

    async def testbench(ctx):
        await put_chars(ctx, dut.chars, frames[0] + frames[1])
        await ctx.tick().repeat(3)
        assert ctx.get(dut.beats.valid)
        for _ in range(20):  # both slots full: the third packet is not taken
            ctx.set(dut.chars.payload.as_value(), 0)
            ctx.set(dut.chars.valid, 1)
            assert not ctx.get(dut.chars.ready)
            await ctx.tick()
        ctx.set(dut.chars.valid, 0)
        assert (await get_packet(ctx, dut.beats))[1] == payloads[0]
        await put_chars(ctx, dut.chars, frames[2])
        assert (await get_packet(ctx, dut.beats))[1] == payloads[1]
        assert (await get_packet(ctx, dut.beats))[1] == payloads[2]

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, "depacketizer_full")


@pytest.mark.parametrize("kwargs, message", [
    ({"max_payload": 0}, "Maximum payload"),
    ({"max_payload": 256}, "Maximum payload"),
    ({"slots": 3}, "power of two"),
    ({"slots": 0}, "power of two"),
])
def test_depacketizer_rejects_bad_parameters(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Depacketizer(**kwargs)
