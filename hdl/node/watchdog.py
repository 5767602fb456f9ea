"""Torque output stage: command limits, arming, the watchdog and its safe stop.

# Ref: IEC 61800-5-2:2016 §4.2.2: SS1 (stop, then STO; here the brake at monitored
# standstill, SS1-t's time limit as a fallback), SS2 (stop, then standstill held by the
# drive), STO (safe torque off).

Behaviour, cycle by cycle, is specified by :mod:`.watchdog_ref` (the gateware equals it bit
for bit): a joint starts disarmed with zero torque; once armed it applies the joint
controller's commands clamped to the uploaded limits; when no valid packet has arrived for
``timeout`` cycles it trips, says so in its status, and runs the safe stop: it still applies
the joint engine's commands, which first stop the joint and then hold it still (``holding``:
the core runs the engine's PID on node-local references, their target following the count
until ``rest``, then frozen: the joint is held where it came to rest); it asserts ``brake``
once the joint is at standstill (the encoder velocity within ±``standstill`` at
``standstill_ticks`` consecutive ticks; the brake from the cycle after the last of them) or
at the latest ``stop_cycles`` into the trip (the stop's time limit, SS1-t as a fallback,
flagged by ``limit``); it keeps holding for ``brake_cycles`` cycles from the brake's first
cycle, then ramps the torque to zero by ``ramp`` per control tick (STO). ``standstill`` = 0
turns the standstill rule off: the brake ``stop_cycles`` into the trip, exactly the fixed
timer. Only a new ``arm`` (CONFIG) leaves the tripped state and releases the brake; a disarm
while tripped engages the brake at once.
"""

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.fixed import WORD

__all__ = ["Watchdog"]


