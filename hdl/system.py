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
from .link.node import line_signature
from .master_port import MasterPort
from .node.top import SlaveNode

__all__ = ["System", "Segment", "check_n_nodes", "MAX_NODES", "CLOCKS"]

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
        members = _master_members(self.master)
        members |= _node_members(range(1, n_nodes + 1), self.line_faults and
                                 line_fault_layout(self.master.codec.slots))
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
        _master_ports(m, self, master)
        _wire_chain(m, self, master.line, self.nodes, 1, self.line_faults)
        return m

    def verilog_ports(self) -> dict:
        """The ports ``verilog.convert(..., ports=)`` takes: the signature's and, with
        ``clocks="node"``, every node domain's clock ``n<k>_clk``, each named by its path.
        Directions are left to Amaranth (``None``: an output where the design drives it, else
        an input), so no name from its private ``hdl._ir`` is needed; every ``Out`` member of
        this design is driven, so each port keeps its signature's direction — the Verilog is
        the same, byte for byte, as with the directions given (tests/test_clocks_system.py
        checks every port's)."""
        ports = {}
        for path, _member, value in self.signature.flatten(self):
            value = value.as_value() if hasattr(value, "as_value") else value
            ports["__".join(map(str, path))] = (value, None)
        for cd in self.node_domains:
            ports[f"{cd.name}_clk"] = (cd.clk, None)
        return ports

    def _elaborate_node_clocks(self):
        """Node ``k`` in domain ``n<k>``, the hops' lines on ports (class docstring)."""
        m = Module()
        m.submodules.master = master = self.master
        _master_ports(m, self, master)
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


def _master_members(master) -> dict:
    """:class:`System`'s ports of the master's link port (``link_errors`` its errors summed)."""
    return {
        "tx_valid":    In(1),
        "tx_char":     In(Char),
        "tx_level":    Out(range(master.tx_depth + 1)),
        "tx_overflow": Out(16),
        "rx_valid":    Out(1),
        "rx_char":     Out(Char),
        "tick_in":     In(1),
        "time_in":     In(8),
        "running":     Out(1),
        "state":       Out(LinkState),
        "errors":      Out(ErrorCounts),
        "link_errors": Out(16),
    }


#: A node's ports named by its address in the system (``torque2``), not in a local part.
_LOCAL_NODE_PORTS = ("torque", "brake", "status", "count", "events", "fault_down", "fault_up")


def _port(base: str, k: int, local: bool) -> str:
    """The name of node ``k``'s port ``base``: ``<base><k>``, or ``base`` in a part of one node
    named apart from its place in the chain (``Segment(..., local=True)``)."""
    return base if local else f"{base}{k}"


def _node_members(addresses, fault_layout, fault_ups=None, local: bool = False) -> dict:
    """The ports of nodes ``addresses``: encoder lines (bit j for the j-th of them), then each
    node's outputs and, with ``fault_layout``, its line-fault inputs (``fault_up<k>`` only for
    ``k`` in ``fault_ups``, default all: the up-line fault acts where the upstream receives);
    with ``local`` (one node) the names without ``k`` and the node's ``address`` an input."""
    addresses = list(addresses)
    members = {"enc_a": In(len(addresses)), "enc_b": In(len(addresses))}
    if local:
        members["address"] = In(8)
    for k in addresses:
        members[_port("torque", k, local)] = Out(signed(WORD))
        members[_port("brake", k, local)] = Out(1)
        members[_port("status", k, local)] = Out(16)
        members[_port("count", k, local)] = Out(signed(32))
        if fault_layout:
            members[_port("fault_down", k, local)] = In(fault_layout)
            if fault_ups is None or k in fault_ups:
                members[_port("fault_up", k, local)] = In(fault_layout)
        members[_port("events", k, local)] = Out(16)
    return members


def _master_ports(m, owner, master) -> None:
    for name in ("tx_valid", "tx_char", "tick_in", "time_in"):
        m.d.comb += getattr(master, name).eq(getattr(owner, name))
    for name in ("tx_level", "tx_overflow", "rx_valid", "rx_char", "running", "state",
                 "errors"):
        m.d.comb += getattr(owner, name).eq(getattr(master, name))
    m.d.comb += owner.link_errors.eq(saturating_sum(master.errors[f] for f in ERROR_CLASSES))


def _wire_chain(m, owner, upstream, nodes, first: int, line_faults: bool,
                first_up_fault: bool = True, local: bool = False):
    """Nodes ``first``, ``first + 1``, … (``nodes``) daisy-chained below ``upstream`` (a line:
    ``d_out``, ``s_out``, ``d_in``, ``s_in``) in ``m``, their ports ``owner``'s; with
    ``line_faults`` each hop's lines through ``owner``'s fault inputs, the up line of the first
    hop only if ``first_up_fault``; with ``local`` (one node) its ports named apart from its
    place and its address ``owner.address``. Returns the last node's downstream line."""
    for j, node in enumerate(nodes):
        k = first + j
        m.submodules["node" if local else f"node{k}"] = node
        port = lambda base, k=k: getattr(owner, _port(base, k, local))   # noqa: E731
        m.d.comb += [
            node.address.eq(owner.address if local else k),
            node.enc_a.eq(owner.enc_a[j]),
            node.enc_b.eq(owner.enc_b[j]),
            port("torque").eq(node.torque),
            port("brake").eq(node.brake),
            port("status").eq(node.status),
            port("count").eq(node.count),
        ]
        # upstream port's outputs drive the node's inputs and vice versa
        down_d, down_s = upstream.d_out, upstream.s_out
        up_d, up_s = node.up.d_out, node.up.s_out
        if line_faults:
            down = port("fault_down")
            down_d, down_s = faulty_line(down_d, down, "d"), faulty_line(down_s, down, "s")
            if j or first_up_fault:
                up = port("fault_up")
                up_d, up_s = faulty_line(up_d, up, "d"), faulty_line(up_s, up, "s")
        m.d.comb += [
            node.up.d_in.eq(down_d),
            node.up.s_in.eq(down_s),
            upstream.d_in.eq(up_d),
            upstream.s_in.eq(up_s),
        ]
        m.d.comb += port("events").eq(node.events)
        upstream = node.down
    return upstream


