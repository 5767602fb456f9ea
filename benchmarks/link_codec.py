"""Simulation speed of the SpaceWire codec: pysim cycles/s of a codec pair, reference cycles/s.

Run on purpose (not a test): ``python benchmarks/link_codec.py [--cycles N] [--slots W]``.
The pair is wired back to back, starts with the standard timers and then streams packets
both ways at the run rate; the clock is free-running (no per-cycle Python testbench), which is
how a co-simulation steps the gateware between exchanges with the master.
"""

import argparse
import time

from amaranth import *
from amaranth.sim import Simulator

from hdl.link.chars import CharKind
from hdl.link.codec import Codec
from hdl.link.codec_ref import CodecRef, char_value


class _Pair(Elaboratable):
    """Two codecs back to back, each sending a counting byte stream with an EOP every 40."""

    def __init__(self, **params):
        self.a = Codec(**params)
        self.b = Codec(**params)

    def elaborate(self, platform):
        m = Module()
        m.submodules.a, m.submodules.b = self.a, self.b
        for src, dst in ((self.a, self.b), (self.b, self.a)):
            m.d.comb += [dst.d_in.eq(src.d_out), dst.s_in.eq(src.s_out)]
        for codec in (self.a, self.b):
            count = Signal(6)
            m.d.comb += [
                codec.link_start.eq(1),
                codec.tx.valid.eq(1),
                codec.tx.payload.kind.eq(Mux(count == 39, CharKind.EOP, CharKind.DATA)),
                codec.tx.payload.data.eq(count),
                codec.rx.ready.eq(1),
            ]
            with m.If(codec.tx.valid & codec.tx.ready):
                m.d.sync += count.eq(Mux(count == 39, 0, count + 1))
        return m


def bench_pysim(cycles, slots):
    pair = _Pair(slots=slots)
    sim = Simulator(pair)
    sim.add_clock(20e-9)
    received = 0

    async def count_rx(ctx):
        nonlocal received
        async for *_, valid in ctx.tick().sample(pair.b.rx.valid):
            received += valid

    sim.add_testbench(count_rx, background=True)
    start = time.perf_counter()
    sim.run_until(cycles * 20e-9)
    return cycles / (time.perf_counter() - start), received


def bench_reference(cycles, slots):
    a, b = CodecRef(slots=slots), CodecRef(slots=slots)
    count = {"a": 0, "b": 0}
    received = 0
    start = time.perf_counter()
    for _ in range(cycles):
        oa, ob = a.outputs(), b.outputs()
        received += ob.rx_valid
        steps = []
        for who, ref, out, peer in (("a", a, oa, ob), ("b", b, ob, oa)):
            c = count[who]
            payload = char_value(CharKind.EOP.value if c == 39 else CharKind.DATA.value, c)
            if out.tx_ready:
                count[who] = 0 if c == 39 else c + 1
            steps.append((ref, dict(d_in=peer.d_out, s_in=peer.s_out, tx_valid=1,
                                    tx_payload=payload, rx_ready=1, link_start=1)))
        for ref, inputs in steps:
            ref.step(**inputs)
    return cycles / (time.perf_counter() - start), received


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=20_000)
    parser.add_argument("--slots", type=int, default=3)
    args = parser.parse_args()
    rate, received = bench_pysim(args.cycles, args.slots)
    print(f"pysim     codec pair, {args.slots} slots: {rate:8.0f} cycles/s "
          f"({args.cycles} cycles, {received} N-chars received by b)")
    rate, received = bench_reference(args.cycles, args.slots)
    print(f"reference codec pair, {args.slots} slots: {rate:8.0f} cycles/s "
          f"({args.cycles} cycles, {received} N-chars received by b)")


if __name__ == "__main__":
    main()