class Watchdog(wiring.Component):
    """See the module docstring.

    Attributes
    ----------
    packet, tick, cmd_valid, arm, disarm : In(1)
        One-cycle pulses.
    cmd : In(signed(24))
        Torque command (FORCE), taken on ``cmd_valid``.
    timeout : In(32)
        Silence that trips the watchdog, cycles.
    ramp : In(WORD)
        Torque decrement per tick in the tripped state (FORCE LSBs, unsigned).
    tau_min, tau_max : In(signed(24))
        Command limits (FORCE).
    stop_cycles, brake_cycles : In(24)
        The safe stop's time limit before the brake, and hold with the brake engaged, cycles
        (24 bits: 0.336 s at 50 MHz; CONFIG ignores larger values).
    velocity : In(signed(24))
        The encoder's velocity word, read at each ``tick`` (the joint engine's sample).
    standstill : In(24)
        Standstill threshold (VEL LSBs, unsigned; 0: no standstill rule).
    standstill_ticks : In(16)
        Consecutive ticks within the threshold that make a standstill (0 counts as 1).
    torque : Out(signed(24))
    armed, tripped, safe : Out(1)
        ``safe``: tripped, past the hold (STO) and the torque zero.
    holding : Out(1)
        Armed, tripped and within the hold (until ``brake_cycles`` cycles after the brake's
        first cycle): the joint engine holds the joint.
    brake : Out(1)
        Tripped and either the brake engaged (standstill or ``stop_cycles`` into the trip) or
        disarmed: engage the brake.
    limit : Out(1)
        Tripped, the brake engaged at the time limit and the standstill rule on: the joint
        was not seen at standstill within ``stop_cycles`` (status bit STOP_LIMIT).
    rest : Out(1)
        The joint is at rest for the hold (combinational, read by the control ticks at a
        hold tick): the standstill rule off, ``velocity`` within ±``standstill``, or the
        brake engaged (or at the time limit). Until a hold tick finds it set, the hold's
        target follows the encoder count (the stop); from then on it is frozen.
    """

    packet:    In(1)
    tick:      In(1)
    cmd_valid: In(1)
    cmd:       In(signed(WORD))
    arm:       In(1)
    disarm:    In(1)
    timeout:   In(32)
    ramp:      In(WORD)
    tau_min:   In(signed(WORD))
    tau_max:   In(signed(WORD))
    stop_cycles:  In(24)
    brake_cycles: In(24)
    velocity:  In(signed(WORD))
    standstill: In(WORD)
    standstill_ticks: In(16)
    torque:    Out(signed(WORD))
    armed:     Out(1)
    tripped:   Out(1)
    safe:      Out(1)
    holding:   Out(1)
    brake:     Out(1)
    limit:     Out(1)
    rest:      Out(1)

    def elaborate(self, platform):
        m = Module()
        silence = Signal(32)
        # cycles since the trip (0 in the first tripped cycle) until the brake engages, then
        # cycles since the brake's first cycle (one counter for both phases; as wide as the
        # 24-bit timers it is compared with, saturating)
        since   = Signal(24)
        braked  = Signal()              # the brake engaged in this trip
        by_limit = Signal()             # ... at the time limit
        run     = Signal(16)            # consecutive ticks at standstill so far

        with m.If(self.disarm):
            m.d.sync += self.armed.eq(0)
        with m.Elif(self.arm):
            m.d.sync += [
                self.armed.eq(1),
                self.tripped.eq(0),
            ]
        with m.If(self.arm | self.packet):
            m.d.sync += silence.eq(0)
        with m.Elif(silence != (1 << 32) - 1):
            m.d.sync += silence.eq(silence + 1)

        # |v| ≤ standstill, as for the torque below (v ≤ T when positive, v ≥ −T otherwise)
        v, thr = self.velocity, self.standstill
        still = Signal()
        at_limit = Signal()             # the stop's time limit, in its first cycle
        m.d.comb += [
            still.eq((thr != 0) & Mux(v > 0, v <= thr, v >= -thr)),
            at_limit.eq(~braked & (since >= self.stop_cycles)),
        ]
        with m.If(self.armed & ~self.tripped & ~self.arm & ~self.disarm &
                  (silence >= self.timeout)):
            m.d.sync += [
                self.tripped.eq(1),
                since.eq(0),
                braked.eq(0),
                by_limit.eq(0),
                run.eq(0),
            ]
        with m.Elif(self.tripped):
            with m.If(at_limit):                        # SS1-t: the brake from this cycle
                m.d.sync += [
                    braked.eq(1),
                    by_limit.eq(1),
                    since.eq(1),
                ]
            with m.Elif(~braked & self.tick & still &
                        (run + 1 >= self.standstill_ticks)):   # standstill: from the next
                m.d.sync += [
                    braked.eq(1),
                    since.eq(0),
                ]
            with m.Else():
                with m.If(since != (1 << 24) - 1):
                    m.d.sync += since.eq(since + 1)
                with m.If(~braked & self.tick):
                    m.d.sync += run.eq(Mux(still, run + 1, 0))
        m.d.comb += [
            self.holding.eq(self.armed & self.tripped &
                            Mux(braked, since < self.brake_cycles,
                                ~at_limit | (self.brake_cycles != 0))),
            self.brake.eq(self.tripped & (braked | at_limit | ~self.armed)),
            self.limit.eq(self.tripped & (by_limit | at_limit) & (thr != 0)),
            self.rest.eq((thr == 0) | still | braked | at_limit),
        ]

        tau = self.torque
        # |τ| ≤ ramp without negating τ: τ ≤ ramp when positive, τ ≥ −ramp otherwise.
        small = Signal()
        m.d.comb += small.eq(Mux(tau > 0, tau <= self.ramp, tau >= -self.ramp))
        with m.If(~self.armed):
            m.d.sync += tau.eq(0)
        with m.Elif(self.tripped & ~self.holding):          # STO: ramp to zero
            with m.If(self.tick):
                with m.If(small):
                    m.d.sync += tau.eq(0)
                with m.Elif(tau > 0):
                    m.d.sync += tau.eq(tau - self.ramp)
                with m.Else():
                    m.d.sync += tau.eq(tau + self.ramp)
        with m.Elif(self.cmd_valid):
            with m.If(self.cmd < self.tau_min):
                m.d.sync += tau.eq(self.tau_min)
            with m.Elif(self.cmd > self.tau_max):
                m.d.sync += tau.eq(self.tau_max)
            with m.Else():
                m.d.sync += tau.eq(self.cmd)
        m.d.comb += self.safe.eq(self.tripped & ~self.holding & (tau == 0))
        return m