class Segment(wiring.Component):
    """Nodes ``first … first + count − 1`` of ``System(n_nodes, …)`` (the same parameters),
    wired as :class:`System` wires them, as a design of their own: a part of the daisy chain
    that a simulator can step apart from the rest (:class:`cosim.compiled.SplitModel`: the
    parts on several threads, the same cycles bit for bit as the whole system's). One clock
    (``clocks="common"``).

    Ports: the system's of these nodes (``enc_a``/``enc_b`` bit j for the j-th of them) and,
    with ``first == 1``, the master's link port and its ports; else ``head``:
    ``In(line_signature(slots))``, the upstream port of hop ``first`` (node ``first − 1``'s
    downstream port) as node ``first`` sees it. Unless the segment ends the chain, ``tail``:
    ``Out(line_signature(slots))``, the last node's downstream port. A part's ``tail`` and the
    next part's ``head`` connect name to name (``tail.d_out`` → ``head.d_out``, ``head.d_in`` →
    ``tail.d_in``, the same for ``s``). Every line leaving a part is a transmitter's register
    (no path from a part's inputs to it within a cycle), which is what lets the parts exchange
    them once a cycle. With ``line_faults`` a fault acts where its line arrives:
    ``fault_down<k>`` in node ``k``'s part, ``fault_up<k>`` in the part of node ``k − 1`` (or
    the master's).

    With ``local`` (one node, ``count == 1``) the part is named apart from its place in the
    chain: the node's ports without ``k`` (``torque``, ``fault_down``, …; the fault input of
    the line arriving at the tail ``fault_up_next``) and its address an input, ``address``,
    which the simulator holds at ``first``. Nodes of the same parameters and the same place
    kind (master's, middle, last) then convert to the same Verilog, one build and one copy
    of the code for all of them; :meth:`system_name` maps a port back to the system's name.
    """

    def __init__(self, n_nodes: int, first: int, count: int, *, codec: dict | None = None,
                 encoder=None, pid_shift=0, line_faults: bool = False, local: bool = False):
        check_n_nodes(n_nodes)
        if not (1 <= first and count >= 1 and first + count - 1 <= n_nodes):
            raise ValueError(f"nodes {first}..{first + count - 1} are not among the system's "
                             f"1..{n_nodes}")
        if local and count != 1:
            raise ValueError(f"a part named apart from its place (local) holds one node, "
                             f"not {count}")
        self.n_nodes, self.first, self.size = n_nodes, first, count
        self.local = bool(local)
        self.has_master = first == 1
        self.has_tail = first + count - 1 < n_nodes
        self.line_faults = bool(line_faults)
        params = list(zip(encoders_per_node(encoder, n_nodes),
                          pid_shifts_per_node(pid_shift, n_nodes), strict=True))
        self.master = MasterPort(codec=codec) if self.has_master else None
        self.nodes = [SlaveNode(codec=codec, encoder=e, pid_shift=s)
                      for e, s in params[first - 1:first - 1 + count]]
        slots = self.nodes[0].up.d_out.shape().width
        last = first + count - 1
        members = (_master_members(self.master) if self.has_master
                   else {"head": In(line_signature(slots))})
        ups = set(range(first + 1, last + 1)) | ({first} if self.has_master else set())
        members |= _node_members(range(first, last + 1), self.line_faults and
                                 line_fault_layout(slots), ups, self.local)
        if self.has_tail:
            members["tail"] = Out(line_signature(slots))
            if self.line_faults:
                members[self._tail_fault] = In(line_fault_layout(slots))
        super().__init__(members)

    @property
    def _tail_fault(self) -> str:
        return "fault_up_next" if self.local else f"fault_up{self.first + self.size}"

    @staticmethod
    def system_name(name: str, first: int) -> str:
        """The system's name of port ``name`` of a ``local`` part of node ``first``
        (``torque`` → ``torque<first>``, ``fault_up_next`` → ``fault_up<first + 1>``; the
        master's ports keep theirs)."""
        if name == "fault_up_next":
            return f"fault_up{first + 1}"
        if name in _LOCAL_NODE_PORTS:
            return f"{name}{first}"
        return name

    def elaborate(self, platform):
        m = Module()
        if self.has_master:
            m.submodules.master = master = self.master
            _master_ports(m, self, master)
            upstream = master.line
        else:
            upstream = self.head
        last = _wire_chain(m, self, upstream, self.nodes, self.first, self.line_faults,
                           first_up_fault=self.has_master, local=self.local)
        if self.has_tail:
            d_in, s_in = self.tail.d_in, self.tail.s_in
            if self.line_faults:
                up = getattr(self, self._tail_fault)
                d_in, s_in = faulty_line(d_in, up, "d"), faulty_line(s_in, up, "s")
            m.d.comb += [self.tail.d_out.eq(last.d_out), self.tail.s_out.eq(last.s_out),
                         last.d_in.eq(d_in), last.s_in.eq(s_in)]
        return m
