"""The node's period timer, its time-code monitor and the snapshot taken at its boundary.

The timer free-runs from reset through phases ``0 .. PERIOD − 1``; phase 0 is the period
boundary. A time-code (``time_code``) arriving at a phase outside ``[0, SYNC_WINDOW)`` makes
its own cycle a boundary (re-synchronisation), counted while armed (``sync_errors`` in
Comm A). Nothing here depends on when a packet arrived, only on what it said (docs/node.md
"Timing").

At every boundary the timer keeps a :class:`Snapshot` of the node's live values — what a
Comm A reports, and the velocity the VDC is given for the period.
"""

from amaranth import *
from amaranth.lib import data, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.fixed import WORD

__all__ = ["PeriodTimer", "Snapshot"]


class Snapshot(data.Struct):
    """The node's state at a period boundary (Comm A's fields of that boundary)."""

    count:    signed(32)      # encoder count
    velocity: signed(WORD)    # q̇, VEL
    torque:   signed(WORD)    # torque applied, FORCE
    status:   16              # :class:`~protocol.regs.Status`
    errors:   16              # illegal encoder transitions
    overruns: 16              # control ticks skipped
    late_d:   16              # Comm D packets after the commit phase


class PeriodTimer(wiring.Component):
    """Phase counter, boundary, re-synchronisation and the boundary's snapshot.

    Attributes
    ----------
    period, window : In(24)
        CONFIG PERIOD (cycles) and SYNC_WINDOW.
    time_code : In(1)
        The time-code strobe.
    armed : In(1)
        The watchdog is armed (re-synchronisations are counted).
    phase : Out(24)
        Cycles since the last boundary (0 in the cycle after a period's last phase; 1 after a
        boundary).
    boundary : Out(1)
        Phase 0, or a re-synchronising time-code.
    resync : Out(1)
        The boundary is a time-code outside the window.
    pre_boundary : Out(1)
        The period's last phase (``PERIOD − 1``).
    elapsed : Out(24)
        Cycles since the boundary, 0 in the boundary's own cycle.
    live : In(Snapshot)
        The values the snapshot takes.
    snapshot : Out(Snapshot)
        ``live`` at the last boundary.
    sync_errors : Out(16)
        Re-synchronisations while armed up to the last boundary, saturating (a
        re-synchronising boundary counts itself).
    """

    period:       In(24)
    window:       In(24)
    time_code:    In(1)
    armed:        In(1)
    phase:        Out(24)
    boundary:     Out(1)
    resync:       Out(1)
    pre_boundary: Out(1)
    elapsed:      Out(24)
    live:         In(Snapshot)
    snapshot:     Out(Snapshot)
    sync_errors:  Out(16)

    def elaborate(self, platform):
        m = Module()
        phase = self.phase
        count = Signal(16)              # re-synchronisations while armed
        m.d.comb += [
            self.resync.eq(self.time_code & (phase >= self.window)),
            self.boundary.eq((phase == 0) | self.resync),
            self.pre_boundary.eq(phase == self.period - 1),
            self.elapsed.eq(Mux(self.boundary, 0, phase)),
        ]
        with m.If(self.boundary):
            m.d.sync += phase.eq(1)
        with m.Elif(phase >= self.period - 1):
            m.d.sync += phase.eq(0)
        with m.Else():
            m.d.sync += phase.eq(phase + 1)
        counted = self.resync & self.armed & (count != 0xFFFF)
        with m.If(counted):
            m.d.sync += count.eq(count + 1)

        with m.If(self.boundary):
            m.d.sync += [
                self.snapshot.eq(self.live),
                self.sync_errors.eq(Mux(counted, count + 1, count)),
            ]
        return m
