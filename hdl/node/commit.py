"""Comm D's references: when they take effect and which time they are for.

``τ_D, q_d0, q̇_d0, q̈_d0`` of a full Comm D take effect together (docs/node.md "Timing"):

* while armed, at phase COMMIT of the node's period timer, so every joint changes its
  references on the same grid; one that arrives at or after COMMIT waits for the next commit
  point and is counted (``late_d`` in Comm A);
* while disarmed, at its last byte.

Its references are for the start of the period it arrived in: the control ticks count their
time from that boundary (``ref_time``), across the next boundary until the next commit, so a
commit point later than the boundary never sends the reference back a period.
"""

from amaranth import *
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.hdl.link.packet import PacketType

from .decoder import CommDWords, PacketEnd

__all__ = ["ReferenceCommit", "TIME_MAX", "sat_inc"]

#: Saturation of the times counted from a boundary (the joint program's TIME input).
TIME_MAX = (1 << 23) - 1


def sat_inc(v):
    """``v + 1``, saturating at :data:`TIME_MAX`."""
    return Mux(v >= TIME_MAX, TIME_MAX, v + 1)


class ReferenceCommit(wiring.Component):
    """Hold Comm D's references and commit them (see the module docstring).

    Attributes
    ----------
    ends : In(stream.Signature(PacketEnd, always_ready=True))
        Packet ends (from :class:`~hdl.node.decoder.PacketDecoder`); a full Comm D's counts.
    comm_d : In(CommDWords)
        The Comm D words received (valid at its end).
    armed : In(1)
        The watchdog is armed.
    phase, elapsed : In(24)
        The period timer's phase and the cycles since its boundary.
    commit : In(24)
        CONFIG COMMIT: the commit phase.
    refs : Out(CommDWords)
        The references in effect.
    ref_time : Out(24)
        Cycles since the boundary ``refs`` are for, saturating at :data:`TIME_MAX`.
    late_d : Out(16)
        Comm D packets that arrived armed at or after the commit phase, saturating.
    committed : Out(1)
        Strobe: ``refs`` take new words (a commit point with one pending, or an arrival while
        disarmed).
    """

    ends:      In(stream.Signature(PacketEnd, always_ready=True))
    comm_d:    In(CommDWords)
    armed:     In(1)
    phase:     In(24)
    elapsed:   In(24)
    commit:    In(24)
    refs:      Out(CommDWords)
    ref_time:  Out(24)
    late_d:    Out(16)
    committed: Out(1)

    def elaborate(self, platform):
        m = Module()
        pend_time = Signal(24)          # cycles since the boundary of the pending Comm D
        pending   = Signal(CommDWords)  # the Comm D waiting for the commit point
        is_pending = Signal()
        arrive    = Signal()            # a full Comm D arrives while armed
        disarmed  = Signal()            # a full Comm D arrives while disarmed
        at_commit = self.phase == self.commit
        full_d = (self.ends.valid & (self.ends.p.type == PacketType.COMM_D) & self.ends.p.full)
        m.d.comb += [
            arrive.eq(full_d & self.armed),
            disarmed.eq(full_d & ~self.armed),
        ]

        m.d.sync += [
            self.ref_time.eq(sat_inc(self.ref_time)),
            pend_time.eq(sat_inc(pend_time)),
        ]
        with m.If(arrive):
            m.d.sync += [
                pending.eq(self.comm_d),
                pend_time.eq(sat_inc(self.elapsed)),
            ]
        with m.If(disarmed):
            m.d.sync += [
                self.refs.eq(self.comm_d),
                self.ref_time.eq(sat_inc(self.elapsed)),
            ]
        with m.If(at_commit):
            with m.If(is_pending):
                m.d.sync += [
                    self.refs.eq(pending),
                    self.ref_time.eq(sat_inc(pend_time)),
                ]
            m.d.sync += is_pending.eq(arrive)
        with m.Elif(arrive):
            m.d.sync += is_pending.eq(1)
        with m.If(arrive & (self.phase >= self.commit) & (self.late_d != 0xFFFF)):
            m.d.sync += self.late_d.eq(self.late_d + 1)
        m.d.comb += self.committed.eq((at_commit & is_pending) | disarmed)
        return m
