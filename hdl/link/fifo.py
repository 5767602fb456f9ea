"""The codecs' receive FIFO in block RAM, with the timing of Amaranth's ``SyncFIFO``.

``SyncFIFO`` reads its memory combinationally (``r_data`` is the entry at the read pointer in
the same cycle), which Virtex-II can only build from distributed RAM: 64 ten-bit entries took
80 LUT4 sites per codec (ten ``RAM64X1D``), 160 on the node. A block RAM reads on the clock
edge, so this FIFO addresses it ahead of the read pointer, with the read port transparent to
the write port, and shows its head from a register (below): in every cycle ``r_data`` is the
entry at the read pointer as memory holds it then — exactly what the combinational read
shows. ``r_data``, ``r_rdy``, ``w_rdy`` and ``level`` are therefore the same as
``SyncFIFO``'s in every cycle (tests/test_codec_fifo.py checks it cycle by cycle against
``SyncFIFO`` under random traffic); only the memory moved. The memory starts
zeroed, as ``SyncFIFO``'s, so even the stale ``r_data`` of an empty FIFO agrees.

``r_data`` itself is a fabric register, ``head``, not the block RAM's output: a block RAM's
clock-to-output (about 5.8 ns on an ECP5, where a flip-flop's is under 1 ns) was the start of
the node's slowest path, the router's routing decision on the packet's first character
(docs/node.md, Clock). The RAM is addressed with the entry after the next cycle's read
pointer, and ``head`` takes the RAM's output when a read advances the pointer; a write into
the entry ``head`` is about to hold (into an empty FIFO, or behind the last entry while it is
read) goes to ``head`` directly. So ``head`` is the entry at the read pointer in every cycle,
as memory holds it.
"""

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out

__all__ = ["BlockRamFIFO"]


class BlockRamFIFO(wiring.Component):
    """First-word-fall-through FIFO in block RAM, cycle for cycle ``SyncFIFO``.

    Parameters
    ----------
    width, depth : int
        Entry width in bits, number of entries (at least 1).

    Attributes
    ----------
    w_en, w_data, w_rdy, r_en, r_data, r_rdy, level
        As :class:`amaranth.lib.fifo.SyncFIFO`'s.
    """

    def __init__(self, *, width: int, depth: int):
        if depth < 1:
            raise ValueError(f"FIFO depth must be at least 1, not {depth}")
        self.width, self.depth = width, depth
        super().__init__({
            "w_en":   In(1),
            "w_data": In(width),
            "w_rdy":  Out(1),
            "r_en":   In(1),
            "r_data": Out(width),
            "r_rdy":  Out(1),
            "level":  Out(range(depth + 1)),
        })

    def elaborate(self, platform):
        m = Module()
        depth = self.depth
        m.d.comb += [
            self.w_rdy.eq(self.level != depth),
            self.r_rdy.eq(self.level != 0),
        ]
        do_read = self.r_rdy & self.r_en
        do_write = self.w_rdy & self.w_en

        m.submodules.storage = storage = Memory(shape=self.width, depth=depth, init=[],
                                                attrs={"ram_style": "block"})
        w_port = storage.write_port()
        r_port = storage.read_port(transparent_for=(w_port,))
        produce = Signal(range(depth))
        consume = Signal(range(depth))
        consume_next = Signal(range(depth))

        def incr(ptr):
            if depth == 1 << len(ptr):
                return (ptr + 1)[:len(ptr)]
            return Mux(ptr == depth - 1, 0, ptr + 1)

        # head = memory[consume] in every cycle (the module's docstring); the RAM shows
        # memory[consume + 1] (its address: the entry after consume_next).
        head = Signal(self.width)
        after = incr(consume)
        m.d.comb += [
            w_port.addr.eq(produce),
            w_port.data.eq(self.w_data),
            w_port.en.eq(do_write),
            consume_next.eq(Mux(do_read, after, consume)),
            r_port.addr.eq(Mux(do_read, incr(after), after)),
            self.r_data.eq(head),
        ]
        m.d.sync += consume.eq(consume_next)
        # The entry written this cycle is the one head holds next: the FIFO is empty and not
        # read (produce = consume), or holds one entry that is read (produce = consume + 1).
        with m.If(do_write & Mux(do_read, self.level == 1, self.level == 0)):
            m.d.sync += head.eq(self.w_data)
        with m.Elif(do_read):
            m.d.sync += head.eq(r_port.data)
        with m.If(do_write):
            m.d.sync += produce.eq(incr(produce))
        with m.If(do_write & ~do_read):
            m.d.sync += self.level.eq(self.level + 1)
        with m.If(do_read & ~do_write):
            m.d.sync += self.level.eq(self.level - 1)
        return m
