"""A testbench of the SpaceWire-like codec: link start-up, a packet each way, a parity fault.

Run it:  python examples/testbenches/codec_link.py [--vcd DIR]

The device under test is the project's codec (``mrm_cosim.hdl.link.codec.Codec``); the far end
is the testbench kit's :class:`~mrm_cosim.testbench.PeerBench`: a scripted peer that speaks the
standard at line level (data-strobe bits, NULLs between characters) and a monitor that decodes
what the codec sends. Nothing here uses the codec's Python reference: the peer is an
independent model of ECSS-E-ST-50-12C §7 (characters) and §8.5 (link start-up, errors).
"""

import argparse

from amaranth.sim import Simulator

from mrm_cosim.hdl.link.chars import CharKind
from mrm_cosim.hdl.link.codec_ref import char_value
from mrm_cosim.testbench import (PeerBench, assert_error_counts, assert_link_state,
                                 run_simulation)

DATA, EOP, EEP = (k.value for k in CharKind)


def main(vcd_dir=None) -> dict:
    bench = PeerBench(reset_cycles=60, wait_cycles=150)     # shorter timers than the default
    dut = bench.dut
    out = {}

    async def testbench(ctx):
        # 1. Start-up (§8.5.2): ErrorReset → ErrorWait → Ready → Started → Connecting → Run.
        await bench.bring_up(ctx)
        assert_link_state(ctx, dut, "RUN")
        assert_error_counts(ctx, dut)                        # a clean start-up: all zero
        out["running_after_cycles"] = bench.cycles

        # 2. A packet from the peer: three data bytes and an end of packet.
        bench.peer.send(("DATA", 0x12), ("DATA", 0x34), ("DATA", 0x56), ("EOP",))
        await bench.until(ctx, lambda: len(bench.received) == 4, limit=500)
        out["received"] = list(bench.received)

        # 3. A packet to the peer through the codec's host stream (an N-char per beat).
        for value in (char_value(DATA, 0xA5), char_value(EOP)):
            ctx.set(dut.tx.payload.as_value(), value)
            ctx.set(dut.tx.valid, 1)
            await bench.until(ctx, lambda: ctx.get(dut.tx.ready), limit=200)
            await bench.cycle(ctx)
        ctx.set(dut.tx.valid, 0)
        await bench.until(ctx, lambda: ("EOP",) in [t for _, t in bench.monitor.tokens],
                          limit=500)
        out["sent_on_the_line"] = [t for _, t in bench.monitor.tokens if t[0] in ("DATA", "EOP")]

        # 4. A parity fault: a bit flipped on the line. The codec counts a parity error and
        #    resets the link (§8.5.3); the peer sees the codec go silent, does the same, and
        #    the two start the link again.
        bench.peer.send(("DATA", 0x77, "corrupt"), ("DATA", 0x00))
        await bench.until(ctx, lambda: not ctx.get(dut.running), limit=400)
        out["errors"] = bench.errors(ctx)
        assert_error_counts(ctx, dut, parity=1)
        bench.peer.bits.clear()
        bench.peer.silent = True
        bench.peer.div = dut.start_div
        bench.monitor.tokens.clear()
        await bench.bring_up(ctx)
        assert_link_state(ctx, dut, "RUN")
        out["running_again"] = bool(ctx.get(dut.running))

    sim = Simulator(dut)
    sim.add_clock(20e-9)                                     # 50 MHz
    sim.add_testbench(testbench)
    run_simulation(sim, "codec_link", vcd_dir)
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vcd", metavar="DIR", help="write codec_link.vcd into DIR")
    result = main(ap.parse_args().vcd)
    assert result["received"] == [char_value(DATA, 0x12), char_value(DATA, 0x34),
                                  char_value(DATA, 0x56), char_value(EOP)]
    assert result["sent_on_the_line"][-2:] == [("DATA", 0xA5), ("EOP",)]
    assert result["errors"]["parity"] == 1 and result["running_again"]
    print(f"link up after {result['running_after_cycles']} cycles; packet in: "
          f"{len(result['received'])} N-chars; packet out seen on the line; parity fault "
          f"counted ({result['errors']}) and the link restarted")
