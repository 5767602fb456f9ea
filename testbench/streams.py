"""Stream bus-functional models for Amaranth's simulator (``amaranth.lib.stream``).

Use them inside a testbench coroutine (``sim.add_testbench``)::

    async def bench(ctx):
        await stream_put(ctx, dut.i, 0x42)
        assert await stream_get(ctx, dut.o) == 0x42
"""

__all__ = ["stream_put", "stream_get", "packet_ends"]


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


def packet_ends(stream, ends: list):
    """A background testbench appending to ``ends`` the cycle (counted from 0) in which each
    packet's last beat is taken on ``stream`` (a stream of :class:`~hdl.link.packet.Beat`)."""
    async def monitor(ctx):
        c = 0
        while True:
            _, _, valid, ready, last = await ctx.tick().sample(stream.valid, stream.ready,
                                                                stream.p.last)
            if valid and ready and last:
                ends.append(c)
            c += 1

    return monitor
