"""The whole robot's gateware: the master's link port and N slave nodes in a daisy chain.

::

    master software ⇄ MasterPort ═══ node 1 ═══ node 2 ═══ … ═══ node N
                                      │ enc, τ    │ enc, τ         │ enc, τ
                                      ▼           ▼                ▼
                                        joints of the plant (outside the gateware)

This is the design the co-simulation runs (``cosim``) and the ``system`` top of
``mrm hdl verilog``. Node k has address k (1-based). The last node's downstream port is left
idle (its codec stays in Error-Wait/Ready: nothing is connected there).
"""

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.encoder import encoders_per_node
from mrm_cosim.protocol.joint_program import pid_shifts_per_node
from mrm_cosim.protocol.fixed import WORD
from mrm_cosim.protocol.link import ERROR_CLASSES

from .link.chain import faulty_line, line_fault_layout
from .link.chars import Char, ErrorCounts, LinkState, saturating_sum
from .master_port import MasterPort
from .node.top import SlaveNode

__all__ = ["System", "check_n_nodes", "MAX_NODES"]

#: slave nodes one System (and so one co-simulated robot) holds
MAX_NODES = 16


def check_n_nodes(n_nodes) -> None:
    """``ValueError`` unless ``n_nodes`` is an integer from 1 to :data:`MAX_NODES`."""
    if (isinstance(n_nodes, bool) or not isinstance(n_nodes, int)
            or not 1 <= n_nodes <= MAX_NODES):
        raise ValueError(f"n_nodes must be an integer from 1 to {MAX_NODES}, not {n_nodes!r}")


class System(wiring.Component):
    """Master link port plus ``n_nodes`` slave nodes.

    Parameters
    ----------
    n_nodes : int
        Number of modules (1..16).
    codec : dict
        :class:`~hdl.link.codec.Codec` parameters of every link port.
    encoder : EncoderParams or sequence of EncoderParams, optional
        Encoder interface parameters: one set for every node, or one per node (node 1 first;
        a robot's modules can have different encoders, and the node's velocity constant and
        angle scale are built for its counts per revolution).
    pid_shift : int or sequence of int
        PID gain shift of every node, or one per node
        (:func:`~mrm_cosim.protocol.joint_program.pid_formats`).

    Attributes
    ----------
    tx_valid, tx_char, tx_level, tx_overflow, rx_valid, rx_char, tick_in, time_in,
    running, state, errors :
        The master port's (see :class:`~hdl.master_port.MasterPort`).
    link_errors : Out(16)
        The master port's ``errors``, the five classes summed (saturating): one narrow word a
        harness can sample every cycle (the nodes report theirs in Comm A).
    enc_a, enc_b : In(n_nodes)
        Encoder lines, bit k for node k+1.
    torque1 … torqueN : Out(signed(24))
        Torque commands (FORCE words, N·m · 2^13).
    brake1 … brakeN : Out(1)
        The nodes' brake outputs (the safe stop, docs/node.md "Safe stop").
    status1 … statusN : Out(16)
        The nodes' :class:`~mrm_cosim.protocol.regs.Status` bits.
    count1 … countN : Out(signed(32))
        Live encoder counts of the nodes.
    fault_down1 … fault_downN, fault_up1 … fault_upN : In(line_fault_layout(slots))
        Only with ``line_faults``: fault injection on the line above node k (from the master
        port or node k − 1), towards node k (``down``) or from it (``up``), as
        :class:`~hdl.link.chain.Chain`'s; all zero: good wires. A co-simulation testbench
        capability (``cosim``), not part of the robot's gateware.
    events1 … eventsN : Out(16)
        The nodes' observation ports (:class:`~mrm_cosim.protocol.regs.NodeEvent` strobes).
    """

    def __init__(self, n_nodes: int, *, codec: dict | None = None, encoder=None,
                 pid_shift=0, line_faults: bool = False):
        check_n_nodes(n_nodes)
        self.n_nodes = n_nodes
        self.line_faults = bool(line_faults)
        self.master = MasterPort(codec=codec)
        self.nodes = [SlaveNode(codec=codec, encoder=e, pid_shift=s)
                      for e, s in zip(encoders_per_node(encoder, n_nodes),
                                      pid_shifts_per_node(pid_shift, n_nodes), strict=True)]
        members = {
            "tx_valid":    In(1),
            "tx_char":     In(Char),
            "tx_level":    Out(range(self.master.tx_depth + 1)),
            "tx_overflow": Out(16),
            "rx_valid":    Out(1),
            "rx_char":     Out(Char),
            "tick_in":     In(1),
            "time_in":     In(8),
            "running":     Out(1),
            "state":       Out(LinkState),
            "errors":      Out(ErrorCounts),
            "link_errors": Out(16),
            "enc_a":       In(n_nodes),
            "enc_b":       In(n_nodes),
        }
        for k in range(1, n_nodes + 1):
            members[f"torque{k}"] = Out(signed(WORD))
            members[f"brake{k}"] = Out(1)
            members[f"status{k}"] = Out(16)
            members[f"count{k}"] = Out(signed(32))
            if self.line_faults:
                layout = line_fault_layout(self.master.codec.slots)
                members[f"fault_down{k}"] = In(layout)
                members[f"fault_up{k}"] = In(layout)
            members[f"events{k}"] = Out(16)
        super().__init__(members)

    def elaborate(self, platform):
        m = Module()
        m.submodules.master = master = self.master
        for name in ("tx_valid", "tx_char", "tick_in", "time_in"):
            m.d.comb += getattr(master, name).eq(getattr(self, name))
        for name in ("tx_level", "tx_overflow", "rx_valid", "rx_char", "running", "state",
                     "errors"):
            m.d.comb += getattr(self, name).eq(getattr(master, name))
        m.d.comb += self.link_errors.eq(saturating_sum(master.errors[f] for f in ERROR_CLASSES))
        upstream = master.line
        for k, node in enumerate(self.nodes):
            m.submodules[f"node{k + 1}"] = node
            m.d.comb += [
                node.address.eq(k + 1),
                node.enc_a.eq(self.enc_a[k]),
                node.enc_b.eq(self.enc_b[k]),
                getattr(self, f"torque{k + 1}").eq(node.torque),
                getattr(self, f"brake{k + 1}").eq(node.brake),
                getattr(self, f"status{k + 1}").eq(node.status),
                getattr(self, f"count{k + 1}").eq(node.count),
            ]
            # upstream port's outputs drive the node's inputs and vice versa
            down_d, down_s = upstream.d_out, upstream.s_out
            up_d, up_s = node.up.d_out, node.up.s_out
            if self.line_faults:
                down, up = getattr(self, f"fault_down{k + 1}"), getattr(self, f"fault_up{k + 1}")
                down_d, down_s = faulty_line(down_d, down, "d"), faulty_line(down_s, down, "s")
                up_d, up_s = faulty_line(up_d, up, "d"), faulty_line(up_s, up, "s")
            m.d.comb += [
                node.up.d_in.eq(down_d),
                node.up.s_in.eq(down_s),
                upstream.d_in.eq(up_d),
                upstream.s_in.eq(up_s),
            ]
            m.d.comb += getattr(self, f"events{k + 1}").eq(node.events)
            upstream = node.down
        return m
