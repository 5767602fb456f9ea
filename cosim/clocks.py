"""A clock per node (issue 21 item 1): the ``[clocks]`` configuration, its integer time base
and the line resampler between clock domains (docs/clocks.md).

Every slave node and the master's link port run from a clock of their own: a frequency offset
in ppm and a phase, per node and for the master port. ``mode``:

* ``"common"`` (the default): one clock for everything, today's design and traces bit for bit;
* ``"list"``: the offsets and phases given (``ppm``, ``phase``, ``master_ppm``,
  ``master_phase``);
* ``"drawn"``: every offset drawn uniformly from ``±range_ppm`` and every phase from ``[0, 1)``
  cycle with a numpy Generator of its own, seeded by the run's seed and a fixed tag (no other
  random stream is touched, so the plant is the same as with a common clock).

``discipline = true`` has the master upload CONFIG TC_DISCIPLINE to every node
(:mod:`protocol.discipline`, target 12 cycles a hop: the link's time-code latency).

Time base. Times are integers in femtoseconds (Amaranth's simulator's own unit). Clock ``d``
(0: the master port, ``k``: node ``k``) has the period ``P_d = 20,000,000 − 4·round(5·ppm)``
fs (the offset rounded to 0.2 ppm; a positive ppm is a faster clock) and the phase
``φ_d = 4·round(5,000,000·phase)`` fs (phase in nominal cycles, ``0 ≤ phase < 1``): its cycle
``c`` lasts from ``φ_d + c·P_d`` to its rising edge at ``φ_d + (c+1)·P_d``. Every edge and
phase is a multiple of 4 fs, so the pysim harness acts at odd times, between edges.

Resampling. A codec's line port is a word of ``slots`` samples per cycle of its own clock,
bit 0 first. The receiver samples the sender's level at the start of each of its own slots,
``t_j = t0 + ⌊j·P/slots⌋`` in its cycle ``[t0, t0 + P)``; the sender's level at ``t`` is bit
``⌊(t − s)·slots / P_s⌋`` of its word in the cycle ``[s, s + P_s)`` holding ``t`` (its cycle 0's
word, the reset state, before its first cycle). A sender's word is a function of its registers
(the codec's transmitter), so it is known from the sender's edge that starts the cycle.

The global grid. The loop (master, plant, records) counts cycles of the master port's clock.
A node's cycle ``c`` ending at ``t1`` belongs to the master cycle ``g`` with
``T0(g) < t1 ≤ T1(g)``; it takes that master cycle's encoder and fault inputs, its level
outputs (torque, brake, status, count) become the master cycle's (the last node cycle of it
wins) and its event strobes are OR-ed into it. A node faster than the master fits two cycles
into one master cycle now and then (every ~10⁴ cycles at 100 ppm): a strobe of the same event
in both would merge into one; such merges are counted (:attr:`ClockedEngine.merged`), never
hidden. Edges at one instant are taken nodes first, master last (domains share no signal:
their order changes nothing else).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mrm_cosim.errors import InputError
from mrm_cosim.protocol.link import slot_at

__all__ = ["ClockConfig", "ClockPlan", "MODES", "NOMINAL_FS", "MAX_PPM", "DEFAULT_RANGE_PPM",
           "system_lines", "node_domain", "plan_clocks", "ClockedEngine", "NodeTime"]

MODES = ("common", "list", "drawn")
#: one nominal cycle (20 ns) in femtoseconds
NOMINAL_FS = 20_000_000
#: the largest offset a clock may have, ppm (the receiver holds ±1 %: docs/link.md)
MAX_PPM = 10_000.0
DEFAULT_RANGE_PPM = 100.0
#: seeds the drawn clocks' own Generator together with the run's seed
_DRAW_TAG = 0x636C6F636B73          # "clocks"


def node_domain(k: int) -> str:
    """The clock domain of node ``k`` (1-based) in a per-node-clock :class:`hdl.system.System`."""
    return f"n{k}"


@dataclass(frozen=True)
class ClockConfig:
    """The ``[clocks]`` section (module docstring).

    Attributes
    ----------
    mode : str
        ``"common"``, ``"list"`` or ``"drawn"``.
    ppm, phase : tuple of float
        ``"list"``: per node (node 1 first) the offset (ppm, positive: faster) and the phase
        (nominal cycles, ``[0, 1)``).
    master_ppm, master_phase : float
        ``"list"``: the master port's.
    range_ppm : float
        ``"drawn"``: the offsets' half-width (ppm).
    discipline : bool
        Upload CONFIG TC_DISCIPLINE to every node (``kp``, ``ki``: its gain shifts).
    """

    mode: str = "common"
    ppm: tuple = ()
    phase: tuple = ()
    master_ppm: float = 0.0
    master_phase: float = 0.0
    range_ppm: float = DEFAULT_RANGE_PPM
    discipline: bool = False
    kp: int = 1
    ki: int = 4

    @property
    def common(self) -> bool:
        return self.mode == "common"

    def check(self, n_nodes: int | None = None, prefix: str = "clocks") -> None:
        """``InputError`` naming the field (``clocks.ppm[2]``) unless the section is valid for a
        robot of ``n_nodes`` modules (``None``: the lists' lengths are not checked)."""
        if self.mode not in MODES:
            raise InputError(f"{prefix}.mode", f"must be one of {', '.join(map(repr, MODES))}, "
                             f"not {self.mode!r}")
        for name in ("discipline",):
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"{prefix}.{name}", f"must be true or false, not "
                                 f"{getattr(self, name)!r}")
        for name in ("kp", "ki"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 7:
                raise InputError(f"{prefix}.{name}", f"must be an integer from 0 to 7, not {v!r}")
        _ppm(self.range_ppm, f"{prefix}.range_ppm")
        if self.range_ppm < 0:
            raise InputError(f"{prefix}.range_ppm", f"must be at least 0, not {self.range_ppm!r}")
        _ppm(self.master_ppm, f"{prefix}.master_ppm")
        _phase(self.master_phase, f"{prefix}.master_phase")
        for name, check in (("ppm", _ppm), ("phase", _phase)):
            values = getattr(self, name)
            if not isinstance(values, list | tuple):
                raise InputError(f"{prefix}.{name}", f"must be a list (one per node), not "
                                 f"{values!r}")
            for i, v in enumerate(values):
                check(v, f"{prefix}.{name}[{i}]")
        if self.mode != "list":
            for name in ("ppm", "phase"):
                if getattr(self, name):
                    raise InputError(f"{prefix}.{name}", f"is for mode 'list', not "
                                     f"{self.mode!r}")
            for name in ("master_ppm", "master_phase"):
                if getattr(self, name):
                    raise InputError(f"{prefix}.{name}", f"is for mode 'list', not "
                                     f"{self.mode!r}")
        elif n_nodes is not None:
            for name in ("ppm", "phase"):
                if len(getattr(self, name)) != n_nodes:
                    raise InputError(f"{prefix}.{name}", f"needs one value per node "
                                     f"({n_nodes}), not {len(getattr(self, name))}")

    def resolve(self, n_nodes: int, seed: int) -> tuple[tuple, tuple]:
        """``(ppm, phase)`` of every clock, master port first (length ``n_nodes + 1``); the
        drawn ones from the seed; common: all zero."""
        self.check(n_nodes)
        if self.mode == "common":
            return (0.0,) * (n_nodes + 1), (0.0,) * (n_nodes + 1)
        if self.mode == "list":
            return ((float(self.master_ppm), *map(float, self.ppm)),
                    (float(self.master_phase), *map(float, self.phase)))
        rng = np.random.default_rng([int(seed), _DRAW_TAG])
        r = float(self.range_ppm)
        ppm = rng.uniform(-r, r, n_nodes + 1)
        phase = rng.uniform(0.0, 1.0, n_nodes + 1)
        # on the time base's grid (0.2 ppm, 1/1,250,000 cycle) so the values written back
        # are the ones that ran
        return (tuple(round(5 * float(p)) / 5 for p in ppm),
                tuple(round(5_000_000 * float(f)) / 5_000_000 for f in phase))


def _ppm(v, field: str) -> None:
    if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v) \
            or abs(v) > MAX_PPM:
        raise InputError(field, f"must be a number of ppm within ±{MAX_PPM:g}, not {v!r}")


