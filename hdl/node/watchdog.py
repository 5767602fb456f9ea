"""Torque output stage: command limits, arming and the watchdog's safe state.

Behaviour, cycle by cycle, is specified by :mod:`.watchdog_ref` (the gateware equals it bit
for bit): a joint starts disarmed with zero torque; once armed it applies the joint
controller's commands clamped to the uploaded limits; when no valid packet has arrived for
``timeout`` cycles it trips, says so in its status, and ramps the torque to zero by ``ramp``
per control tick. Only a new ``arm`` (CONFIG) leaves the tripped state.
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
    torque : Out(signed(24))
    armed, tripped, safe : Out(1)
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
    torque:    Out(signed(WORD))
    armed:     Out(1)
    tripped:   Out(1)
    safe:      Out(1)

    def elaborate(self, platform):
        m = Module()
        silence = Signal(32)

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
        with m.If(self.armed & ~self.tripped & ~self.arm & ~self.disarm &
                  (silence >= self.timeout)):
            m.d.sync += self.tripped.eq(1)

        tau = self.torque
        # |τ| ≤ ramp without negating τ: τ ≤ ramp when positive, τ ≥ −ramp otherwise.
        small = Signal()
        m.d.comb += small.eq(Mux(tau > 0, tau <= self.ramp, tau >= -self.ramp))
        with m.If(~self.armed):
            m.d.sync += tau.eq(0)
        with m.Elif(self.tripped):
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
        m.d.comb += self.safe.eq(self.tripped & (tau == 0))
        return m
