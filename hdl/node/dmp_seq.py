"""When the primitive generator steps, and whose references the joint takes.

The joint-side motion primitive (:class:`~hdl.node.dmp.DmpGenerator`, docs/dmp.md) replaces
Comm D's ``q_d0, q̇_d0, q̈_d0`` while it is selected; Comm D's ``τ_D`` stays in use. CONFIG DMP
(:class:`~protocol.regs.DmpControl`) drives it:

* ``START``: the generator starts at once (it computes its first step from the primitive's
  start); the joint keeps Comm D's references until the next period boundary. There the
  generator's first step takes effect and the generator's references are selected; it then
  steps at every boundary and every DMP_STEP cycles after one (PERIOD is a multiple of
  DMP_STEP, the uploads check it), so the steps lie on the node's period grid, as Comm D's
  commit does, and every joint of a system steps in the same cycle. Under a disciplined
  timer (CONFIG TC_DISCIPLINE, a period of PERIOD + adj cycles) the grid is the nominal
  one: no step but the boundary's once the phase reaches PERIOD (``tail``), so a period
  has PERIOD / DMP_STEP steps whatever ``adj``, its last interval DMP_STEP + adj.
* ``STOP``: the generator stops; its references, still selected, hold the last position with
  zero velocity and acceleration.
* ``OFF``: the generator stops and Comm D's references are selected again.

Each step's references are for the cycle of the step strobe: the generator computed them
during the previous step and they take effect in the next cycle, when ``ref_time`` (cycles
since the strobe, the joint program's interpolation time) is 1 — as Comm D's references are
for their boundary. So a tick in the strobe's own cycle still uses the old references, the
next one the new, as at Comm D's commit point.
"""

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from .commit import TIME_MAX, sat_inc

__all__ = ["DmpTiming"]


class DmpTiming(wiring.Component):
    """Step strobes of the primitive generator and the reference selection (module docstring).

    Attributes
    ----------
    boundary : In(1)
        The period timer's boundary.
    tail : In(1)
        No step but the boundary's: the disciplined timer's phase is at or past PERIOD (the
        cycles a lengthened period adds, :class:`~hdl.node.timer.PeriodTimer`).
    gen_ready : In(1)
        The generator's next step is computed. A step strobe without it changes nothing here
        (the generator counts it): the references and their time run on, and a waiting
        generator starts at a later boundary.
    step_cycles : In(24)
        CONFIG DMP_STEP.
    off, start, stop : In(1)
        Strobes: CONFIG DMP = OFF, START, STOP.
    gen_start, gen_step, gen_stop : Out(1)
        Strobes to the generator.
    select : Out(1)
        The joint takes the generator's references (and Comm D's ``τ_D``).
    ref_time : Out(24)
        Cycles since the last step strobe, saturating at :data:`~hdl.node.commit.TIME_MAX`.
    """

    boundary:    In(1)
    tail:        In(1)
    gen_ready:   In(1)
    step_cycles: In(24)
    off:         In(1)
    start:       In(1)
    stop:        In(1)
    gen_start:   Out(1)
    gen_step:    Out(1)
    gen_stop:    Out(1)
    select:      Out(1)
    ref_time:    Out(24, init=TIME_MAX)

    def elaborate(self, platform):
        m = Module()
        waiting = Signal()          # started; the first step comes at the next boundary
        running = Signal()          # selected and stepping
        due = ((self.boundary & (waiting | running))
               | (running & (self.ref_time == self.step_cycles) & ~self.tail))
        m.d.comb += [
            self.gen_start.eq(self.start),
            self.gen_stop.eq(self.stop | self.off),
            self.gen_step.eq(due & ~self.start & ~self.off & ~self.stop),
        ]
        taken = self.gen_step & self.gen_ready
        m.d.sync += self.ref_time.eq(Mux(taken, 1, sat_inc(self.ref_time)))
        with m.If(self.start):
            m.d.sync += [waiting.eq(1), running.eq(0), self.select.eq(0)]
        with m.Elif(self.off):
            m.d.sync += [waiting.eq(0), running.eq(0), self.select.eq(0)]
        with m.Elif(self.stop):
            m.d.sync += [waiting.eq(0), running.eq(0)]
        with m.Elif(taken & waiting):
            m.d.sync += [waiting.eq(0), running.eq(1), self.select.eq(1)]
        return m
