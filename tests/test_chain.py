# amaranth: UnusedElaboratable=no
"""A 3-node daisy chain with the real codecs: start-up, packets both ways, time-codes down.

pysim runs a 3-node chain at a few hundred cycles/s here, so each test is one short simulation
with shortened link timers (Error-Reset 1.2 µs, Error-Wait 3 µs), except the one at standard
timers.
"""

import numpy as np
import pytest
from amaranth.sim import Simulator

from mrm_cosim.hdl.link import packet_ref as ref
from mrm_cosim.hdl.link.chain import (
    Chain, master_receive, master_send, node_receive, node_send, put_chars, read_stats,
)
from mrm_cosim.protocol import packet as proto
from mrm_cosim.testbench import run_simulation

SHORT = {"reset_cycles": 60, "wait_cycles": 150}

# Time-code latency per hop, master tick_in -> node 1 tick_out and node k -> node k+1, cycles:
# the codec's tick_in -> peer tick_out latency, as the node passes tick_out on to its downstream
# codec's tick_in in the same cycle. docs/link.md: at least 10, bound 14 (waiting for the
# character on the line to finish varies); 10-13 measured.
HOP_MIN, HOP_MAX = 10, 14


async def bring_up(ctx, chain, limit):
    """Wait until every link of the chain is in Run; return the cycles it took."""
    for cycle in range(limit):
        if ctx.get(chain.master_running) and all(
                ctx.get(node.up_running) for node in chain.nodes) and all(
                ctx.get(node.down_running) for node in chain.nodes[:-1]):
            return cycle
        await ctx.tick()
    raise AssertionError(f"chain not running after {limit} cycles")


async def send_time_code(ctx, chain, value):
    """Strobe a time-code into the master codec; return the cycle number of the strobe."""
    ctx.set(chain.time_in, value)
    ctx.set(chain.tick_in, 1)
    sent = ctx.get(chain.cycle)
    await ctx.tick()
    ctx.set(chain.tick_in, 0)
    return sent


def check_hops(sent, stamps):
    hops = np.diff([sent, *stamps])
    assert ((hops >= HOP_MIN) & (hops <= HOP_MAX)).all(), f"hop latencies {hops}"
    return hops


def test_chain_delivers_like_the_reference_and_counts_bad_packets():
    rng = np.random.default_rng(30)
    chain = Chain(3, codec=SHORT)
    frames = []
    for seq in range(10):
        dest = int(rng.choice([1, 2, 3, proto.BROADCAST, 7]))
        payload = rng.integers(0, 256, size=int(rng.integers(1, 6))).tolist()
        frames.append(proto.encode(proto.Header(dest, 0, int(proto.PacketType.CONFIG), seq),
                                   payload))
    corrupt = proto.encode(proto.Header(2, 0, int(proto.PacketType.PARAM), 99), [1, 2, 3])
    corrupt[5] ^= 0x10
    cut = (proto.encode(proto.Header(1, 0, int(proto.PacketType.PARAM), 98), [4, 5, 6])[:-3]
           + [proto.EEP])
    frames[3:3] = [corrupt]
    frames[7:7] = [cut]
    model = ref.ChainModel(3)
    expected = {k: [] for k in (1, 2, 3)}
    for frame in frames:
        for k, packets in model.send_down(frame).items():
            expected[k] += packets
    assert all(expected.values()) and model.routers[2].dropped > 0
    received = {k: [] for k in (1, 2, 3)}

    def receiver(k):
        async def testbench(ctx):
            while True:
                received[k].append(await node_receive(ctx, chain.nodes[k - 1], rng=rng,
                                                      p_stall=0.2))
        return testbench

    async def master(ctx):
        await bring_up(ctx, chain, 1000)
        for frame in frames:
            await put_chars(ctx, chain.master_tx, frame)
        await ctx.tick().repeat(150)
        assert received == expected
        for k, node in enumerate(chain.nodes, start=1):
            assert read_stats(ctx, node.rx_stats) == model.nodes[k - 1].counts, k
            assert ctx.get(node.dropped) == model.routers[k - 1].dropped, k

    sim = Simulator(chain)
    sim.add_clock(20e-9)
    for k in (1, 2, 3):
        sim.add_testbench(receiver(k), background=True)
    sim.add_testbench(master)
    run_simulation(sim, "chain_reference")


