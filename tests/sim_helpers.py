"""Shared simulation helpers: stream BFMs, VCD-on-request runner, a faulty line, a codec pair.

Start from the house example (after the Amaranth stream docs and Glasgow); the packet layer's
tests import these too.
"""

import contextlib
import os

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out
from amaranth.sim import Simulator

from hdl.link.codec import Codec

__all__ = ["stream_put", "stream_get", "run_simulation", "FaultyLine", "CodecPair"]


async def stream_put(ctx, stream, payload):
    """Offer ``payload`` on ``stream`` until it is taken."""
    ctx.set(stream.payload, payload)
    ctx.set(stream.valid, 1)
    await ctx.tick().until(stream.ready)
    ctx.set(stream.valid, 0)


async def stream_get(ctx, stream):
    """Take one payload from ``stream``."""
    ctx.set(stream.ready, 1)
    payload, = await ctx.tick().sample(stream.payload).until(stream.valid)
    ctx.set(stream.ready, 0)
    return payload


def run_simulation(sim: Simulator, name: str):
    """Run ``sim``; dump ``<name>.vcd`` into ``$SIM_VCD_DIR`` when that is set."""
    vcd_dir = os.environ.get("SIM_VCD_DIR")
    if vcd_dir:
        os.makedirs(vcd_dir, exist_ok=True)
        writer = sim.write_vcd(os.path.join(vcd_dir, f"{name}.vcd"))
    else:
        writer = contextlib.nullcontext()
    with writer:
        sim.run()


class FaultyLine(wiring.Component):
    """One direction of a data-strobe line with fault injection, purely combinational.

    Each line sample is ``((x & ~clear) | set) ^ flip`` per slot: clear both lines to cut the
    wire, set or clear one to make it stuck, flip a slot for a single bit error.
    """

    def __init__(self, slots: int):
        self.slots = slots
        super().__init__({
            "d_in":    In(slots), "s_in":    In(slots),
            "d_out":   Out(slots), "s_out":  Out(slots),
            "clear_d": In(slots), "clear_s": In(slots),
            "set_d":   In(slots), "set_s":   In(slots),
            "flip_d":  In(slots), "flip_s":  In(slots),
        })

    def elaborate(self, platform):
        m = Module()
        m.d.comb += [
            self.d_out.eq(((self.d_in & ~self.clear_d) | self.set_d) ^ self.flip_d),
            self.s_out.eq(((self.s_in & ~self.clear_s) | self.set_s) ^ self.flip_s),
        ]
        return m


class CodecPair(Elaboratable):
    """Two codecs ``a`` and ``b`` wired back to back through ``ab`` and ``ba`` faulty lines."""

    def __init__(self, **codec_args):
        self.a = Codec(**codec_args)
        self.b = Codec(**codec_args)
        self.ab = FaultyLine(self.a.slots)
        self.ba = FaultyLine(self.a.slots)

    def elaborate(self, platform):
        m = Module()
        m.submodules.a = self.a
        m.submodules.b = self.b
        m.submodules.ab = self.ab
        m.submodules.ba = self.ba
        for src, line, dst in ((self.a, self.ab, self.b), (self.b, self.ba, self.a)):
            m.d.comb += [
                line.d_in.eq(src.d_out),
                line.s_in.eq(src.s_out),
                dst.d_in.eq(line.d_out),
                dst.s_in.eq(line.s_out),
            ]
        return m
