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

__all__ = ["System", "check_n_nodes", "MAX_NODES", "CLOCKS"]

#: slave nodes one System (and so one co-simulated robot) holds
MAX_NODES = 16
#: the System's clocking: one clock, or one per node (docs/clocks.md)
CLOCKS = ("common", "node")


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
    clocks : str
        ``"common"`` (the default): every node on the master port's clock ``sync``, the lines
        wired through. ``"node"``: node ``k`` in a clock domain of its own, ``n<k>``
        (ports ``n<k>_clk``, ``n<k>_rst``; the master port in ``sync``), and the lines of
        hop ``k`` brought out instead of wired, for a harness to resample between the
        domains (docs/clocks.md):
    down_d_out<k>, down_s_out<k>, up_d_in<k>, up_s_in<k> : Out(slots), In(slots)
        ``"node"`` only: the upstream end of hop ``k`` (the master port, or node ``k − 1``'s
        downstream port), in the upstream's domain.
    up_d_out<k>, up_s_out<k>, down_d_in<k>, down_s_in<k> : Out(slots), In(slots)
        ``"node"`` only: node ``k``'s end of hop ``k``, in its domain. With ``line_faults``
        the fault ports act on the receiving end (``fault_down<k>`` on ``down_*_in<k>`` in
        node ``k``'s domain, ``fault_up<k>`` on ``up_*_in<k>`` in the upstream's).
    """

    def __init__(self, n_nodes: int, *, codec: dict | None = None, encoder=None,
                 pid_shift=0, line_faults: bool = False, clocks: str = "common"):
        check_n_nodes(n_nodes)
        if clocks not in CLOCKS:
            raise ValueError(f"clocks must be one of {', '.join(map(repr, CLOCKS))}, "
                             f"not {clocks!r}")
        self.n_nodes = n_nodes
        self.clocks = clocks
        #: ``"node"``: node k's clock domain (its ``clk`` a port of the Verilog:
        #: :meth:`verilog_ports`; its reset undriven, held low)
        self.node_domains = ([ClockDomain(f"n{k}") for k in range(1, n_nodes + 1)]
                             if clocks == "node" else [])
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
        if clocks == "node":
            slots = self.master.codec.slots
            for k in range(1, n_nodes + 1):
                for w in ("d", "s"):
                    members[f"down_{w}_out{k}"] = Out(slots)
                    members[f"up_{w}_in{k}"] = In(slots)
                    members[f"up_{w}_out{k}"] = Out(slots)
                    members[f"down_{w}_in{k}"] = In(slots)
        super().__init__(members)

    def elaborate(self, platform):
        if self.clocks == "node":
            return self._elaborate_node_clocks()
        m = Module()
        m.submodules.master = master = self.master
        self._master_ports(m, master)
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

    def verilog_ports(self) -> dict:
        """The ports ``verilog.convert(..., ports=)`` takes: the signature's and, with
        ``clocks="node"``, every node domain's clock ``n<k>_clk`` (an input)."""
        from amaranth.hdl._ir import PortDirection

        ports = {}
        for path, member, value in self.signature.flatten(self):
            value = value.as_value() if hasattr(value, "as_value") else value
            direction = PortDirection.Input if member.flow == In else PortDirection.Output
            ports["__".join(map(str, path))] = (value, direction)
        for cd in self.node_domains:
            ports[f"{cd.name}_clk"] = (cd.clk, PortDirection.Input)
        return ports

    def _master_ports(self, m, master) -> None:
        for name in ("tx_valid", "tx_char", "tick_in", "time_in"):
            m.d.comb += getattr(master, name).eq(getattr(self, name))
        for name in ("tx_level", "tx_overflow", "rx_valid", "rx_char", "running", "state",
                     "errors"):
            m.d.comb += getattr(self, name).eq(getattr(master, name))
        m.d.comb += self.link_errors.eq(saturating_sum(master.errors[f] for f in ERROR_CLASSES))

    def _elaborate_node_clocks(self):
        """Node ``k`` in domain ``n<k>``, the hops' lines on ports (class docstring)."""
        m = Module()
        m.submodules.master = master = self.master
        self._master_ports(m, master)
        upstream = master.line
        for k, node in enumerate(self.nodes, start=1):
            domain = f"n{k}"
            m.domains += self.node_domains[k - 1]
            m.submodules[f"node{k}"] = DomainRenamer(domain)(node)
            m.d.comb += [
                node.address.eq(k),
                node.enc_a.eq(self.enc_a[k - 1]),
                node.enc_b.eq(self.enc_b[k - 1]),
                getattr(self, f"torque{k}").eq(node.torque),
                getattr(self, f"brake{k}").eq(node.brake),
                getattr(self, f"status{k}").eq(node.status),
                getattr(self, f"count{k}").eq(node.count),
                getattr(self, f"events{k}").eq(node.events),
            ]
            down_d, down_s = getattr(self, f"down_d_in{k}"), getattr(self, f"down_s_in{k}")
            up_d, up_s = getattr(self, f"up_d_in{k}"), getattr(self, f"up_s_in{k}")
            if self.line_faults:
                down, up = getattr(self, f"fault_down{k}"), getattr(self, f"fault_up{k}")
                down_d, down_s = faulty_line(down_d, down, "d"), faulty_line(down_s, down, "s")
                up_d, up_s = faulty_line(up_d, up, "d"), faulty_line(up_s, up, "s")
            m.d.comb += [
                getattr(self, f"down_d_out{k}").eq(upstream.d_out),
                getattr(self, f"down_s_out{k}").eq(upstream.s_out),
                getattr(self, f"up_d_out{k}").eq(node.up.d_out),
                getattr(self, f"up_s_out{k}").eq(node.up.s_out),
                node.up.d_in.eq(down_d),
                node.up.s_in.eq(down_s),
                upstream.d_in.eq(up_d),
                upstream.s_in.eq(up_s),
            ]
            upstream = node.down
        return m