def test_time_codes_reach_every_node_with_a_fixed_hop_latency():
    chain = Chain(3, codec=SHORT)

    async def testbench(ctx):
        await bring_up(ctx, chain, 1000)
        seen = set()
        for value in [*range(1, 8), 12]:             # 12 breaks the sequence
            await ctx.tick().repeat(2 + 3 * value)   # different phases against the NULLs
            sent = await send_time_code(ctx, chain, 0x40 | value)
            stamps = []
            for node in chain.nodes:
                await ctx.tick().until(node.tc_strobe)
                assert ctx.get(node.tc_time) == 0x40 | value
                assert ctx.get(node.tc_in_sequence) == (value != 12)
                stamps.append(ctx.get(node.tc_stamp))
            seen.update(check_hops(sent, stamps).tolist())
            for _ in range(HOP_MAX + 2):   # one strobe per node per time-code
                await ctx.tick()
                assert not any(ctx.get(node.tc_strobe) for node in chain.nodes)
        assert len(seen) > 1, "the wait for the character on the line should vary"

    sim = Simulator(chain)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, "chain_time_codes")


def test_simultaneous_replies_arrive_intact_in_node_order():
    rng = np.random.default_rng(31)
    chain = Chain(3, codec=SHORT)
    replies_a = {k: rng.integers(0, 256, size=proto.DATA_PAYLOAD).tolist() for k in (1, 2, 3)}
    replies_c = {k: rng.integers(0, 256, size=proto.DATA_PAYLOAD).tolist() for k in (1, 2, 3)}
    requests = {k: rng.integers(0, 256, size=proto.DATA_PAYLOAD).tolist() for k in (1, 2, 3)}

    def node_host(k):
        node = chain.nodes[k - 1]

        async def testbench(ctx):
            # Comm A: every node answers the time-code at once.
            await ctx.tick().until(node.tc_strobe)
            seq = ctx.get(node.tc_time)
            await node_send(ctx, node, proto.Header(0, 0, int(proto.PacketType.COMM_A), seq),
                            replies_a[k])
            # Comm B -> Comm C: answer the request as soon as it is in.
            header, payload = await node_receive(ctx, node)
            assert (header.src, header.type, list(payload)) == (0, proto.PacketType.COMM_B,
                                                                requests[k])
            await node_send(ctx, node, proto.Header(0, 0, int(proto.PacketType.COMM_C), header.seq),
                            replies_c[k])
        return testbench

    async def master(ctx):
        await bring_up(ctx, chain, 1000)
        await send_time_code(ctx, chain, 5)
        while not comm_a_done:
            await ctx.tick()
        # Requests to the three nodes back to back, while their replies come back.
        for k in (1, 2, 3):
            await master_send(ctx, chain, proto.Header(k, 0, int(proto.PacketType.COMM_B), 10 + k),
                              requests[k])

    async def time_code_under_load(ctx):
        # A time-code in the middle of the requests: it waits behind a data character.
        while not comm_a_done:
            await ctx.tick()
        await ctx.tick().repeat(60)
        assert ctx.get(chain.master_tx.valid), "the link should be busy with a request"
        loaded_tc.append(await send_time_code(ctx, chain, 6))

    comm_a_done = []
    loaded_tc = []
    arrivals = {k: [] for k in (1, 2, 3)}

    def monitor(k):
        node = chain.nodes[k - 1]

        async def testbench(ctx):
            async for _, _, strobe, stamp, value in ctx.tick().sample(
                    node.tc_strobe, node.tc_stamp, node.tc_time):
                if strobe:
                    arrivals[k].append((value, stamp))
        return testbench

    async def master_rx(ctx):
        packets = await master_receive(ctx, chain, 3)
        checked = [proto.check_frame(p) for p in packets]
        assert [c[0] for c in checked] == [proto.Verdict.GOOD] * 3
        assert [c[1].src for c in checked] == [1, 2, 3], "documented order: node 1, 2, 3"
        for _, header, payload in checked:
            assert header == proto.Header(0, header.src, proto.PacketType.COMM_A, 5)
            assert list(payload) == replies_a[header.src]
        comm_a_done.append(True)
        packets = await master_receive(ctx, chain, 3)
        checked = [proto.check_frame(p) for p in packets]
        assert [c[0] for c in checked] == [proto.Verdict.GOOD] * 3
        assert [c[1].src for c in checked] == [1, 2, 3]
        for _, header, payload in checked:
            assert header == proto.Header(0, header.src, proto.PacketType.COMM_C, 10 + header.src)
            assert list(payload) == replies_c[header.src]
        for node in chain.nodes:
            assert read_stats(ctx, node.rx_stats) == {"good": 1, "crc": 0, "length": 0, "eep": 0}
            assert ctx.get(node.dropped) == 0
            assert not any(read_stats(ctx, node.up_errors).values())
        assert [[v for v, _ in arrivals[k]] for k in (1, 2, 3)] == [[5, 6]] * 3
        check_hops(loaded_tc[0], [arrivals[k][1][1] for k in (1, 2, 3)])

    sim = Simulator(chain)
    sim.add_clock(20e-9)
    for k in (1, 2, 3):
        sim.add_testbench(node_host(k))
        sim.add_testbench(monitor(k), background=True)
    sim.add_testbench(master)
    sim.add_testbench(master_rx)
    sim.add_testbench(time_code_under_load)
    run_simulation(sim, "chain_simultaneous_replies")


