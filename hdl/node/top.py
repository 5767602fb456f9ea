"""The slave node: the chain endpoint of the link with the node compute core behind it.

::

    up line ═══ LinkNode ═══ down line        (codecs, router, packet layer, time-codes)
                  │ rx/tx beats, tc_strobe
               NodeCore ── enc_a, enc_b (encoder lines)
                  └──────── torque, brake, status

This is the ``node`` top of ``mrm hdl verilog`` / ``mrm hdl synth``; ``node_core`` is the
compute core alone (for its resource figures without the link).
"""

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.encoder import EncoderParams
from mrm_cosim.protocol.fixed import WORD
from mrm_cosim.protocol.link import DEFAULT_RUN_DIV, DEFAULT_SLOTS

from ..helpers import rejecting
from ..link.node import LinkNode, line_signature
from .core import NodeCore

__all__ = ["SlaveNode", "slave_node_top", "node_core_top"]


class SlaveNode(wiring.Component):
    """One module's FPGA: link endpoint plus compute core.

    Parameters
    ----------
    codec : dict
        :class:`~hdl.link.codec.Codec` parameters of both link ports.
    encoder : EncoderParams

    Attributes
    ----------
    address : In(8)
        Node address on the chain (1..254).
    up, down : Out(line_signature(slots))
        Data-strobe line ports towards the master and towards the next node.
    enc_a, enc_b : In(1)
        Encoder lines.
    torque : Out(signed(24))
        Torque command, FORCE word (N·m · 2^13).
    brake : Out(1)
        Engage the joint's holding brake (the safe stop, docs/node.md "Safe stop").
    status : Out(16)
        :class:`~mrm_cosim.protocol.regs.Status` bits.
    count : Out(signed(32))
        Live encoder count.
    events : Out(16)
        The core's observation port (:class:`~mrm_cosim.protocol.regs.NodeEvent` strobes).
    """

    def __init__(self, *, codec: dict | None = None, encoder: EncoderParams | None = None,
                 pid_shift: int = 0):
        with rejecting(self):
            self._link = LinkNode(codec=codec)
        self._core = NodeCore(encoder=encoder, pid_shift=pid_shift)
        slots = self._link.up_codec.slots
        super().__init__({
            "address": In(8),
            "up":      Out(line_signature(slots)),
            "down":    Out(line_signature(slots)),
            "enc_a":   In(1),
            "enc_b":   In(1),
            "torque":  Out(signed(WORD)),
            "brake":   Out(1),
            "status":  Out(16),
            "count":   Out(signed(32)),
            "events":  Out(16),
        })

    @property
    def link(self) -> LinkNode:
        return self._link

    @property
    def core(self) -> NodeCore:
        return self._core

    def elaborate(self, platform):
        m = Module()
        m.submodules.link = link = self._link
        m.submodules.core = core = self._core
        wiring.connect(m, link_rx=link.rx, core_rx=core.rx)
        wiring.connect(m, core_tx=core.tx, link_tx=link.tx)
        for port in ("up", "down"):
            ours, theirs = getattr(self, port), getattr(link, port)
            m.d.comb += [
                theirs.d_in.eq(ours.d_in),
                theirs.s_in.eq(ours.s_in),
                ours.d_out.eq(theirs.d_out),
                ours.s_out.eq(theirs.s_out),
            ]
        m.d.comb += [
            link.address.eq(self.address),
            core.period_start.eq(link.tc_strobe),
            core.period.eq(link.tc_time),
            core.enc_a.eq(self.enc_a),
            core.enc_b.eq(self.enc_b),
            self.torque.eq(core.torque),
            self.brake.eq(core.brake),
            self.status.eq(core.status),
            self.count.eq(core.count),
            core.up_errors.eq(link.up_errors),
            core.down_errors.eq(link.down_errors),
            core.rx_stats.eq(link.rx_stats),
            core.dropped.eq(link.dropped),
        ]
        m.d.comb += self.events.eq(core.events)
        return m


def slave_node_top(*, slots: int = DEFAULT_SLOTS, start_div: int | None = None,
                   run_div: int = DEFAULT_RUN_DIV,
                   reset_cycles: int = 320, wait_cycles: int = 640, disconnect_cycles: int = 43,
                   rx_fifo_depth: int = 64, counts_per_rev: int = 800_000,
                   filter_cycles: int = 2, min_window: int = 2048,
                   stop_cycles: int = 1 << 24, pid_shift: int = 0) -> SlaveNode:
    """Factory for the ``node`` top: link parameters as ``link_node``, encoder parameters as
    :class:`~mrm_cosim.protocol.encoder.EncoderParams` (50 MHz clock), the PID gain shift
    (:func:`~mrm_cosim.protocol.joint_program.pid_formats`)."""
    return SlaveNode(codec=dict(slots=slots, start_div=start_div, run_div=run_div,
                                reset_cycles=reset_cycles, wait_cycles=wait_cycles,
                                disconnect_cycles=disconnect_cycles,
                                rx_fifo_depth=rx_fifo_depth),
                     encoder=EncoderParams(counts_per_rev=counts_per_rev,
                                           filter_cycles=filter_cycles, min_window=min_window,
                                           stop_cycles=stop_cycles),
                     pid_shift=pid_shift)


def node_core_top(*, counts_per_rev: int = 800_000, filter_cycles: int = 2,
                  min_window: int = 2048, stop_cycles: int = 1 << 24,
                  pid_shift: int = 0) -> NodeCore:
    """Factory for the ``node_core`` top (the compute core without the link)."""
    return NodeCore(encoder=EncoderParams(counts_per_rev=counts_per_rev,
                                          filter_cycles=filter_cycles, min_window=min_window,
                                          stop_cycles=stop_cycles),
                    pid_shift=pid_shift)
