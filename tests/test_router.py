# amaranth: UnusedElaboratable=no

import numpy as np
from amaranth.sim import Simulator

from mrm_cosim.hdl.link import packet_ref as ref
from mrm_cosim.hdl.link.chain import char_int, char_value, get_chars, put_chars
from mrm_cosim.hdl.link.router import Router
from mrm_cosim.protocol import packet as proto
from mrm_cosim.testbench import run_simulation

ADDRESS = 2


def random_packets(rng, n, dests):
    """``n`` frames with random destinations from ``dests`` and unique payloads."""
    packets = []
    for index in range(n):
        header = proto.Header(int(rng.choice(dests)), int(rng.integers(256)),
                            int(proto.PacketType.COMM_A), index & 0xFF)
        payload = bytes([index, *rng.integers(0, 256, size=int(rng.integers(0, 12))).tolist()])
        packets.append(proto.encode(header, payload))
    return packets


def make_sim(dut, *, address=ADDRESS, up_running=1, down_running=1):
    sim = Simulator(dut)
    sim.add_clock(20e-9)

    async def levels(ctx):
        ctx.set(dut.address, address)
        ctx.set(dut.up_running, up_running)
        ctx.set(dut.down_running, down_running)

    sim.add_testbench(levels)
    return sim


def flatten(packets):
    return [char for packet in packets for char in packet]


def test_down_path_routes_by_address():
    rng = np.random.default_rng(20)
    packets = random_packets(rng, 24, [ADDRESS, proto.BROADCAST, 1, 3, 7, proto.MASTER_ADDRESS])
    inputs = packets[:8] + [[proto.EOP]] + packets[8:16] + [[proto.EEP]] + packets[16:]
    model = ref.RouterModel(ADDRESS)
    to_local, to_down = [], []
    for packet in inputs:
        local, down = model.from_upstream(packet)
        to_local += [local] if local else []
        to_down += [down] if down else []
    assert len(to_local) >= 4 and len(to_down) >= 4 and model.dropped == 2
    dut = Router()
    sim = make_sim(dut)

    async def upstream(ctx):
        await put_chars(ctx, dut.up_rx, flatten(inputs), rng=rng, p_idle=0.2)

    async def local(ctx):
        assert await get_chars(ctx, dut.local_rx, len(to_local), rng=rng, p_stall=0.3) == \
            flatten(to_local)

    async def downstream(ctx):
        assert await get_chars(ctx, dut.down_tx, len(to_down), rng=rng, p_stall=0.5) == \
            flatten(to_down)
        await ctx.tick().repeat(4)
        assert ctx.get(dut.dropped) == model.dropped
        assert not ctx.get(dut.local_rx.valid) and not ctx.get(dut.up_tx.valid)

    sim.add_testbench(upstream)
    sim.add_testbench(local)
    sim.add_testbench(downstream)
    run_simulation(sim, "router_down_path")


def test_end_of_chain_discards_packets_for_missing_nodes():
    rng = np.random.default_rng(21)
    packets = random_packets(rng, 16, [ADDRESS, proto.BROADCAST, 3, 9])
    model = ref.RouterModel(ADDRESS)
    to_local = [model.from_upstream(p, down_running=False)[0] for p in packets]
    to_local = [p for p in to_local if p]
    dut = Router()
    sim = make_sim(dut, down_running=0)

    async def upstream(ctx):
        await put_chars(ctx, dut.up_rx, flatten(packets), rng=rng, p_idle=0.1)
        await ctx.tick().repeat(4)
        assert ctx.get(dut.dropped) == model.dropped == len(packets) - len(to_local)
        assert not ctx.get(dut.down_tx.valid), "nothing may wait for a link that is down"

    async def local(ctx):
        assert await get_chars(ctx, dut.local_rx, len(to_local), rng=rng, p_stall=0.3) == \
            flatten(to_local)

    sim.add_testbench(upstream)
    sim.add_testbench(local)
    run_simulation(sim, "router_end_of_chain")