@pytest.mark.parametrize("n_nodes, max_payload", [(0, 64), (255, 64), (2, 0)])
def test_chain_rejects_bad_parameters(n_nodes, max_payload):
    with pytest.raises(ValueError):
        Chain(n_nodes, max_payload=max_payload)


def test_chain_starts_at_standard_timers_and_carries_packages_both_ways():
    """ECSS timers (Error-Reset 6.4 µs, Error-Wait 12.8 µs, start at 10 Mbit/s)."""
    rng = np.random.default_rng(32)
    chain = Chain(3)
    down = rng.integers(0, 256, size=proto.DATA_PAYLOAD).tolist()
    up = rng.integers(0, 256, size=proto.DATA_PAYLOAD).tolist()
    last = chain.nodes[-1]

    async def master(ctx):
        cycles = await bring_up(ctx, chain, 3000)
        # Error-Reset + Error-Wait (960 cycles) + the NULL/FCT exchange at 10 Mbit/s.
        assert 960 < cycles < 1500, cycles
        sent = await send_time_code(ctx, chain, 1)
        await master_send(ctx, chain, proto.Header(3, 0, int(proto.PacketType.COMM_D), 1), down)
        stamps = [ctx.get(node.tc_stamp) for node in chain.nodes]
        check_hops(sent, stamps)
        (packet,) = await master_receive(ctx, chain)
        assert proto.check_frame(packet) == (proto.Verdict.GOOD, proto.Header(0, 3, 0x0A, 1),
                                           bytes(up))

    async def node3(ctx):
        header, payload = await node_receive(ctx, last)
        assert (header, list(payload)) == (proto.Header(3, 0, proto.PacketType.COMM_D, 1), down)
        await node_send(ctx, last, proto.Header(0, 0, int(proto.PacketType.COMM_A), header.seq), up)

    sim = Simulator(chain)
    sim.add_clock(20e-9)
    sim.add_testbench(master)
    sim.add_testbench(node3)
    run_simulation(sim, "chain_standard_timers")
