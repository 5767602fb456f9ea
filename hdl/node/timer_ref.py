"""Reference of the node's period timer alone (:class:`~hdl.node.timer.PeriodTimer`): phase,
boundaries, re-synchronisation and the time-code discipline (:mod:`~protocol.discipline`),
event by event with exact cycles.

:class:`~hdl.node.core_ref.NodeModel` keeps the same timer inside the node's reference (with
the snapshot and the ticks); this one is the timer only, fast enough for thousands of periods
on clocks of their own (:mod:`mrm_cosim.testbench.discipline`) and small enough to compare
with the gateware cycle by cycle (tests/test_node_timer.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mrm_cosim.protocol.discipline import LATENCY, Discipline, arrival, loop_step, period_length

__all__ = ["TimerModel"]


@dataclass
class TimerModel:
    """The period timer from reset (cycle 0 is a boundary).

    Attributes
    ----------
    period, window, tick : int
        CONFIG PERIOD, SYNC_WINDOW, TICK.
    word : int
        CONFIG TC_DISCIPLINE (:meth:`config` writes it).
    armed : bool
        Re-synchronisations are counted (``sync_errors``).
    boundaries, resyncs : list of int
        Cycles of every boundary (re-synchronisations included) and of the re-synchronising
        ones.
    f, a, adj : int
        The loop's rate estimate, fraction and this period's adjustment.
    pending : tuple or None
        A step under way: ``(cycle, f, a, adj)``, its values and the first cycle they apply
        (:data:`~protocol.discipline.LATENCY` after its time-code).
    errors, rates : list of int
        The phase error ``phase − target`` of every time-code the loop took, and the rate
        estimate ``f`` after it.
    """

    period: int = 50_000
    window: int = 2_500
    tick: int = 50
    word: int = 0
    armed: bool = False
    boundaries: list = field(default_factory=list)
    resyncs: list = field(default_factory=list)
    errors: list = field(default_factory=list)
    rates: list = field(default_factory=list)
    sync_errors: int = 0
    f: int = 0
    a: int = 0
    adj: int = 0
    pending: tuple | None = None
    lb: int = 0                 # last boundary
    nb: int = 0                 # next boundary (cycle 0 at reset)

    @property
    def enabled(self) -> bool:
        return Discipline.from_word(self.word).enable

    @property
    def length(self) -> int:
        """The period's length (cycles), :func:`~protocol.discipline.period_length`."""
        return period_length(self.period, self.adj)

    def rem(self, now: int) -> int:
        """The gateware's ``rem = PERIOD + adj − phase`` in cycle ``now``."""
        phase = self.phase(now)
        return self.period + self.adj - phase

    def advance(self, now: int) -> None:
        """Process the boundaries of cycles before ``now`` and a loop step applying in
        ``now`` or before (before a boundary in its own cycle: that period is the new
        length)."""
        while True:
            p = self.pending
            if p is not None and p[0] <= now and p[0] <= self.nb:
                self.pending = None
                self.f, self.a, self.adj = p[1:]
                self.rates.append(self.f)
                self._relength(p[0] - 1)
            elif self.nb < now:
                self.lb = self.nb
                self.nb = self.lb + self.length
                self.boundaries.append(self.lb)
            else:
                break

    def phase(self, now: int) -> int:
        """The timer's phase in cycle ``now`` (0 in a boundary's cycle)."""
        self.advance(now)
        return 0 if now >= self.nb else now - self.lb

    def tail(self, now: int) -> bool:
        """No control tick in cycle ``now``: the loop on and fewer than TICK cycles to the
        boundary (``rem < TICK``)."""
        return self.enabled and self.rem(now) < self.tick

    def _relength(self, now: int) -> None:
        if now + 1 < self.nb:       # the gateware compares with the new length from now + 1
            self.nb = max(self.lb + self.length, now + 2)

    def timecode(self, now: int) -> bool:
        """A time-code strobe in cycle ``now``; returns whether it re-synchronised."""
        p = self.phase(now)
        busy = self.pending is not None         # a step under way: this one is not taken
        resync, lp = arrival(self.word, p, self.window, self.period + self.adj)
        if resync:
            self.nb = now
        self.advance(now + 1)
        if resync:
            self.resyncs.append(now)
            if self.armed:
                self.sync_errors = min(self.sync_errors + 1, 0xFFFF)
            if self.enabled:        # the arrival cycle counts as phase `target`
                self.lb = now - Discipline.from_word(self.word).target
                self.nb = self.lb + self.length
        elif self.enabled and not busy:
            self.errors.append(lp - Discipline.from_word(self.word).target)
            self.pending = (now + LATENCY, *loop_step(self.word, lp, self.f, self.a))
        return resync

    def config(self, now: int, word: int) -> None:
        """CONFIG TC_DISCIPLINE written in cycle ``now``: the loop cleared."""
        self.advance(now)
        self.word = word
        self.f = self.a = self.adj = 0
        self.pending = None
        self._relength(now)
