"""Control ticks: what the joint engine is given, and when.

Every TICK cycles from the period boundary (and at the boundary itself) is a control tick:
the encoder takes a velocity sample and the joint program (:mod:`.joint`, the CONFIG MODE's
entry) runs on inputs latched in that cycle — the encoder count (saturated to a word), the
velocity, the Comm D references in effect and ``t_next``, the time their reference trajectory
is evaluated at (``ref_time + TICK``, saturating). A tick that finds the joint engine busy is
skipped and counted (``overruns`` in Comm A).

While the watchdog holds the joint (``hold``: the safe stop's SS1/SS2 stage after a trip,
:class:`~hdl.node.watchdog.Watchdog`, docs/node.md "Safe stop") every tick runs the PID entry
whatever the mode, on node-local references: ``q_d0`` the encoder count of the hold tick (as a
POS word, saturated) until a hold tick finds the joint at rest (``rest``, the watchdog's: its
velocity within ±STANDSTILL, the brake on, or the standstill rule off), that tick's target
from then on, ``q̇_d0 = q̈_d0 = 0`` and ``τ_D = 0`` (no feed-forward); the PID words ``kp, ki,
kd`` are the hold gains. The target trails the count by at most ``trail`` counts (CONFIG
STOP_TRAIL): the first hold tick takes the count, each later stopping tick (the one that
finds ``rest`` included) ``q_d0 ← clamp(q_d0, count − trail, count + trail)`` (in POS
words: ``trail · 2^4``). With ``trail`` = 0 the target is each tick's count, the position
error the last tick's step (≈ 0), and the velocity term ``k_d (0 − q̇)`` stops the joint, at
most at the torque limit; with ``trail`` > 0 a joint that gravity drives builds a position
error of up to ``trail`` whose P term and integral carry the load, so it comes to rest. The
frozen target then holds it where it came to rest (SS1's stop, then SS2's standstill), not
where it was at the trip.

Between runs the joint engine's host port takes, in priority order, the PID integral clears
of an ARM (:class:`~hdl.node.config.NodeConfig`) and the PARAM words for the joint bank.
"""

from amaranth import *
from amaranth.lib import data, stream, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.fixed import POS, WORD
from mrm_cosim.protocol.isa import ADDR_BITS, Microcode
from mrm_cosim.protocol.joint_program import INPUTS as JOINT_INPUTS
from mrm_cosim.protocol.regs import MODES

from .commit import TIME_MAX
from .decoder import CommDWords, HostWrite

__all__ = ["ControlTicks", "TickInputs"]

#: The joint program's input ports by name (:data:`~hdl.node.joint.INPUTS`), as latched at a
#: tick.
TickInputs = data.StructLayout({n: signed(WORD) for n in JOINT_INPUTS})


