"""The node's period timer, its time-code monitor and the snapshot taken at its boundary.

The timer free-runs from reset through phases ``0 .. PERIOD − 1``; phase 0 is the period
boundary. A time-code (``time_code``) arriving at a phase outside ``[0, SYNC_WINDOW)`` makes
its own cycle a boundary (re-synchronisation), counted while armed (``sync_errors`` in
Comm A). Nothing here depends on when a packet arrived, only on what it said (docs/node.md
"Timing").

With CONFIG TC_DISCIPLINE on (:mod:`~protocol.discipline`, issue 21 item 3) a time-code inside
the window runs one step of a digital PLL: the signed phase error ``e = phase − target`` sets
this period's length to ``PERIOD + adj``, ``adj`` a share of ``e`` (saturated to 8 bits, so
bounded) plus the carry of a fractional rate accumulator that integrates ``e``; ``tail`` then
marks the last TICK cycles before the boundary (no control tick there). The step is
computed serially (one shift a cycle for the gains, no barrel shifters): the new ``adj``
applies :data:`~protocol.discipline.LATENCY` cycles after the time-code, and a time-code
in the cycles between is not taken by the loop. One subtraction,
``rem = PERIOD + adj − phase`` (the cycles to the boundary), serves the end of the period
(``rem ≤ 1``), its last phase, the tail, the window before the boundary and that side's
error. The window is then two-sided: a time-code up to SYNC_WINDOW cycles *before* a
boundary is an early one, its error ``−rem − target`` (negative), not a resync. A
re-synchronising time-code is still a boundary, but the phase restarts at ``target + 1``
instead of 1: the arrival cycle counts as phase ``target``, so the next boundary comes where
the master's does (acquisition in one period; restarting at 1, a slow node's next time-code
would arrive before its boundary and re-synchronise it again, every period). Off (0, the
default), ``adj`` stays 0 and ``tail`` 0: the free-running timer.

At every boundary the timer keeps a :class:`Snapshot` of the node's live values — what a
Comm A reports, and the velocity the VDC is given for the period.
"""

from amaranth import *
from amaranth.lib import data, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.discipline import (E_BITS, FRAC, GAIN_BITS, LATENCY, RATE_BITS,
                                           TARGET_BITS)
from mrm_cosim.protocol.fixed import WORD
from mrm_cosim.protocol.regs import CONFIG_DEFAULTS, Config

__all__ = ["PeriodTimer", "Snapshot", "DisciplineWord"]