def test_up_path_merges_whole_packets():
    rng = np.random.default_rng(22)
    own = random_packets(rng, 12, [proto.MASTER_ADDRESS])
    forwarded = [[p[0], p[1] ^ 0x80, *p[2:]] for p in random_packets(rng, 12, [0])]
    dut = Router()
    sim = make_sim(dut)

    async def host(ctx):
        await put_chars(ctx, dut.local_tx, flatten(own), rng=rng, p_idle=0.3)

    async def downstream(ctx):
        await put_chars(ctx, dut.down_rx, flatten(forwarded), rng=rng, p_idle=0.3)

    async def upstream(ctx):
        chars = await get_chars(ctx, dut.up_tx, len(own) + len(forwarded), rng=rng, p_stall=0.4)
        output = proto.split_packets(chars)
        assert ref.is_packet_merge(output, own, forwarded), "packets interleaved or lost"
        sources = ["own" if packet in own else "fwd" for packet in output]
        assert "own" in sources[:len(sources) // 2] and "fwd" in sources[:len(sources) // 2]

    sim.add_testbench(host)
    sim.add_testbench(downstream)
    sim.add_testbench(upstream)
    run_simulation(sim, "router_up_merge")


def test_round_robin_alternates_when_both_wait():
    rng = np.random.default_rng(23)
    own = random_packets(rng, 3, [0])
    forwarded = [[p[0], p[1] ^ 0x80, *p[2:]] for p in random_packets(rng, 3, [0])]
    dut = Router()
    sim = make_sim(dut)

    async def host(ctx):
        await put_chars(ctx, dut.local_tx, flatten(own))

    async def downstream(ctx):
        await put_chars(ctx, dut.down_rx, flatten(forwarded))

    async def upstream(ctx):
        await ctx.tick().repeat(5)  # let both sides wait
        output = proto.split_packets(await get_chars(ctx, dut.up_tx, 6))
        # After reset the tie goes downstream first, then the grant alternates.
        assert output == [forwarded[0], own[0], forwarded[1], own[1], forwarded[2], own[2]]

    sim.add_testbench(host)
    sim.add_testbench(downstream)
    sim.add_testbench(upstream)
    run_simulation(sim, "router_round_robin")


def test_upstream_link_down_discards_without_blocking_the_host():
    rng = np.random.default_rng(24)
    own = random_packets(rng, 5, [0])
    model = ref.RouterModel(ADDRESS)
    assert all(model.to_upstream(packet, up_running=False) is None for packet in own)
    dut = Router()
    sim = make_sim(dut, up_running=0)

    async def host(ctx):
        await put_chars(ctx, dut.local_tx, flatten(own))
        await ctx.tick().repeat(3)
        assert ctx.get(dut.dropped) == model.dropped == 5
        assert not ctx.get(dut.up_tx.valid)

    sim.add_testbench(host)
    run_simulation(sim, "router_up_down")


def test_link_loss_mid_packet_follows_the_codec_rules():
    """Before the codec took any of a packet the router drops it; after, it keeps feeding it."""
    packet_a = proto.encode(proto.Header(5, 0, 0x0A, 1), bytes(range(6)))
    packet_b = proto.encode(proto.Header(5, 0, 0x0A, 2), bytes(range(6, 12)))
    packet_c = proto.encode(proto.Header(6, 0, 0x0A, 3), bytes(range(12, 18)))
    packet_d = proto.encode(proto.Header(7, 0, 0x0A, 4), bytes(range(18, 24)))
    dut = Router()
    sim = make_sim(dut)

    go_on = []

    async def upstream(ctx):
        await put_chars(ctx, dut.up_rx, packet_a)
        while not go_on:
            await ctx.tick()
        await put_chars(ctx, dut.up_rx, packet_b + packet_c + packet_d)

    async def codec(ctx):
        # Packet A: the codec takes three characters, then the link drops. A codec that has
        # started a packet takes the rest (and drops it): the router must keep offering it.
        got = await take_chars(ctx, dut.down_tx, 3)
        ctx.set(dut.down_running, 0)
        got += await take_chars(ctx, dut.down_tx, len(packet_a) - 3)
        assert got == packet_a
        assert ctx.get(dut.dropped) == 0
        # Packet B: the link is back, B's first character waits in the router, the codec has
        # taken none of it when the link drops again: B is dropped whole, though the link comes
        # back before B's end has passed.
        ctx.set(dut.down_running, 1)
        go_on.append(True)
        await ctx.tick().repeat(3)
        assert ctx.get(dut.down_tx.valid) and char_int(
            ctx.get(dut.down_tx.payload.as_value())) == packet_b[0]
        ctx.set(dut.down_running, 0)
        await ctx.tick().repeat(2)
        ctx.set(dut.down_running, 1)
        # Packet C goes through whole, then D.
        assert await get_chars(ctx, dut.down_tx, 2) == packet_c + packet_d
        assert ctx.get(dut.dropped) == 1

    sim.add_testbench(upstream)
    sim.add_testbench(codec)
    run_simulation(sim, "router_link_loss")


async def take_chars(ctx, stream, n):
    """Take exactly ``n`` characters, ready every cycle."""
    chars = []
    ctx.set(stream.ready, 1)
    while len(chars) < n:
        _, _, valid, raw = await ctx.tick().sample(stream.valid, stream.payload.as_value())
        if valid:
            chars.append(char_int(raw))
    ctx.set(stream.ready, 0)
    return chars


def test_char_value_round_trip():
    for char in [0, 1, 0x7F, 0xFF, proto.EOP, proto.EEP]:
        assert char_int(char_value(char)) == char