class ControlTicks(wiring.Component):
    """The tick counter, the joint engine's inputs and host port (see the module docstring).

    Parameters
    ----------
    joint : Microcode
        The joint program (entries per mode, the integral's registers).

    Attributes
    ----------
    boundary : In(1)
        The period boundary (the ticks restart).
    tail : In(1)
        No tick but the boundary's: the last TICK cycles of a disciplined period
        (:class:`~hdl.node.timer.PeriodTimer`).
    cycles : In(16)
        CONFIG TICK: cycles per tick.
    mode : In(2)
        CONFIG MODE: which entry of the joint program runs.
    count : In(signed(32))
    velocity : In(signed(24))
        The encoder's live count and velocity.
    refs : In(CommDWords)
        The Comm D references in effect; ``ref_time`` the cycles since the boundary they are
        for (:class:`~hdl.node.commit.ReferenceCommit`).
    ref_time : In(24)
    busy : In(1)
        The joint engine runs.
    clear_lo, clear_hi : In(1)
        Strobes: write zero into ``ilo_s`` / ``ihi_s``.
    hold : In(1)
        The safe stop holds the joint (PID entry, node-local references).
    rest : In(1)
        The joint is at rest for the hold (the watchdog's ``rest``): the hold tick that finds
        it set updates ``q_d0`` a last time; the ticks before it each update it.
    trail : In(16)
        CONFIG STOP_TRAIL: how far (counts) the hold's target may trail the count while
        stopping.
    words : In(stream.Signature(HostWrite))
        PARAM words for the joint bank (the bank field is not looked at).
    tick : Out(1)
        Strobe: a control tick (the encoder's velocity sample, the watchdog's tick).
    overruns : Out(16)
        Ticks skipped because the engine was busy, saturating.
    start : Out(1)
    entry : Out(ROM address)
        The joint engine's start strobe and entry.
    inputs : Out(TickInputs)
        The joint engine's inputs, latched at the tick that starts it.
    host_addr, host_wdata, host_we : Out(9), Out(signed(24)), Out(1)
        The joint engine's host write port.
    """

    def __init__(self, joint: Microcode):
        if not isinstance(joint, Microcode):
            raise TypeError(f"joint must be a Microcode, not {joint!r}")
        self._mc = joint
        super().__init__({
            "boundary":   In(1),
            "tail":       In(1),
            "cycles":     In(16),
            "mode":       In(2),
            "count":      In(signed(32)),
            "velocity":   In(signed(WORD)),
            "refs":       In(CommDWords),
            "ref_time":   In(24),
            "busy":       In(1),
            "clear_lo":   In(1),
            "clear_hi":   In(1),
            "hold":       In(1),
            "rest":       In(1),
            "trail":      In(16),
            "words":      In(stream.Signature(HostWrite)),
            "tick":       Out(1),
            "overruns":   Out(16),
            "start":      Out(1),
            "entry":      Out(range(len(joint.instrs))),
            "inputs":     Out(TickInputs),
            "host_addr":  Out(ADDR_BITS),
            "host_wdata": Out(signed(WORD)),
            "host_we":    Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        jmc = self._mc
        tick_cnt = Signal(16)
        tick     = self.tick
        tn       = Signal(25)
        count24  = Signal(signed(WORD))
        j_in     = self.inputs
        entries  = Array(C(jmc.entries[mode], range(len(jmc.instrs))) for mode in MODES)
        hold_set = Signal()             # the hold's position is in j_in.qd0
        hold_run = Signal()             # a hold tick has set j_in.qd0 (stopping: it trails)
        pos_now  = Signal(signed(WORD)) # the count as a POS word (counts · 2^4), saturated
        lim = 1 << (WORD - 1 + POS.lsb)
        # the trailing target: clamp(q_d0, pos − E, pos + E), E = trail · 2^4 (a POS word);
        # the result lies between q_d0 and pos_now, so it needs no saturation. The tick
        # registers pos and pos ± E; the cycle after it writes the clamp into j_in.qd0 (the
        # engine, started by the tick, first reads an input two cycles after it: its ROM's
        # registered read, then stage R), so the count's saturation, the adders and the
        # compares are not one path (they were the node's slowest, 23 ns on ECP5)
        span = Signal(16 - POS.lsb)
        lo, hi = Signal(signed(WORD + 2)), Signal(signed(WORD + 2))
        pos_r = Signal(signed(WORD))
        first_r = Signal()              # the hold's first tick: the target is the count
        trail_due = Signal()            # the cycle after a stopping hold tick
        trailed = Signal(signed(WORD))
        qd0 = j_in.qd0
        m.d.comb += [
            span.eq(self.trail << -POS.lsb),
            trailed.eq(Mux(first_r, pos_r, Mux(qd0 < lo, lo, Mux(qd0 > hi, hi, qd0)))),
        ]
        m.d.sync += trail_due.eq(0)
        with m.If(trail_due):
            m.d.sync += j_in.qd0.eq(trailed)
        m.d.comb += [
            pos_now.eq(Mux(self.count >= lim, (1 << (WORD - 1)) - 1,
                           Mux(self.count < -lim, -(1 << (WORD - 1)),
                               self.count << -POS.lsb))),
            tick.eq(self.boundary | ((tick_cnt == 0) & ~self.tail)),
            tn.eq(self.ref_time + self.cycles),
            count24.eq(Mux(self.count > (1 << 23) - 1, (1 << 23) - 1,
                           Mux(self.count < -(1 << 23), -(1 << 23), self.count))),
        ]
        m.d.sync += tick_cnt.eq(Mux(tick, self.cycles - 1, tick_cnt - 1))
        with m.If(tick):
            with m.If(self.busy):
                with m.If(self.overruns != 0xFFFF):
                    m.d.sync += self.overruns.eq(self.overruns + 1)
            with m.Else():
                m.d.sync += [
                    j_in.q.eq(count24),
                    j_in.qd.eq(self.velocity),
                    j_in.tn.eq(Mux(tn > TIME_MAX, TIME_MAX, tn)),
                ]
                with m.If(self.hold):
                    m.d.sync += [
                        j_in.tauD.eq(0),
                        j_in.vd0.eq(0),
                        j_in.ad0.eq(0),
                    ]
                    with m.If(~hold_set):       # stopping: trails the count; kept from rest
                        m.d.sync += [
                            pos_r.eq(pos_now),
                            lo.eq(pos_now - span),
                            hi.eq(pos_now + span),
                            first_r.eq(~hold_run),
                            trail_due.eq(1),
                            hold_set.eq(self.rest),
                            hold_run.eq(1),
                        ]
                    m.d.comb += self.entry.eq(jmc.entries["pid"])
                with m.Else():
                    m.d.sync += [
                        j_in.tauD.eq(self.refs.tau),
                        j_in.qd0.eq(self.refs.qd0),
                        j_in.vd0.eq(self.refs.vd0),
                        j_in.ad0.eq(self.refs.ad0),
                    ]
                    m.d.comb += self.entry.eq(entries[self.mode])
                m.d.comb += self.start.eq(1)
        with m.If(~self.hold):
            m.d.sync += [
                hold_set.eq(0),
                hold_run.eq(0),
            ]

        # Host port: the ARM's integral clears first, then a PARAM word while idle.
        clear = self.clear_lo | self.clear_hi
        m.d.comb += self.words.ready.eq(~clear & ~self.busy)
        with m.If(clear):
            m.d.comb += [
                self.host_addr.eq(Mux(self.clear_lo, jmc.addr("ilo_s"), jmc.addr("ihi_s"))),
                self.host_wdata.eq(0),
                self.host_we.eq(1),
            ]
        with m.Elif(self.words.valid & self.words.ready):
            m.d.comb += [
                self.host_addr.eq(self.words.p.addr),
                self.host_wdata.eq(self.words.p.data),
                self.host_we.eq(1),
            ]
        return m
