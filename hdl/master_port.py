"""The master's link port: one SpaceWire codec with host buffers a processor would have.

The MRM master is a PowerPC whose SpaceWire codec sits in the FPGA fabric beside it (MRM paper
§4); software frames and checks packets. This port is that codec plus the buffers between it
and software: characters written by the master go into a transmit FIFO (no handshake: software
checks ``tx_level`` before writing, and a write into a full FIFO is counted in
``tx_overflow`` rather than lost silently), and received characters are presented one per cycle
(the master always accepts; the codec's credit flow control is what throttles the peer).

The master starts the link (``link_start``); the first node waits for it (``auto_start``).
"""

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.fifo import SyncFIFOBuffered
from amaranth.lib.wiring import In, Out

from .link.chars import Char, ErrorCounts, LinkState
from .link.codec import Codec
from .link.node import line_signature

__all__ = ["MasterPort"]


class MasterPort(wiring.Component):
    """Master-side link endpoint.

    Parameters
    ----------
    codec : dict
        Keyword arguments of the :class:`~hdl.link.codec.Codec` (slots, timers, ...).
    tx_depth : int
        Transmit FIFO depth in characters.

    Attributes
    ----------
    tx_valid : In(1), tx_char : In(Char)
        Write one character into the transmit FIFO this cycle.
    tx_level : Out(range(tx_depth + 1))
        Characters waiting in the transmit FIFO.
    tx_overflow : Out(16)
        Writes lost to a full FIFO (saturating); never expected, always checked.
    rx_valid : Out(1), rx_char : Out(Char)
        A received character this cycle.
    tick_in : In(1), time_in : In(8)
        Send a time-code.
    line : Out(line_signature(slots))
        The line to node 1.
    running : Out(1), state : Out(LinkState), errors : Out(ErrorCounts)
    """

    def __init__(self, *, codec: dict | None = None, tx_depth: int = 256):
        if not isinstance(tx_depth, int) or tx_depth < 64:
            raise ValueError(f"tx_depth must be an integer of at least 64, not {tx_depth!r}")
        self.codec = Codec(**(codec or {}))
        self.tx_depth = tx_depth
        super().__init__({
            "tx_valid":    In(1),
            "tx_char":     In(Char),
            "tx_level":    Out(range(tx_depth + 1)),
            "tx_overflow": Out(16),
            "rx_valid":    Out(1),
            "rx_char":     Out(Char),
            "tick_in":     In(1),
            "time_in":     In(8),
            "line":        Out(line_signature(self.codec.slots)),
            "running":     Out(1),
            "state":       Out(LinkState),
            "errors":      Out(ErrorCounts),
        })

    def elaborate(self, platform):
        m = Module()
        m.submodules.codec = codec = self.codec
        m.submodules.fifo = fifo = SyncFIFOBuffered(width=len(self.tx_char.as_value()),
                                                    depth=self.tx_depth)
        m.d.comb += [
            fifo.w_data.eq(self.tx_char.as_value()),
            fifo.w_en.eq(self.tx_valid),
            self.tx_level.eq(fifo.level),
            codec.tx.payload.eq(fifo.r_data),
            codec.tx.valid.eq(fifo.r_rdy),
            fifo.r_en.eq(codec.tx.ready),
            codec.rx.ready.eq(1),
            self.rx_valid.eq(codec.rx.valid),
            self.rx_char.eq(codec.rx.payload),
            codec.tick_in.eq(self.tick_in),
            codec.time_in.eq(self.time_in),
            codec.link_start.eq(1),
            codec.auto_start.eq(0),
            codec.link_disable.eq(0),
            self.running.eq(codec.running),
            self.state.eq(codec.state),
            self.errors.eq(codec.errors),
            self.line.d_out.eq(codec.d_out),
            self.line.s_out.eq(codec.s_out),
            codec.d_in.eq(self.line.d_in),
            codec.s_in.eq(self.line.s_in),
        ]
        with m.If(self.tx_valid & ~fifo.w_rdy & (self.tx_overflow != 0xFFFF)):
            m.d.sync += self.tx_overflow.eq(self.tx_overflow + 1)
        return m
