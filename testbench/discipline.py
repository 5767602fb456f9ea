"""Node period timers on clocks of their own against the master's time-code: issue 21 item 3.

The master starts a period every ``PERIOD`` cycles of *its* clock (20 ns nominal) and sends a
time-code then; node ``k`` is ``hop`` hops down the chain and sees it after a fixed latency of
``HOP_FIXED`` master cycles per hop plus, per hop, a wait of 0–``HOP_JITTER`` cycles for the
character on the line (docs/link.md: 10–14 cycles per hop). Each node runs the bit-exact
timer reference (:class:`~hdl.node.timer_ref.TimerModel`, equal to the gateware cycle by
cycle: tests/test_node_timer.py) on its own clock, ``ppm`` parts per million fast (negative:
slow) with a phase of its own, and samples the strobe at its first clock edge at or after the
arrival.

Times are exact integers (as in :mod:`.clocks`): a master cycle lasts ``10**6`` time units, a
node's ``10**6 − ppm`` (so its frequency is ``ppm`` ppm above nominal to within 1e−8 of it).
Everything resets together at time 0 (a node's cycle 0 starts at its phase, less than a
cycle later): the grid the nodes share today through a common reset, which their clocks then
leave.

The **skew** of a node in master period ``n`` is the time from the master's period start to
the node's nearest period boundary, in master cycles (positive: the node late). With the loop
on, the target phase is the node's mean latency (``(HOP_FIXED + HOP_JITTER/2)·hop``, what the
master knows from the link's stamps), so the skew it is steered to is zero give or take the
jitter: the fixed latency is compensated, not measured.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np

from mrm_cosim.hdl.node.timer_ref import TimerModel
from mrm_cosim.protocol.discipline import FRAC, Discipline

__all__ = ["NodeClock", "NodeRun", "run_discipline", "random_clocks", "drift_per_period",
           "skew_bound", "GAINS", "RATE_WANDER", "HOP_FIXED", "HOP_JITTER", "UNIT"]

HOP_FIXED = 10          # master cycles per hop, fixed part
HOP_JITTER = 4          # master cycles per hop, the wait for the character being sent (0–4)
UNIT = 10**6            # time units per master cycle


@dataclass(frozen=True)
class NodeClock:
    """A node's clock and place: ``ppm`` off nominal, ``phase`` (its cycle 0's start, in master
    cycles, 0 ≤ phase < 1), ``hop`` (1: next to the master) and ``start`` (master cycles: the
    node leaves reset that much after the master; 0 is the common reset of today)."""

    ppm: int
    phase: float = 0.0
    hop: int = 1
    start: int = 0

    @property
    def target(self) -> int:
        """The node's mean time-code latency (cycles): the loop's target phase."""
        return (HOP_FIXED * 2 + HOP_JITTER) * self.hop // 2


#: The loop's gains of the test and the benchmark (docs/node.md "Discipline").
GAINS = Discipline(kp=1, ki=4)
#: Largest |rate estimate − drift| (cycles per period) of a locked loop: the premise of
#: :func:`skew_bound`, checked by the test from period 60 on (measured: ≤ 1.0 over 40 runs of
#: 1,000 periods, ``benchmarks/timer_discipline.py``). The estimate integrates e/16 per
#: period, so the jitter moves it by up to ``(J/2 + 1)/16`` a period around the drift.
RATE_WANDER = 1.5


def skew_bound(hop: int) -> float:
    """Bound on a locked node's |skew| (master cycles) at chain position ``hop`` with
    :data:`GAINS` (kp = 1), node and master cycles taken as equal (100 ppm of a few cycles).

    The node's boundary is late by ``s``; the time-code arrives at phase ``L + j − s + q``
    (latency ``L``, jitter ``j`` in ``[0, J]``, ``J = HOP_JITTER·hop``, sampling ``q`` in
    ``[0, 1)``), the target is ``L + J/2``, so ``e = j − J/2 + q − s``. The period's change
    is ``⌊e/2⌋ + r`` and the master's period is ``d`` longer than the node's, the carry ``r``
    equal to ``d`` plus the rate's error ``ε`` plus the fraction's change (less than a cycle).
    So ``s' = s/2 + w`` with ``|w| ≤ (J/2 + 1)/2 + 1/2 + 1 + ε`` (jitter and sampling, the
    floored half, the fraction), and ``|s| ≤ 2·max|w| = J/2 + 4 + 2ε`` — less the half cycle
    the signs of the sampling and the floor share: ``J/2 + 3 + 2ε``, with ε at most
    :data:`RATE_WANDER`."""
    return HOP_JITTER * hop / 2 + 3 + 2 * RATE_WANDER


@dataclass
class NodeRun:
    """One node's run: per master period ``n = 1 … periods`` the skew (master cycles), the
    number of re-synchronisations and their cycles, the boundaries (node cycles) and the
    loop's phase errors."""

    clock: NodeClock
    skew: np.ndarray
    resyncs: int
    resync_at: list
    boundaries: list
    errors: list = field(default_factory=list)
    rates: np.ndarray = None    # the loop's rate estimate after each time-code, cycles/period

    def lock_period(self, bound: float) -> int | None:
        """First period from which |skew| stays within ``bound`` (None: never)."""
        out = np.abs(self.skew) > bound
        if not out.any():
            return 1
        last = int(np.nonzero(out)[0][-1])
        return None if last == len(self.skew) - 1 else last + 2

    def stats(self, since: int = 1) -> tuple[float, float]:
        """Max |skew| and RMS skew (master cycles) over periods ``since …``."""
        s = self.skew[since - 1:]
        return float(np.max(np.abs(s))), float(np.sqrt(np.mean(s * s)))


