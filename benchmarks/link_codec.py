"""SpaceWire codec figures: pysim and reference cycles/s of a codec pair; fault recovery times.

Run on purpose (not a test): ``python benchmarks/link_codec.py [--cycles N] [--slots W]
[--recovery]``. The pair is wired back to back, starts with the standard timers and then
streams packets both ways at the run rate; the clock is free-running (no per-cycle Python
testbench), which is how a co-simulation steps the gateware between exchanges with the master.
``--recovery`` injects line faults a -> b into a pair streaming data both ways (standard
timers) and prints, per fault, when the link went down and when both ends were back in Run,
counted from the first faulty cycle, with the error counters.
"""

import argparse
import time

from amaranth import *
from amaranth.sim import Simulator

from mrm_cosim.hdl.link.chars import CharKind
from mrm_cosim.hdl.link.codec import Codec
from mrm_cosim.hdl.link.codec_ref import CodecRef, char_value


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


def _params(slots):
    """150 Mbit/s where the width allows it (2 slots per bit at 6, 1 at 3), else 1 slot/bit."""
    return dict(slots=slots, run_div=max(1, slots // 3))


def bench_pysim(cycles, slots):
    pair = _Pair(**_params(slots))
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
    a, b = CodecRef(**_params(slots)), CodecRef(**_params(slots))
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


FAULTS = [
    # name, ((clear, set, flip) on D, (clear, set, flip) on S), cycles
    # (default SERDES: 6 slots of 3.33 ns per cycle, a bit is 2 slots)
    ("cut (both lines low) 2 us", ((63, 0, 0), (63, 0, 0)), 100),
    ("D stuck high 2 us", ((0, 63, 0), (0, 0, 0)), 100),
    ("S stuck low 2 us", ((0, 0, 0), (63, 0, 0)), 100),
    ("D glitch, one 3.3 ns slot", ((0, 0, 4), (0, 0, 0)), 1),
    ("bit error (D and S, one bit)", ((0, 0, 12), (0, 0, 12)), 1),
]


def bench_recovery():
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from mrm_cosim.testbench import PairBench

    rows = []
    for name, fault, duration in FAULTS:
        bench = PairBench()
        result = {}

        async def testbench(ctx, bench=bench, fault=fault, duration=duration, result=result):
            await bench.bring_up(ctx)
            for who in "ab":
                bench.tx[who] = [char_value(CharKind.DATA.value, 0x80 | (n & 0x0F))
                                 for n in range(4000)]
            await bench.run(ctx, 50)
            start = bench.cycles
            bench.faults["ab"] = fault
            for n in range(5000):
                if n == duration:
                    bench.faults.clear()
                both = ctx.get(bench.pair.a.running) and ctx.get(bench.pair.b.running)
                if "down" not in result and not both:
                    result["down"] = bench.cycles - start
                if "down" in result and both:
                    result["up"] = bench.cycles - start
                    break
                await bench.cycle(ctx)
            result["errors"] = (bench.errors(ctx, "a"), bench.errors(ctx, "b"))

        bench.simulate(testbench, "recovery")
        # Data characters sent here all have bit 7 set: a received one without it is garbage
        # the line fault produced and parity could not see.
        garbage = sum(1 for v in bench.received["b"]
                      if (v & 3) == CharKind.DATA.value and not (v >> 2) & 0x80)
        rows.append((name, result, garbage))

    print("fault a -> b (standard timers)   down after   both in Run after   errors a / b"
          "   bad chars delivered")
    for name, result, garbage in rows:
        def fmt(errors):
            return ",".join(f"{k}={v}" for k, v in errors.items() if v) or "-"
        errors_a, errors_b = result["errors"]
        down, up = result["down"] * 20 / 1000, result["up"] * 20 / 1000
        print(f"{name:32s} {down:8.2f} us   {up:10.2f} us      {fmt(errors_a)} / "
              f"{fmt(errors_b)}   {garbage}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=20_000)
    parser.add_argument("--slots", type=int, default=6)
    parser.add_argument("--recovery", action="store_true", help="also measure fault recovery")
    args = parser.parse_args()
    rate, received = bench_pysim(args.cycles, args.slots)
    print(f"pysim     codec pair, {args.slots} slots: {rate:8.0f} cycles/s "
          f"({args.cycles} cycles, {received} N-chars received by b)")
    rate, received = bench_reference(args.cycles, args.slots)
    print(f"reference codec pair, {args.slots} slots: {rate:8.0f} cycles/s "
          f"({args.cycles} cycles, {received} N-chars received by b)")
    if args.recovery:
        bench_recovery()


if __name__ == "__main__":
    main()
