"""Daisy-chain figures: pysim cycles/s of a 3-node chain and the payload share of the line.

Run on purpose (not a test): ``python benchmarks/link_chain.py [--cycles N] [--nodes N]
[--short-timers]``. The chain (master codec + N link nodes, standard timers unless
``--short-timers``) starts up; then the master streams 40-byte packages to nodes 1..N in turn
and every node answers each with a 40-byte package, so the master's link is loaded both ways.
Both directions of the master's line are decoded bit by bit (data-strobe transitions, then
characters, parity checked) and every line bit of a window of ``--cycles`` cycles is put into
one of: payload, packet header, CRC, data-character parity/flag bits, EOP, FCT, NULL, time-code.
The useful payload rate is the payload share of the line bits (150 Mbit/s in Run).
"""

import argparse
import time

import numpy as np
from amaranth.sim import Simulator

from mrm_cosim.protocol import packet as ref
from mrm_cosim.hdl.link.chain import Chain, get_packet, master_send, put_packet
from mrm_cosim.protocol.link import CONTROL_BITS, DATA_BITS, NULL_BITS, TIME_BITS

_CONTROL = {(0, 0): "FCT", (1, 0): "EOP", (0, 1): "EEP", (1, 1): "ESC"}  # (C0, C1)


class WireDecoder:
    """Characters on one direction of a data-strobe line, with the cycle each one ended in."""

    def __init__(self, slots: int):
        self.slots = slots
        self.prev = (0, 0)
        self.bits = []
        self.bit_cycle = []
        self.pos = None           # index of the next character's parity bit, once framed
        self.par = 0
        self.esc = False
        self.tokens = []          # (cycle, kind, value)
        self.parity_errors = 0

    def feed(self, cycle: int, d_word: int, s_word: int):
        for i in range(self.slots):
            cur = ((d_word >> i) & 1, (s_word >> i) & 1)
            if cur != self.prev:  # one of D, S changes per bit
                self.bits.append(cur[0])
                self.bit_cycle.append(cycle)
            self.prev = cur
        self._frame()

    def _frame(self):
        b = self.bits
        if self.pos is None:      # the first NULL: ESC (P111) then FCT (0100)
            for k in range(max(0, len(b) - 16), len(b) - 7):
                if b[k + 1:k + 8] == [1, 1, 1, 0, 1, 0, 0]:
                    self.pos, self.par = k + 8, 0
                    break
            return
        while True:
            k = self.pos
            if len(b) < k + 2:
                return
            flag = b[k + 1]
            n = 2 if flag else 8
            if len(b) < k + 2 + n:
                return
            self.parity_errors += (self.par ^ b[k] ^ flag) != 1
            payload = b[k + 2:k + 2 + n]
            self.par = sum(payload) & 1
            self.pos = k + 2 + n
            cycle = self.bit_cycle[k + 1 + n]
            if flag:
                code = _CONTROL[tuple(payload)]
                if self.esc:
                    self.esc = False
                    self.tokens.append((cycle, "NULL" if code == "FCT" else "ESC-" + code, 0))
                elif code == "ESC":
                    self.esc = True
                else:
                    self.tokens.append((cycle, code, 0))
            else:
                value = sum(bit << i for i, bit in enumerate(payload))
                self.tokens.append((cycle, "TIME" if self.esc else "DATA", value))
                self.esc = False


def line_budget(tokens, start, stop):
    """Line bits per category for the characters that ended in cycles [start, stop)."""
    budget = dict.fromkeys(["payload", "header", "crc", "parity+flag", "EOP", "FCT", "NULL",
                            "time-code"], 0)
    packet = []   # cycles of the data characters of the packet in progress
    for cycle, kind, _ in tokens:
        inside = start <= cycle < stop
        if kind == "DATA":
            packet.append(cycle)
            budget["parity+flag"] += 2 * inside
        elif kind in ("EOP", "EEP"):
            for index, c in enumerate(packet):
                if not start <= c < stop:
                    continue
                if index < ref.HEADER_BYTES:
                    budget["header"] += 8
                elif index >= len(packet) - ref.CRC_BYTES:
                    budget["crc"] += 8
                else:
                    budget["payload"] += 8
            packet = []
            budget["EOP"] += CONTROL_BITS * inside
        elif kind == "FCT":
            budget["FCT"] += CONTROL_BITS * inside
        elif kind == "NULL":
            budget["NULL"] += NULL_BITS * inside
        elif kind == "TIME":
            budget["time-code"] += TIME_BITS * inside
    return budget


def analytic_share(payload: int = ref.DATA_PAYLOAD) -> tuple[float, float]:
    """Payload share of the line for back-to-back packages: one way, and both ways loaded.

    One way: ``8 n / (10 (n + 6) + 4)``. Both ways: each direction also carries one 4-bit FCT
    per 8 N-chars received on the other direction.
    """
    n_chars = payload + ref.HEADER_BYTES + ref.CRC_BYTES
    frame_bits = DATA_BITS * n_chars + CONTROL_BITS
    fct_bits = CONTROL_BITS * (n_chars + 1) / 8
    return 8 * payload / frame_bits, 8 * payload / (frame_bits + fct_bits)


