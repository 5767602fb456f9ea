"""Your own component next to the project's link: a byte counter on a codec's receive stream.

Run it:  python examples/testbenches/my_component.py

``PacketCounter`` stands for gateware of your own: it takes the N-chars a codec delivers
(its ``rx`` stream, ``amaranth.lib.stream``), counts data bytes and packets, and is always
ready. It is wired to the project's codec with Amaranth's ``connect`` — the two signatures
fit, so there is nothing to adapt — and driven from the line by the testbench kit's scripted
peer. Copy this file to start a testbench of yours.
"""

from amaranth import Module
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out
from amaranth.sim import Simulator

from mrm_cosim.hdl.link.chars import Char, CharKind
from mrm_cosim.hdl.link.codec import Codec
from mrm_cosim.testbench import LinePeer, run_simulation


class PacketCounter(wiring.Component):
    """Counts data bytes and end-of-packet marks on an N-char stream."""

    rx: In(stream.Signature(Char))
    data_bytes: Out(16)
    packets: Out(16)

    def elaborate(self, platform):
        m = Module()
        m.d.comb += self.rx.ready.eq(1)
        with m.If(self.rx.valid):
            with m.If(self.rx.payload.kind == CharKind.DATA):
                m.d.sync += self.data_bytes.eq(self.data_bytes + 1)
            with m.Else():
                m.d.sync += self.packets.eq(self.packets + 1)
        return m


class Top(wiring.Component):
    """The project's codec with your component on its receive side."""

    d_in: In(6)                 # the codec's default SERDES: 6 line samples per cycle
    s_in: In(6)
    data_bytes: Out(16)
    packets: Out(16)
    running: Out(1)

    def elaborate(self, platform):
        m = Module()
        # The scripted peer grants 8 credits and no more; the codec's credit audit expects a
        # peer like itself (56 at rest, docs/link.md "Lost FCTs"), so it is off here.
        m.submodules.codec = codec = Codec(reset_cycles=60, wait_cycles=150, credit_audit=0)
        m.submodules.counter = counter = PacketCounter()
        wiring.connect(m, codec.rx, counter.rx)           # the signatures fit: no glue
        m.d.comb += [codec.d_in.eq(self.d_in), codec.s_in.eq(self.s_in),
                     codec.link_start.eq(1), self.running.eq(codec.running),
                     self.data_bytes.eq(counter.data_bytes), self.packets.eq(counter.packets)]
        self.codec = codec
        return m


def main(vcd_dir=None) -> dict:
    top = Top()
    peer = LinePeer(slots=6, div=20)                # 15 Mbit/s: 20 slots of 3.33 ns a bit
    result = {}

    async def testbench(ctx):
        for _ in range(5000):                       # start-up: our NULLs after its NULLs
            d, s = peer.cycle()
            ctx.set(top.d_in, d)
            ctx.set(top.s_in, s)
            await ctx.tick()
            if peer.silent and ctx.get(top.codec.state).name == "STARTED":
                peer.silent = False
            if not peer.silent and ctx.get(top.codec.state).name == "CONNECTING":
                break
        peer.send(("FCT",))
        for _ in range(2000):
            d, s = peer.cycle()
            ctx.set(top.d_in, d)
            ctx.set(top.s_in, s)
            await ctx.tick()
            if ctx.get(top.running):
                break
        for _ in range(2):                          # two packets: 3 bytes, then 1 byte
            peer.send(("DATA", 1), ("DATA", 2), ("DATA", 3), ("EOP",))
        peer.send(("DATA", 9), ("EEP",))
        for _ in range(3000):
            d, s = peer.cycle()
            ctx.set(top.d_in, d)
            ctx.set(top.s_in, s)
            await ctx.tick()
        result.update(running=ctx.get(top.running), data_bytes=ctx.get(top.data_bytes),
                      packets=ctx.get(top.packets))

    sim = Simulator(top)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, "my_component", vcd_dir)
    return result


if __name__ == "__main__":
    r = main()
    assert r == {"running": 1, "data_bytes": 7, "packets": 3}, r
    print(f"link running; your counter saw {r['data_bytes']} data bytes in {r['packets']} packets")