class DisciplineWord(data.Struct):
    """CONFIG TC_DISCIPLINE (:class:`~protocol.discipline.Discipline`)."""

    target: TARGET_BITS     # phase the time-code should arrive at
    kp:     GAIN_BITS       # phase gain 2^-kp
    ki:     GAIN_BITS       # rate gain 2^-ki
    enable: 1


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
    discipline : In(DisciplineWord)
        CONFIG TC_DISCIPLINE; ``restart`` (In(1)) its write strobe, which clears the loop.
    tick : In(16)
        CONFIG TICK.
    window_next : In(24)
        The value ``window`` takes in the next cycle (:class:`~hdl.node.config.NodeConfig`'s).
    pm1_next, pmw_next, pmt_next : In(signed(26))
        ``PERIOD − 1``, ``PERIOD − SYNC_WINDOW`` and ``PERIOD − TICK + 1`` as they stand in
        the next cycle (NodeConfig keeps them in registers, formed as a CONFIG record comes
        in): the comparisons with the cycles to the boundary, ``rem = PERIOD + adj − phase``,
        are ``phase`` against thresholds kept in registers (these plus ``adj``), computed a
        cycle ahead with the loop's next ``adj``; and the compares themselves are flags formed
        a cycle ahead from the phase's next value. The adder in front of each compare had made
        ``phase`` → ``rem`` → window → resync → boundary the node's slowest path.
    tail : Out(1)
        The loop on and fewer than TICK cycles to the boundary: no control tick.
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
    discipline:   In(DisciplineWord)
    restart:      In(1)
    tick:         In(16)
    window_next:  In(24, init=CONFIG_DEFAULTS[Config.SYNC_WINDOW])
    pm1_next:     In(signed(26), init=CONFIG_DEFAULTS[Config.PERIOD] - 1)
    pmw_next:     In(signed(26), init=CONFIG_DEFAULTS[Config.PERIOD]
                     - CONFIG_DEFAULTS[Config.SYNC_WINDOW])
    pmt_next:     In(signed(26), init=CONFIG_DEFAULTS[Config.PERIOD]
                     - CONFIG_DEFAULTS[Config.TICK] + 1)
    tail:         Out(1)

    def elaborate(self, platform):
        m = Module()
        phase = self.phase
        count = Signal(16)              # re-synchronisations while armed
        adj   = Signal(signed(RATE_BITS - FRAC + 2))    # this period's length − PERIOD
        rem   = Signal(signed(26))      # cycles to the boundary (1 in the period's last phase)
        late  = Signal()                # past the window after the boundary
        early = Signal()                # the loop on and within the window before one
        adj_next = Signal.like(adj)
        p0, w0, t0 = (CONFIG_DEFAULTS[r] for r in (Config.PERIOD, Config.SYNC_WINDOW,
                                                   Config.TICK))
        # the thresholds rem ≤ 1, rem ≤ window, rem < tick become on phase (PERIOD + adj − 1,
        # − SYNC_WINDOW, − TICK + 1)
        thr1  = Signal(signed(27), init=p0 - 1)
        thrw  = Signal(signed(27), init=p0 - w0)
        thrt  = Signal(signed(27), init=p0 - t0 + 1)
        thr1_next = Signal(signed(27))
        thrw_next = Signal(signed(27))
        thrt_next = Signal(signed(27))
        m.d.comb += [
            thr1_next.eq(self.pm1_next + adj_next),
            thrw_next.eq(self.pmw_next + adj_next),
            thrt_next.eq(self.pmt_next + adj_next),
        ]
        m.d.sync += [
            thr1.eq(thr1_next),
            thrw.eq(thrw_next),
            thrt.eq(thrt_next),
        ]
        # The phase's comparisons, kept in registers formed a cycle ahead: the phase's next
        # value against the next window and thresholds (each flag equals its compare in every
        # cycle). CONFIG's records reach ``*_next`` from a register (the core delays them a
        # cycle), so no path from the link's depacketizer runs through these compares.
        phase_next = Signal.like(phase)
        f_zero = Signal(init=1)                             # phase == 0
        f_late = Signal(init=int(0 >= w0))                  # phase ≥ SYNC_WINDOW
        f_thrw = Signal(init=int(0 >= p0 - w0))             # phase ≥ thrw
        f_end  = Signal(init=int(0 >= p0 - 1))              # phase ≥ thr1 (rem ≤ 1)
        f_pre  = Signal(init=int(0 == p0 - 1))              # phase == thr1
        f_tail = Signal(init=int(0 >= p0 - t0 + 1))         # phase ≥ thrt
        m.d.sync += [
            phase.eq(phase_next),
            f_zero.eq(phase_next == 0),
            f_late.eq(phase_next >= self.window_next),
            f_thrw.eq(phase_next >= thrw_next),
            f_end.eq(phase_next >= thr1_next),
            f_pre.eq(phase_next == thr1_next),
            f_tail.eq(phase_next >= thrt_next),
        ]
        m.d.comb += [
            rem.eq(thr1 + 1 - phase),
            late.eq(f_late),
            early.eq(self.discipline.enable & late & f_thrw),
            self.resync.eq(self.time_code & late & ~early),
            self.boundary.eq(f_zero | self.resync),
            self.pre_boundary.eq(f_pre),
            self.elapsed.eq(Mux(self.boundary, 0, phase)),
            self.tail.eq(self.discipline.enable & f_tail),
        ]
        self._loop(m, adj, adj_next, rem, early)
        with m.If(self.resync & self.discipline.enable):
            m.d.comb += phase_next.eq(self.discipline.target + 1)   # acquisition at the target
        with m.Elif(self.boundary):
            m.d.comb += phase_next.eq(1)
        with m.Elif(f_end):                                     # rem ≤ 1
            m.d.comb += phase_next.eq(0)
        with m.Else():
            m.d.comb += phase_next.eq(phase + 1)
        counted = self.resync & self.armed & (count != 0xFFFF)
        with m.If(counted):
            m.d.sync += count.eq(count + 1)

        with m.If(self.boundary):
            m.d.sync += [
                self.snapshot.eq(self.live),
                self.sync_errors.eq(Mux(counted, count + 1, count)),
            ]
        return m

    def _loop(self, m, adj, adj_next, rem, early):
        """The discipline's step at an in-window time-code
        (:func:`~protocol.discipline.loop_step`), serially: in the time-code's cycle the
        arrival's phase, or minus the cycles to the boundary, clipped to 14 bits (``e``
        saturates at ±128, so ``|x| ≥ 2^13 > 4095 + 128`` saturates whatever the target), into
        a register ``x_r``; in the next (``k = 1``) the error ``e = sat(x_r − target)`` into
        two shift registers, ``e·2^FRAC`` and ``e``, each already shifted right once if
        ``ki ≥ 1`` (``kp ≥ 1``); in each of the next cycles ``k`` up to 2^GAIN_BITS − 1 each
        shifts right by one while ``k ≤ ki`` (``kp``), which leaves ``(e·2^FRAC) >> ki`` and
        ``e >> kp`` without a barrel shifter; the sums are formed with the last shift (step
        LATENCY − 2) and go into ``f``, ``a``, ``adj`` in the next cycle —
        :data:`~protocol.discipline.LATENCY` cycles after the time-code (the timer's thresholds
        take the new ``adj`` from them a cycle ahead). (The error had been
        formed in the time-code's cycle, behind the cycles-to-boundary adder and the window's
        compare: 45 logic levels, the node's slowest path, 42 MHz on ECP5.) ``step`` ≠ 0: a
        step under way, a time-code then is not taken."""
        d = self.discipline
        e_max = 1 << (E_BITS - 1)
        f_max = 1 << (RATE_BITS - 1)
        big  = 1 << 13
        x    = Signal(signed(15))               # phase, or −rem before the boundary, clipped
        x_r  = Signal(signed(15))               # x in the time-code's cycle
        raw  = Signal(signed(16))
        sat  = Signal()                         # e saturated: no integration
        e    = Signal(signed(E_BITS))
        f    = Signal(signed(RATE_BITS))        # rate estimate, FRAC fraction bits
        a    = Signal(FRAC)                     # the accumulator's fraction
        fsum = Signal(signed(RATE_BITS + 1))
        f2   = Signal(signed(RATE_BITS))
        s    = Signal(signed(RATE_BITS + 1))
        sat_r = Signal()                        # e saturated, kept for the sums
        sf   = Signal(signed(RATE_BITS))        # e·2^FRAC, shifted right ki times
        sp   = Signal(signed(E_BITS))           # e, shifted right kp times
        step = Signal(range(LATENCY))           # 0 idle; 1 … LATENCY − 2 shifts; the sums
        sf_last = Signal.like(sf)
        sp_last = Signal.like(sp)
        f_pre   = Signal.like(f)                # the sums, formed a cycle before they apply
        a_pre   = Signal.like(a)
        adj_pre = Signal.like(adj)
        top  = raw[E_BITS - 1:]                 # all equal: raw fits E_BITS
        rtop = rem[13:]                         # all equal: rem fits 14 bits
        rfit = (rtop == 0) | (rtop == (1 << len(rtop)) - 1)
        m.d.comb += [
            x.eq(Mux(early, Mux(rfit, -rem[:14].as_signed(), Mux(rem[-1], big, -big)),
                     Mux(self.phase[13:].any(), big, self.phase[:14]))),
            raw.eq(x_r - d.target),
            sat.eq(~((top == 0) | (top == (1 << len(top)) - 1))),
            e.eq(Mux(sat, Mux(raw[-1], -e_max, e_max - 1), raw)),
            # the sums are formed in step LATENCY − 2, from the values its shifts leave
            sf_last.eq(Mux(step <= d.ki, sf >> 1, sf)),
            sp_last.eq(Mux(step <= d.kp, sp >> 1, sp)),
            fsum.eq(f + sf_last),
            f2.eq(Mux(sat_r, f,
                      Mux(fsum[-1] == fsum[-2], fsum,                   # no overflow
                          Mux(fsum[-1], -f_max, f_max - 1)))),
            s.eq(a + f2),
        ]
        with m.If(self.restart):
            m.d.sync += [f.eq(0), a.eq(0), adj.eq(0), step.eq(0)]
        with m.Elif(step == 0):
            with m.If(self.time_code & ~self.resync & d.enable):
                m.d.sync += [x_r.eq(x), step.eq(1)]
        with m.Elif(step == 1):
            ef = Signal(signed(RATE_BITS))
            m.d.comb += ef.eq(e << FRAC)
            m.d.sync += [
                sat_r.eq(sat),
                sf.eq(Mux(d.ki != 0, ef >> 1, ef)),
                sp.eq(Mux(d.kp != 0, e >> 1, e)),
                step.eq(2),
            ]
        with m.Elif(step == LATENCY - 1):
            m.d.sync += [
                f.eq(f_pre),
                a.eq(a_pre),
                adj.eq(adj_pre),
                step.eq(0),
            ]
        with m.Else():
            with m.If(step <= d.ki):
                m.d.sync += sf.eq(sf >> 1)
            with m.If(step <= d.kp):
                m.d.sync += sp.eq(sp >> 1)
            with m.If(step == LATENCY - 2):
                m.d.sync += [
                    f_pre.eq(f2),
                    a_pre.eq(s[:FRAC]),
                    adj_pre.eq((s >> FRAC) + sp_last),
                ]
            m.d.sync += step.eq(step + 1)
        m.d.comb += adj_next.eq(Mux(self.restart, 0,
                                    Mux(step == LATENCY - 1, adj_pre, adj)))