def _phase(v, field: str) -> None:
    if isinstance(v, bool) or not isinstance(v, int | float) or not 0 <= v < 1:
        raise InputError(field, f"must be a number in [0, 1) (a fraction of a cycle), "
                         f"not {v!r}")


@dataclass(frozen=True)
class ClockPlan:
    """Every clock's period and phase, femtoseconds, master port first (module docstring)."""

    periods: tuple
    phases: tuple
    slots: int

    @classmethod
    def from_ppm(cls, ppm, phase, slots: int) -> ClockPlan:
        periods = tuple(NOMINAL_FS - 4 * round(5 * float(p)) for p in ppm)
        phases = tuple(min(4 * round(NOMINAL_FS // 4 * float(f)), per - 4)
                       for f, per in zip(phase, periods, strict=True))
        return cls(periods, phases, int(slots))

    @property
    def n_domains(self) -> int:
        return len(self.periods)


class NodeTime:
    """Node ``k``'s cycles against the master port's, on the global grid (module docstring):
    the model backend's clock of a node (:class:`cosim.model.ModelBackend` with a
    :class:`ClockPlan`), the same arithmetic as :class:`ClockedEngine`'s event order.

    Node cycle ``c`` ends at ``t1 = φ_k + (c + 1)·P_k`` and belongs to the master cycle ``g``
    with ``T0(g) < t1 ≤ T1(g)`` (:meth:`master_cycle`; the edges before the master's first
    belong to its cycle 0, as the harnesses take every edge up to the end of the current master
    cycle); master cycle ``g``'s inputs reach node cycles from :meth:`node_cycle` ``(g)`` on,
    the first whose end lies after ``T0(g)``."""

    __slots__ = ("p0", "f0", "pk", "fk")

    def __init__(self, plan: ClockPlan, k: int):
        self.p0, self.f0 = plan.periods[0], plan.phases[0]
        self.pk, self.fk = plan.periods[k], plan.phases[k]

    def master_cycle(self, c: int) -> int:
        """The master cycle node cycle ``c`` belongs to (its outputs are that cycle's)."""
        g = -((self.f0 - self.fk - (c + 1) * self.pk) // self.p0) - 1     # ⌈(t1 − φ0)/P0⌉ − 1
        return g if g > 0 else 0

    def node_cycle(self, g: int) -> int:
        """The first node cycle belonging to master cycle ``g`` or a later one."""
        if g <= 0:
            return 0
        return (self.f0 + g * self.p0 - self.fk) // self.pk


def plan_clocks(config: ClockConfig, n_nodes: int, seed: int, slots: int) -> ClockPlan | None:
    """The run's :class:`ClockPlan`, ``None`` for a common clock."""
    if config.common:
        return None
    return ClockPlan.from_ppm(*config.resolve(n_nodes, seed), slots)


def system_lines(n_nodes: int) -> list[tuple[str, int, str, int]]:
    """The per-node-clock System's line wires ``(sender port, sender domain, receiver port,
    receiver domain)``: per hop ``k`` its D and S words down (from the master port or node
    ``k − 1``) and up (from node ``k``)."""
    out = []
    for k in range(1, n_nodes + 1):
        for w in ("d", "s"):
            out.append((f"down_{w}_out{k}", k - 1, f"down_{w}_in{k}", k))
            out.append((f"up_{w}_out{k}", k, f"up_{w}_in{k}", k - 1))
    return out


def output_domain(name: str) -> int:
    """Which clock an output of the System belongs to: node ``k``'s torque, brake, status,
    count and events ``k``, else the master port's (0)."""
    for stem in ("torque", "brake", "status", "count", "events"):
        if name.startswith(stem) and name[len(stem):].isdigit():
            return int(name[len(stem):])
    return 0


def is_strobe(name: str) -> bool:
    return name.startswith("events")


class ClockedEngine:
    """The event order and the resampler of a per-node-clock run, in Python (the pysim
    harness; :mod:`cosim.compiled` does the same in C++).

    The harness calls :meth:`next_group` for the edges up to the end of the current master
    cycle, and for each domain of a group :meth:`line_inputs` (what to set before its edge),
    then, after the edge, :meth:`record` of its line outputs.
    """

    def __init__(self, plan: ClockPlan, lines):
        self.plan = plan
        self.lines = list(lines)
        self.cycle = [0] * plan.n_domains        # every domain's current (unfinished) cycle
        self.hist: list[dict] = [{} for _ in self.lines]   # sender cycle -> word, per line
        self.merged = 0

    def edge(self, d: int) -> int:
        """The time of domain ``d``'s next rising edge (the end of its current cycle)."""
        return self.plan.phases[d] + (self.cycle[d] + 1) * self.plan.periods[d]

    def node_group(self, until: int) -> list[int] | None:
        """The nodes whose next edge is the earliest one at or before ``until`` (all of them
        at that instant), or ``None``."""
        best, group = None, []
        for d in range(1, self.plan.n_domains):
            e = self.edge(d)
            if e > until:
                continue
            if best is None or e < best:
                best, group = e, [d]
            elif e == best:
                group.append(d)
        return group or None

    def level_word(self, line: int, d: int) -> int:
        """The word receiver ``d`` takes on ``line`` in its current cycle."""
        _src, s, _dst, _r = self.lines[line]
        plan, slots = self.plan, self.plan.slots
        p_r, p_s, phi_s = plan.periods[d], plan.periods[s], plan.phases[s]
        t0 = plan.phases[d] + self.cycle[d] * p_r
        hist = self.hist[line]
        word = 0
        for j in range(slots):
            at = slot_at(t0 + (j * p_r) // slots, phi_s, p_s, slots)
            c, k = (0, 0) if at is None else at     # (before its cycle 0: its reset word)
            word |= ((hist[c] >> k) & 1) << j
        return word

    def record(self, d: int, get) -> None:
        """After domain ``d``'s edge (its cycle counted on): its line outputs, ``get(port)``."""
        c = self.cycle[d]
        for i, (src, s, _dst, _r) in enumerate(self.lines):
            if s == d:
                h = self.hist[i]
                h[c] = get(src)
                h.pop(c - 8, None)
