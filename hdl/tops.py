"""Registry of the gateware tops that can be exported as Verilog: name -> factory.

Each entry builds a :class:`~amaranth.lib.wiring.Component` whose signature gives the ports of
the generated module. ``mrm hdl verilog --top NAME`` uses it; other layers add their tops here
(the packet layer adds ``link_node``).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field

from amaranth.back import verilog
from amaranth.lib import wiring

from mrm_cosim.protocol.joint_program import PID_SHIFT_MAX
from mrm_cosim.protocol.link import CREDIT_AUDIT, CREDIT_TIMEOUT, DEFAULT_RUN_DIV, DEFAULT_SLOTS
from mrm_cosim.errors import InputError

from .link.node import link_node_top
from .node.top import node_core_top, slave_node_top

__all__ = ["Top", "TOPS", "build_top", "component_verilog", "param_error", "verilog_text"]


@dataclass(frozen=True)
class Top:
    """A buildable top: ``factory(**params)`` returns the component; ``help`` says what it is."""

    factory: Callable[..., wiring.Component]
    help: str
    bounds: dict = field(default_factory=dict)
    """``{parameter: (lo, hi)}``: the values that elaborate in seconds, checked before the
    build (parameters not named here: :data:`PARAM_BOUNDS`)."""

    def parameters(self) -> dict[str, object]:
        """The factory's keyword parameters and their defaults."""
        return {name: p.default for name, p in inspect.signature(self.factory).parameters.items()
                if p.kind is p.KEYWORD_ONLY}


def _spw_codec(*, slots: int = DEFAULT_SLOTS, start_div: int | None = None,
               run_div: int = DEFAULT_RUN_DIV, max_run_div: int | None = None,
               reset_cycles: int = 320, wait_cycles: int = 640, disconnect_cycles: int = 43,
               rx_fifo_depth: int = 64, credit_timeout: int = CREDIT_TIMEOUT,
               credit_audit: int = CREDIT_AUDIT) -> wiring.Component:
    # credit_audit expects a peer that grants what this codec grants at rest (a peer like it):
    # 0 for a foreign peer (docs/link.md "Lost FCTs").
    from .link.codec import Codec
    return Codec(slots=slots, start_div=start_div, run_div=run_div, max_run_div=max_run_div,
                 reset_cycles=reset_cycles,
                 wait_cycles=wait_cycles, disconnect_cycles=disconnect_cycles,
                 rx_fifo_depth=rx_fifo_depth, credit_timeout=credit_timeout,
                 credit_audit=credit_audit)


def _dmp_generator(*, max_basis: int = 32) -> wiring.Component:
    from .node.dmp import DmpGenerator
    return DmpGenerator(max_basis=max_basis)


def _system(*, n_nodes: int = 3) -> wiring.Component:
    from .system import System, check_n_nodes
    check_n_nodes(n_nodes)  # before construction: a half-built component would be "unused"
    return System(n_nodes)


#: Bounds of an integer parameter no top bounds more tightly: a 32-bit signed word (a counter
#: or divider wider than that is no design; Python's big integers overflowed inside
#: elaboration).
PARAM_BOUNDS = (-(1 << 31), (1 << 31) - 1)

TOPS: dict[str, Top] = {
    "spw_codec": Top(_spw_codec, "standalone SpaceWire codec (wire ports d_in, s_in, d_out, "
                                 "s_out; N-char streams, time-codes, link control/status)",
                      # the receive FIFO is a memory initialised entry by entry: a million
                      # entries took minutes to elaborate; 4,096 take under a second
                      bounds={"rx_fifo_depth": (1, 4096), "slots": (1, 64)}),
    "link_node": Top(link_node_top, "daisy-chain endpoint: up/down codecs, router, packet layer "
                                    "(host beat streams), time-code capture"),
    "node": Top(slave_node_top, "slave node: link endpoint + compute core (VDC, joint control, "
                                "encoder, watchdog); encoder lines in, torque word out",
                  bounds={"pid_shift": (0, PID_SHIFT_MAX)}),
    "node_core": Top(node_core_top, "node compute core alone (packet beat streams, encoder "
                                    "lines, torque word)",
                      bounds={"pid_shift": (0, PID_SHIFT_MAX)}),
    "dmp_generator": Top(_dmp_generator, "joint-side DMP generator alone (host parameter "
                                         "writes, start/stop/step strobes, q_d0/q̇_d0/q̈_d0 "
                                         "references)",
                         bounds={"max_basis": (1, 256)}),
    "system": Top(_system, "the whole robot's gateware: master link port and n_nodes slave "
                           "nodes in a daisy chain (what the co-simulation runs)"),
}


def build_top(name: str, **params) -> wiring.Component:
    """Build the top ``name`` with ``params``; ``KeyError`` for an unknown name or parameter,
    :class:`InputError` (field the parameter's name) for a value outside its bounds."""
    top = TOPS[name]
    unknown = set(params) - set(top.parameters())
    if unknown:
        raise KeyError(f"top {name!r} has no parameter {sorted(unknown)[0]!r}")
    for key, value in params.items():
        if value is None:
            continue
        lo, hi = top.bounds.get(key, PARAM_BOUNDS)
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise InputError(key, f"must be an integer from {lo:,} to {hi:,}, not {value!r} "
                             "(the range that elaborates in seconds)")
    return top.factory(**params)


def param_error(exc: ValueError, top: str):
    """The :class:`~mrm_cosim.errors.InputError` for a top that refused its parameters: named
    ``--param NAME`` when the error names one of ``top``'s parameters, else ``--param``."""
    from mrm_cosim.errors import InputError

    if isinstance(exc, InputError) and exc.field in TOPS[top].parameters():
        return InputError(f"params.{exc.field}", exc.message)
    return InputError("params", str(exc))


def component_verilog(component: wiring.Component, name: str) -> str:
    """Verilog of ``component`` as module ``name``; ports from its signature, no src attributes."""
    return verilog.convert(component, name=name, emit_src=False)


def verilog_text(name: str, **params) -> str:
    """Verilog of the top ``name`` built with ``params``, as a module of the same name."""
    return component_verilog(build_top(name, **params), name)