def free_running(n_nodes: int, codec: dict, cycles: int = 2000) -> float:
    """pysim cycles/s of the chain with no testbench: start-up, then NULLs on every link."""
    sim = Simulator(Chain(n_nodes, codec=codec))
    sim.add_clock(20e-9)
    sim.run_until(10 * 20e-9)           # elaboration and the first steps out of the timing
    t0 = time.perf_counter()
    sim.run_until((10 + cycles) * 20e-9)
    return cycles / (time.perf_counter() - t0)


def run(cycles: int, n_nodes: int, short: bool):
    codec = {"reset_cycles": 60, "wait_cycles": 150} if short else {}
    free = free_running(n_nodes, codec)
    chain = Chain(n_nodes, codec=codec)
    slots = chain.master.slots
    down, up = WireDecoder(slots), WireDecoder(slots)
    rng = np.random.default_rng(0)
    marks = {}
    replies = [0] * n_nodes

    async def wires(ctx):
        first = chain.nodes[0]
        async for _, _, cycle, d_down, s_down, d_up, s_up in ctx.tick().sample(
                chain.cycle, chain.master.d_out, chain.master.s_out,
                first.up.d_out, first.up.s_out):
            down.feed(cycle, d_down, s_down)
            up.feed(cycle, d_up, s_up)

    def node_host(k):
        node = chain.nodes[k - 1]

        async def testbench(ctx):
            while True:
                header, payload = await get_packet(ctx, node.rx)
                await put_packet(ctx, node.tx, ref.Header(0, 0, ref.PacketType.COMM_C,
                                                          header.seq), payload[::-1])
                replies[k - 1] += 1
        return testbench

    async def master_rx(ctx):
        ctx.set(chain.master_rx.ready, 1)

    async def master(ctx):
        t0 = time.perf_counter()
        while not (ctx.get(chain.master_running) and
                   all(ctx.get(node.up_running) for node in chain.nodes)):
            await ctx.tick()
        marks["up"] = (ctx.get(chain.cycle), time.perf_counter() - t0)
        seq = 0
        started = None
        while True:
            for k in range(1, n_nodes + 1):
                payload = rng.integers(0, 256, size=ref.DATA_PAYLOAD).tolist()
                await master_send(ctx, chain, ref.Header(k, 0, ref.PacketType.COMM_B,
                                                         seq & 0xFF), payload)
                seq += 1
                now = ctx.get(chain.cycle)
                if started is None and now > marks["up"][0] + 600:
                    started = (now, time.perf_counter())
                if started is not None and now >= started[0] + cycles:
                    marks["window"] = (started[0], now, time.perf_counter() - started[1])
                    await ctx.tick().repeat(300)  # let the packets cut by the window end
                    return

    sim = Simulator(chain)
    sim.add_clock(20e-9)
    sim.add_testbench(wires, background=True)
    sim.add_testbench(master_rx)
    for k in range(1, n_nodes + 1):
        sim.add_testbench(node_host(k), background=True)
    sim.add_testbench(master)
    sim.run()

    up_cycles, up_seconds = marks["up"]
    start, stop, seconds = marks["window"]
    print(f"{n_nodes}-node chain ({'short' if short else 'standard'} timers), "
          f"{slots} line bits per 20 ns cycle in Run")
    print(f"  free-running (no testbench): pysim {free:,.0f} cycles/s")
    print(f"  start-up: all links in Run after {up_cycles} cycles ({up_cycles * 20e-3:.1f} µs);"
          f" pysim {up_cycles / up_seconds:,.0f} cycles/s (with the line decoder)")
    print(f"  loaded:   {stop - start} cycles in {seconds:.1f} s: pysim "
          f"{(stop - start) / seconds:,.0f} cycles/s (with a per-cycle line decoder)")
    print(f"  replies sent per node: {replies}")
    one_way, both_ways = analytic_share()
    for name, decoder in (("master -> node 1", down), ("node 1 -> master", up)):
        budget = line_budget(decoder.tokens, start, stop)
        total = slots * (stop - start)
        print(f"  line {name}: {total} bits in the window, {decoder.parity_errors} parity "
              f"errors")
        for key, bits in budget.items():
            print(f"    {key:12s} {bits:7d} bits  {100 * bits / total:5.1f} %")
        print(f"    {'(unassigned)':12s} {total - sum(budget.values()):7d} bits  (characters "
              f"cut by the window's edges)")
        share = budget["payload"] / total
        print(f"    useful payload rate {100 * share:.1f} % of the line = "
              f"{150 * share:.1f} Mbit/s")
    print(f"  analytic, 40-byte packages back to back: {100 * one_way:.1f} % one way, "
          f"{100 * both_ways:.1f} % with the other direction's FCTs")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=3000, help="loaded window, cycles")
    parser.add_argument("--nodes", type=int, default=3)
    parser.add_argument("--short-timers", action="store_true")
    args = parser.parse_args(argv)
    run(args.cycles, args.nodes, args.short_timers)


if __name__ == "__main__":
    main()