def run_discipline(clocks, periods: int, *, period: int = 50_000, window: int = 2_500,
                   discipline: Discipline | None = None, seed: int = 0) -> list[NodeRun]:
    """Run ``periods`` master periods for every node of ``clocks`` (:class:`NodeClock`).

    ``discipline``: the loop's gains (its target replaced per node by
    :attr:`NodeClock.target`); None: TC_DISCIPLINE 0, today's free-running timer.
    """
    rng = np.random.default_rng(seed)
    runs = []
    for clk in clocks:
        t_node = UNIT - clk.ppm
        phi = int((clk.start + clk.phase) * UNIT)
        word = 0
        if discipline is not None:
            word = Discipline(target=clk.target, kp=discipline.kp, ki=discipline.ki).word
        timer = TimerModel(period=period, window=window, armed=True)
        timer.config(0, word)
        for n in range(1, periods + 1):
            delay = HOP_FIXED * clk.hop + int(rng.integers(0, HOP_JITTER + 1, clk.hop).sum())
            t_arr = (n * period + delay) * UNIT
            timer.timecode(-((phi - t_arr) // t_node))          # ceil: the first edge ≥ it
        end = -((phi - (periods + 1) * period * UNIT) // t_node)
        timer.advance(end)
        b_times = [phi + b * t_node for b in timer.boundaries]
        skew = []
        for n in range(1, periods + 1):
            m = n * period * UNIT
            i = bisect.bisect_left(b_times, m)
            near = min((b_times[j] for j in (i - 1, i) if 0 <= j < len(b_times)),
                       key=lambda t, m=m: abs(t - m))
            skew.append((near - m) / UNIT)
        runs.append(NodeRun(clk, np.array(skew), len(timer.resyncs), timer.resyncs,
                            timer.boundaries,
                            timer.errors, np.array(timer.rates) / (1 << FRAC)))
    return runs


def random_clocks(seed: int = 0, ppms=(100, -100, 50, -50), late: bool = False,
                  period: int = 50_000) -> list[NodeClock]:
    """The test's and the benchmark's nodes: one per chain position, clocks ``ppms``, phases
    drawn from ``seed``; ``late``: each leaves reset at a random cycle of the master's first
    period (no common reset: the first time-code re-synchronises it, the loop acquires)."""
    rng = np.random.default_rng(seed)
    return [NodeClock(ppm=p, phase=float(rng.uniform(0, 1)), hop=h + 1,
                      start=int(rng.integers(1, period)) if late else 0)
            for h, p in enumerate(ppms)]


def drift_per_period(ppm: int, period: int = 50_000) -> float:
    """Master cycles a free-running node's boundary moves per period of its own (negative:
    it comes earlier): ``period`` node cycles last ``period · (10^6 − ppm) / 10^6`` master
    cycles, exactly, with this harness's clocks."""
    return -period * ppm / UNIT
