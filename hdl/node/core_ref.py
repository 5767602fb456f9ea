"""Transaction-level reference of the node core (:class:`~hdl.node.core.NodeCore`).

It composes the block references: :class:`~hdl.node.vdc_ref.VdcModel`,
:class:`~hdl.node.joint_ref.JointModel`, :mod:`~hdl.node.trig_ref` and the watchdog rules of
:mod:`~hdl.node.watchdog_ref`, driven by events with their clock cycle. The encoder is not in
it: callers give a ``sample(cycle) -> (count, velocity, errors)`` function, the encoder
interface's outputs in that cycle (the gateware's, or those of its reference
:class:`~hdl.node.encoder_ref.EncoderModel`). It is fast enough to stand in for the gateware in
long runs (the ``model`` backend, :mod:`cosim.model`).

Internal events follow the node's period timer (free-running from reset, phase 0 = boundary):

* boundary (phase 0, or a time-code outside the sync window; with CONFIG TC_DISCIPLINE on, the
  period is ``PERIOD + adj`` cycles, ``adj`` set by the last in-window time-code,
  :mod:`~mrm_cosim.protocol.discipline`): snapshot of everything the
  Comm A reply carries (count, velocity, torque, status, encoder errors, counters), CORDIC of
  the count; an ARM whose record acted before the previous cycle (its last byte three or more
  cycles before) takes effect here (PID integral cleared);
* control ticks every ``TICK`` cycles from each boundary (with the discipline on, none within
  ``TICK`` cycles before the next boundary); a tick's command lands
  ``cycles(mode)`` cycles later (:meth:`~mrm_cosim.protocol.isa.Microcode.cycles`), then the
  limits and the watchdog apply;
* commit point (phase ``COMMIT``): an armed node's last full Comm D becomes the joint
  engine's input (disarmed: at its last byte);
* the safe stop after a watchdog trip (IEC 61800-5-2 SS1 at monitored standstill, SS1-t as
  the time limit; docs/node.md "Safe stop", :mod:`~hdl.node.watchdog_ref`): the ticks run
  the PID entry on node-local references (while the joint stops the first hold tick's count,
  then at each tick the last target clamped to within ±STOP_TRAIL counts of the tick's count,
  frozen at the first hold tick with the joint at rest, :meth:`NodeModel._at_rest`; zero velocity,
  acceleration and ``τ_D``) and their commands land; the brake from the cycle after the tick
  that completes STANDSTILL_TICKS consecutive ticks with the velocity within ±STANDSTILL
  (≠ 0), at the latest STOP_CYCLES after the trip; the hold for BRAKE_CYCLES from the
  brake's first cycle; then the ramp to zero (STO);
* steps of the primitive generator (:class:`~hdl.node.dmp_ref.DmpGeneratorModel`, CONFIG DMP,
  :mod:`~hdl.node.dmp_seq`): at every boundary and DMP_STEP cycles after the last step
  taken while it runs (a strobe that finds the references not ready does not move that
  grid; with the loop on, only at phases below PERIOD: a lengthened period's last interval
  is DMP_STEP + adj, not a step just before the boundary's own); while it is selected its
  references replace Comm D's (``τ_D`` stays Comm D's) and their time counts from the step.

External events: :meth:`timecode` at the strobe's cycle, :meth:`packet` at the cycle its last
byte is taken. Within one cycle, internal events come first (they see the registers as they were
before the cycle, as the packet does). A CONFIG packet's records act one cycle after its last
byte (the gateware holds the decoder's record in a register before the CONFIG block, so that
the period timer's thresholds are formed from registers; docs/node.md "Clock"): the model
keeps them pending and applies them in that cycle, after its internal events and after a
time-code in it.

Observation port. With :attr:`NodeModel.events` a list, the model appends ``(cycle, NodeEvent)``
for every strobe of the gateware's ``events`` port
(:class:`~mrm_cosim.protocol.regs.NodeEvent`), not necessarily in cycle order: boundaries,
resyncs, time-codes, packets taken and commits when they happen; the VDC's start one cycle after
the Comm B (the engine is idle then: a Comm B follows the boundary's CORDIC), its MARK and END
:meth:`~mrm_cosim.protocol.isa.Microcode.mark_cycles` and
:meth:`~mrm_cosim.protocol.isa.Microcode.cycles` after that; a reply leaving the cycle after its
request (Comm C: after the request and the MARK), which assumes the reply FSM is idle, i.e. the
previous reply has left (in the A/B/C/D cycle they are tens of µs apart).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache

from mrm_cosim.hdl.link.codec_ref import saturating_sum_ref
from mrm_cosim.protocol.crc import CRC16_INIT, crc16
from mrm_cosim.protocol.discipline import WORD_BITS as DISCIPLINE_BITS
from mrm_cosim.protocol.discipline import (LATENCY, Discipline, arrival, loop_step,
                                           period_length)
from mrm_cosim.protocol.encoder import EncoderParams
from mrm_cosim.protocol.fixed import POS, saturate
from mrm_cosim.protocol.joint_program import MODES as JOINT_MODES
from mrm_cosim.protocol.joint_program import JointParams, joint_microcode
from mrm_cosim.protocol.link import ERROR_CLASSES
from mrm_cosim.protocol.packet import PacketType
from mrm_cosim.protocol.regs import (COMM_B_WORDS, COMM_D_WORDS, CONFIG_DEFAULTS, PAYLOAD,
                                     RX_DROPS, Bank, Config, DmpControl, Status, pack_words,
                                     unpack_words)
from mrm_cosim.protocol.regs import NodeEvent as Ev
from mrm_cosim.protocol.vdc_program import VdcParams, vdc_microcode

from .dmp_ref import DmpGeneratorModel
from .joint_ref import JointInputs, JointModel
from .trig_ref import sin_cos
from .vdc_ref import VdcInputs, VdcModel

__all__ = ["NodeModel"]

_TIME_MAX = (1 << 23) - 1
_NEVER = 1 << 62
(_ST_ARMED, _ST_TRIPPED, _ST_SAFE, _ST_FRESH, _ST_PRIME, _ST_DMP, _ST_HOLD, _ST_BRAKE,
 _ST_STOP_LIMIT) = (int(b) for b in (Status.ARMED, Status.TRIPPED, Status.SAFE, Status.FRESH,
                                     Status.PRIME, Status.DMP, Status.HOLD, Status.BRAKE,
                                     Status.STOP_LIMIT))
_CFG_MODE = Config.MODE
_CFG_TC = Config.TC_DISCIPLINE


@cache
def _vdc_timing(entry: str) -> tuple[int, int]:
    """``(mark_cycles, cycles)`` of the VDC program's entry point: properties of the ROM
    (:func:`~mrm_cosim.protocol.vdc_program.vdc_microcode`, built once), scanned once per
    entry instead of on every Comm B."""
    mc = vdc_microcode()
    return mc.mark_cycles(entry), mc.cycles(entry)


def _zero_vdc() -> VdcModel:
    z13, z6 = [[0] * 13, [0] * 13], [[0] * 6, [0] * 6]
    return VdcModel(VdcParams(K=z6, rho_T=[r[:] for r in z13], lower=[r[:] for r in z13],
                              upper=[r[:] for r in z13], inv_T=0), [r[:] for r in z13])


@dataclass
class NodeModel:
    """State of one node core at transaction level (see the module docstring).

    Attributes
    ----------
    vdc : VdcModel
    joint : JointModel
    config : dict of Config to int
    d_words : list of 4 int
        The words the joint engine takes: ``τ_D`` (Comm D's) and ``q_d0, q̇_d0, q̈_d0`` (Comm
        D's, or the primitive generator's while it is selected); ``d_base`` the cycle their
        time counts from.
    cd_words : list of 4 int
        Committed Comm D words ``τ_D, q_d0, q̇_d0, q̈_d0`` (``cd_base``: the boundary they are
        for).
    dmp : DmpGeneratorModel
        The primitive generator; ``dmp_select`` whether its references are in use,
        ``dmp_waiting`` started and waiting for the boundary of its first step,
        ``dmp_running`` stepping; its ``overruns`` count the steps that found the next one not
        ready.
    d_next : list of 4 int
        The last full Comm D received while armed, waiting for the commit point.
    g_words : list of 3 int
    forces : list of 12 int
        FORCE words of the last VDC run (Link a, then Link b): what Comm C returns.
    boundaries : list of int
        Cycles of every period boundary so far (resynchronisations included).
    sync_errors, late_d : int
        Time-codes outside the window while armed; Comm D packets after the commit phase.
    upload_crc, upload_count : int
        CRC-16/CCITT-FALSE of the payload bytes of every CONFIG and PARAM packet since reset,
        in arrival order (0xFFFF before the first), and their number modulo 2^16.
    link_health : tuple of 4 int
        What the next Comm A reports of the link (:meth:`set_link`): the upstream and
        downstream codecs' error totals, frames dropped by the depacketizer, packets
        discarded by the router.
    events : list of (int, NodeEvent) or None
        The observation port's strobes ``(cycle, flag)`` (module docstring); None: not kept.
    presets : list of (int, int)
        Every CONFIG PRESET (homing) taken, ``(cycle, count)``: the encoder interface (the
        caller's) loads the count then (``EncoderModel.cycle(..., preset=count)``).
    trip_cycle : int
        First cycle of the last watchdog trip (``tripped`` visible).
    hold_pos : int or None
        The safe stop's hold position (POS word): the first hold tick's count, then at each
        hold tick the last one clamped to within ±STOP_TRAIL counts of the tick's count, until
        a tick finds the joint at rest (``hold_fixed``), then frozen; None before the first
        hold tick.
    still_cycle : int or None
        The brake's first cycle when the standstill rule engaged it in the last trip (the cycle
        after the tick that completed the standstill); None otherwise.
    still_run : int
        Consecutive ticks at standstill so far in the last trip.
    encoder_preset : callable or None
        ``encoder_preset(cycle, count)``, called for each PRESET: the caller's encoder
        interface (``cosim.model`` attaches its own). None: the caller applies
        :attr:`presets` to what its ``sample`` returns itself.
    """

    encoder: EncoderParams = field(default_factory=EncoderParams)
    vdc: VdcModel = field(default_factory=_zero_vdc)
    joint: JointModel = field(default_factory=lambda: JointModel(JointParams.zero()))
    config: dict = field(default_factory=lambda: dict(CONFIG_DEFAULTS))
    d_words: list = field(default_factory=lambda: [0, 0, 0, 0])
    d_next: list = field(default_factory=lambda: [0, 0, 0, 0])
    d_pending: bool = False
    d_base: int = 0                       # cycle the joint's references are for
    cd_words: list = field(default_factory=lambda: [0, 0, 0, 0])
    cd_base: int = 0                      # boundary the committed Comm D words are for
    dmp: DmpGeneratorModel = field(default_factory=DmpGeneratorModel)
    dmp_select: bool = False
    dmp_waiting: bool = False
    dmp_running: bool = False
    _dmp_due: int = _NEVER                # the next step strobe inside this period
    _dmp_hold: int = -1                   # a CONFIG DMP's cycle: no step strobe in it
    d_next_base: int = 0                  # boundary of the pending Comm D's arrival period
    g_words: list = field(default_factory=lambda: [0, 0, 0])
    b_words: list = field(default_factory=lambda: [0] * 13)
    snap_count: int = 0
    snap_qd: int = 0
    cos_q: int = 0
    sin_q: int = 0
    prime: bool = True
    fresh: bool = False
    armed: bool = False
    tripped: bool = False
    trip_cycle: int = 0
    hold_pos: int | None = None
    hold_fixed: bool = False
    still_cycle: int | None = None
    still_run: int = 0
    _now: int = 0                         # the cycle of the last _watch (for status)
    arm_pending: bool = False
    arming: bool = False
    torque: int = 0
    last_packet: int = 0
    overruns: int = 0
    sync_errors: int = 0
    late_d: int = 0
    upload_crc: int = CRC16_INIT
    upload_count: int = 0
    link_health: tuple = (0, 0, 0, 0)
    tc_value: int = 0
    forces: list = field(default_factory=lambda: [0] * 12)
    boundaries: list = field(default_factory=list)
    events: list | None = None
    presets: list = field(default_factory=list)
    encoder_preset: object = None
    _vdc_mark: int = -1                   # cycle of the last VDC run's MARK (observation port)
    _snap: tuple = (0, 0, 0, 0, 0, 0)     # torque, status, errors, overruns, sync, late
    _busy_until: int = -1
    _started: int = -1
    _landing: tuple | None = None
    _done: int = 0                        # internal events at cycles < _done are processed
    _lb: int = 0                          # last boundary
    _nb: int = 0                          # next boundary
    _nt: int = 0                          # next regular tick
    _commit_seen: int = -1                # boundary whose commit point has passed
    _prime_due: int | None = None
    _pre_seen: int = -1                   # boundary whose previous cycle was examined
    _sample: object = None
    tc_loop: tuple = (0, 0, 0)            # the discipline's rate f, fraction a, adjustment adj
    _tc_pending: tuple | None = None      # a loop step under way: (first cycle, new tc_loop)
    _cfg_pending: list = field(default_factory=list)    # [(cycle, [(reg, value), …])]: CONFIG
    #                                                     records not yet applied, in order

    # --- internal events ----------------------------------------------------------------------
    def phase(self, now: int) -> int:
        """Phase of the period timer in cycle ``now`` (internal events before it processed)."""
        return 0 if now >= self._nb else now - self._lb

    def next_boundary(self) -> int:
        return self._nb

    def run(self, until: int, sample=None) -> None:
        """Process the internal events (boundaries, ticks, commit points) of cycles < ``until``,
        and the CONFIG records that act before it (each after its cycle's internal events).

        ``sample(cycle) -> (count, velocity, errors)``: the encoder interface's outputs.
        """
        if sample is not None:
            self._sample = sample
        sample = self._sample or (lambda c: (0, 0, 0))
        pending = self._cfg_pending
        while pending and pending[0][0] < until:
            c, recs = pending.pop(0)
            self._run_events(c + 1, sample)
            for reg, value in recs:
                self._config(c, reg, value)
        self._run_events(until, sample)

    def _run_events(self, until: int, sample) -> None:
        """:meth:`run`'s internal events of cycles < ``until``."""
        cfg = self.config
        while True:
            nb = self._nb
            commit = self._lb + cfg[Config.COMMIT] if self._commit_seen != self._lb else _NEVER
            if commit >= nb:
                commit = _NEVER
            pre = nb - 1 if self.arm_pending and self._pre_seen != nb else _NEVER
            ds = self._dmp_due if self.dmp_running and self._dmp_due < nb else _NEVER
            if ds != _NEVER and cfg[_CFG_TC] and self._disciplined and \
                    ds - self._lb >= cfg[Config.PERIOD]:
                ds = _NEVER                     # past the nominal period: the boundary steps
            nt = self._nt
            tp = self._tc_pending
            if cfg[_CFG_TC] and self._disciplined:
                adj = tp[1][2] if tp is not None and nt >= tp[0] else self.tc_loop[2]
                if nt + cfg[Config.TICK] > self._lb + cfg[Config.PERIOD] + adj:
                    nt = _NEVER                 # the disciplined period's tail: no tick
            c = min(nb, nt, commit, pre, ds)
            if tp is not None and tp[0] <= c and tp[0] < until:
                if nt == _NEVER and self._nt < tp[0]:
                    # the tail took that tick in its cycle, under the adj then: the gateware's
                    # tick counter has run out, and a new adj cannot bring it back
                    self._nt = _NEVER
                self._tc_apply(tp[0])           # the loop's step applies before its cycle
                continue
            if c >= until:
                break
            if c == pre:
                self._pre_seen = nb
                if c == self._started or c >= self._busy_until:    # engine idle: clear I_lo
                    self.joint.i_lo = 0
                    self.arm_pending = False
                    self.arming = True
                if c != min(nb, nt, commit, ds):
                    continue
            if c == nb:
                self._boundary(c, sample)
            elif c == nt:
                self._tick(c, sample, c - self.d_base)
            if c == commit:
                self._commit_seen = self._lb
                if self.d_pending and self.events is not None:
                    self.events.append((c, Ev.COMMIT))
                if self.d_pending:
                    self._take_d(self.d_next, self.d_next_base)
                    self.d_pending = False
            if c == ds:
                self._dmp_step(c)
        self._done = max(self._done, until)

    def config_due(self) -> int:
        """The cycle in which the next pending CONFIG record acts (a large number: none)."""
        return self._cfg_pending[0][0] if self._cfg_pending else _NEVER

    def _take_d(self, words, base: int) -> None:
        """Comm D's words ``words`` (for boundary ``base``) take effect: all four, or only
        ``τ_D`` while the generator's references are selected."""
        self.cd_words, self.cd_base = list(words), base
        if self.dmp_select:
            self.d_words[0] = words[0]
        else:
            self.d_words, self.d_base = list(words), base

    def _dmp_step(self, c: int) -> None:
        """A step strobe of the generator in cycle ``c`` (after that cycle's tick): its
        precomputed references take effect for cycle ``c`` and it computes the next step.
        One that finds the next step not ready changes nothing here (the generator counts
        it; a waiting generator then starts at a later boundary)."""
        if c == self._dmp_hold:                 # CONFIG DMP in this cycle wins
            return
        if self.events is not None:
            self.events.append((c, Ev.DMP_STEP))
        out = self.dmp.step(c)
        if out is None:
            # Its time runs on from the last step taken: a grid step still ahead of this strobe
            # (a boundary's, off the grid after a resync) comes as due; one missed at the grid
            # point leaves the next boundary to step.
            if c >= self._dmp_due:
                self._dmp_due = _NEVER
            return
        if self.dmp_waiting:
            self.dmp_waiting, self.dmp_running, self.dmp_select = False, True, True
        self.d_base = c
        self.d_words = [self.d_words[0], *out]
        self._dmp_due = c + self.config[Config.DMP_STEP]

    def _boundary(self, c: int, sample, resync: bool = False) -> None:
        self._watch(c)
        count, qd, errors = sample(c)
        if resync and self.armed:                       # a resync reports itself
            self.sync_errors = min(self.sync_errors + 1, 0xFFFF)
        self._snap = (self.torque, int(self.status), errors, self.overruns, self.sync_errors,
                      self.late_d)
        self.snap_count, self.snap_qd = count, qd
        self.cos_q, self.sin_q = sin_cos(count, self.encoder.counts_per_rev)
        self.fresh = False
        self._lb = c
        if resync and self._disciplined:   # the arrival counts as phase `target` (acquisition)
            self._lb = c - Discipline.from_word(self.config[Config.TC_DISCIPLINE]).target
        self._nb = self._lb + self._period_len()
        self.boundaries.append(c)
        if self.events is not None:
            self.events.append((c, Ev.BOUNDARY))
            if resync:
                self.events.append((c, Ev.RESYNC))
        arm = self.arming
        hold = self.holding_at(c)               # the watchdog's, before the ARM takes effect
        if arm and self.armed and self.tripped and not hold:
            self._ramp()
        if arm:
            self.arming = False
            self.joint.i_hi = 0
            self.armed, self.tripped, self.prime = True, False, True
            self.last_packet = c
        self._tick(c, sample, c - self.d_base, ramped=arm, hold=hold)
        if self.dmp_waiting or self.dmp_running:
            self._dmp_step(c)

    @property
    def _disciplined(self) -> bool:
        return Discipline.from_word(self.config[Config.TC_DISCIPLINE]).enable

    def _period_len(self) -> int:
        """Cycles of a period starting now: PERIOD, with the discipline's adjustment."""
        return period_length(self.config[Config.PERIOD], self.tc_loop[2])

    def _tc_apply(self, now: int) -> None:
        """The loop's step under way applies if its first cycle is ``now`` or before (the
        timer compares with its ``adj`` from that cycle)."""
        tp = self._tc_pending
        if tp is not None and tp[0] <= now:
            self._tc_pending = None
            self.tc_loop = tp[1]
            self._relength(tp[0] - 1)

    def _relength(self, now: int) -> None:
        """The period's length changed in cycle ``now`` (the timer compares with it from
        ``now + 1``)."""
        if now + 1 < self._nb:
            self._nb = max(self._lb + self._period_len(), now + 2)

    def _ramp(self) -> None:
        ramp = self.config[Config.RAMP]
        self.torque = 0 if abs(self.torque) <= ramp else \
            self.torque - ramp if self.torque > 0 else self.torque + ramp

    def engage_cycle(self, trip: int | None = None) -> int:
        """The brake's first cycle in the trip at ``trip`` (None: the last trip): the
        standstill's, or the time limit, STOP_CYCLES after the trip, whichever comes first."""
        limit = (self.trip_cycle if trip is None else trip) + self.config[Config.STOP_CYCLES]
        if trip is None and self.still_cycle is not None and self.still_cycle <= limit:
            return self.still_cycle
        return limit

    def holding_at(self, c: int) -> bool:
        """The safe stop holds the joint in cycle ``c`` (armed, tripped, fewer than
        BRAKE_CYCLES cycles after the brake's first cycle; :meth:`_watch` up to ``c`` done)."""
        return (self.armed and self.tripped
                and c < self.engage_cycle() + self.config[Config.BRAKE_CYCLES])

    def brake_at(self, c: int) -> bool:
        """The ``brake`` output in cycle ``c``: tripped and the brake engaged (standstill, or
        STOP_CYCLES into the trip), or tripped and disarmed (:meth:`_watch` up to ``c``
        done)."""
        return self.tripped and (c >= self.engage_cycle() or not self.armed)

    def stop_limit_at(self, c: int) -> bool:
        """Status STOP_LIMIT in cycle ``c``: tripped, the brake engaged at the time limit (no
        standstill seen before it), the standstill rule on."""
        return (self.tripped and self.config[Config.STANDSTILL] != 0 and self.still_cycle is None
                and c >= self.engage_cycle())

    def _standstill(self, now: int, qd: int) -> None:
        """The tick at ``now`` with the velocity word ``qd``: the standstill count of a trip
        whose brake has not engaged (the time limit not reached)."""
        if not self.tripped or self.still_cycle is not None or now >= self.engage_cycle():
            return
        thr = self.config[Config.STANDSTILL]
        if thr != 0 and abs(qd) <= thr:
            if self.still_run + 1 >= self.config[Config.STANDSTILL_TICKS]:
                self.still_cycle = now + 1
            else:
                self.still_run += 1
        else:
            self.still_run = 0

    def _at_rest(self, now: int, qd: int) -> bool:
        """The hold tick at ``now`` with the velocity word ``qd`` freezes the hold's target
        (the count it takes): the standstill rule off (the first hold tick, a step to the
        count there), the velocity within ±STANDSTILL (the joint at rest), or the brake on
        in this cycle (standstill reached or the stop's time limit)."""
        thr = self.config[Config.STANDSTILL]
        return thr == 0 or abs(qd) <= thr or now >= self.engage_cycle()

    def _sto_at(self, c: int) -> bool:
        """Tripped by cycle ``c`` (the trip predicted if not seen yet) and not holding: the
        watchdog ignores the engine's commands (STO's ramp)."""
        cfg = self.config
        if self.tripped:
            engage = self.engage_cycle()
        else:
            trip = self.last_packet + 2 + cfg[Config.TIMEOUT]
            if not (self.armed and c >= trip):
                return False
            engage = self.engage_cycle(trip)
        return not (self.armed and c < engage + cfg[Config.BRAKE_CYCLES])

    def _tick(self, now: int, sample, tt: int, ramped: bool = False,
              hold: bool | None = None) -> None:
        """Control tick at cycle ``now``, ``tt`` cycles after the period boundary the
        committed references are for (the boundary of the period their Comm D arrived in).
        ``hold``: whether the safe stop holds in this cycle (None: from the state)."""
        self._watch(now)
        if hold is None:
            hold = self.holding_at(now)
        tick = self.config[Config.TICK]
        self._nt = now + tick
        if self.armed and self.tripped and not ramped and not hold:
            self._ramp()
        count, qd, _ = sample(now)              # every tick strobes the velocity estimator
        self._standstill(now, qd)
        if now < self._busy_until:
            self.overruns = min(self.overruns + 1, 0xFFFF)
            return
        tt = min(tt, _TIME_MAX)
        if hold:                                # the safe stop's PID on node-local references
            if not self.hold_fixed:             # stopping: the target trails the count
                pos = saturate(count << -POS.lsb)
                if self.hold_pos is None:       # the first hold tick: the count
                    self.hold_pos = pos
                else:                           # then within ±STOP_TRAIL counts of it
                    span = self.config[Config.STOP_TRAIL] << -POS.lsb
                    self.hold_pos = min(max(self.hold_pos, pos - span), pos + span)
                self.hold_fixed = self._at_rest(now, qd)
            mode = "pid"
            refs = (0, self.hold_pos, 0, 0)
        else:
            mode = JOINT_MODES[self.config[Config.MODE]]
            refs = self.d_words
        x = JointInputs(q=saturate(count), qd=qd, tn=min(tt + tick, _TIME_MAX),
                        tau_D=refs[0], qd0=refs[1], vd0=refs[2], ad0=refs[3])
        tau, _, _ = self.joint.tick(mode, x)
        cycles = joint_microcode(self.joint.params.pid_shift).cycles(mode)
        self._started = now
        self._busy_until = now + cycles + 1
        done = now + cycles
        if not self.armed:
            self._landing = (done + 1, 0)
        elif not self._sto_at(done):            # visible from the cycle after the command
            self._landing = (done + 1, min(max(tau, self.config[Config.TAU_MIN]),
                                           self.config[Config.TAU_MAX]))

    def torque_at(self, now: int) -> int:
        """Torque word output in cycle ``now`` (internal events up to ``now`` processed, none
        after it)."""
        self._watch(now)
        return self.torque

    # --- external events ----------------------------------------------------------------------
    def timecode(self, now: int, value: int, sample=None) -> bool:
        """Time-code strobe in cycle ``now`` with time ``value``; returns whether it
        re-synchronised the timer (arrival phase outside ``[0, SYNC_WINDOW)``)."""
        self.run(now, sample)
        self._tc_apply(now)
        busy = self._tc_pending is not None     # a step under way: this one is not taken
        if self.events is not None:
            self.events.append((now, Ev.TIMECODE))
        sample = self._sample or (lambda c: (0, 0, 0))
        phase = self.phase(now)
        word = self.config[Config.TC_DISCIPLINE]
        resync = phase >= self.config[Config.SYNC_WINDOW]
        if resync and word:                 # the loop's window is two-sided
            resync, phase = arrival(word, phase, self.config[Config.SYNC_WINDOW],
                                    self.config[Config.PERIOD] + self.tc_loop[2])
        if resync:
            self._boundary(now, sample, resync=True)
        pending = self._cfg_pending         # records acting in this cycle: after the time-code
        held = pending.pop(0)[1] if pending and pending[0][0] == now else ()
        self.run(now + 1)
        if not resync and word and self._disciplined and not busy:
            f, a, _ = self.tc_loop
            self._tc_pending = (now + LATENCY, loop_step(word, phase, f, a))
        self.tc_value = value & 0xFF
        for reg, v in held:
            self._config(now, reg, v)
        return resync

    def period_start(self, now: int, count: int, qd: int) -> None:
        """A time-code in cycle ``now`` with the encoder resting at ``count``, ``qd``."""
        self.timecode(now, self.tc_value, lambda c: (count, qd, 0))

    def packet(self, now: int, ptype: int, payload: bytes, period: int | None = None,
               enc_errors: int = 0, sample=None):
        """A packet whose last byte is taken at cycle ``now``.

        ``period`` overrides the last time-code value; ``sample`` as in :meth:`run`.

        Returns
        -------
        bytes or None
            The reply payload for Comm A and Comm C requests (Comm C: once the VDC ran).
        """
        if ptype == PacketType.CONFIG and any(
                payload[k] == Config.DMP and int.from_bytes(payload[k + 1:k + 5], "little")
                in tuple(DmpControl) for k in range(0, len(payload) - 4, 5)):
            self._dmp_hold = now + 1            # its strobe suppresses a step in its cycle
        self.run(now + 1, sample)
        if period is not None:
            self.tc_value = period & 0xFF
        self._watch(now)
        payload = bytes(payload)
        reply = None
        if ptype in (PacketType.CONFIG, PacketType.PARAM):
            self.upload_crc = crc16(payload, self.upload_crc)
            self.upload_count = (self.upload_count + 1) & 0xFFFF
        if ptype == PacketType.COMM_B and len(payload) == PAYLOAD:
            self.b_words = unpack_words(payload, len(COMM_B_WORDS))
            entry = "first" if self.prime or payload[-1] & 1 else "main"
            mark, cycles = _vdc_timing(entry)
            self._vdc_mark = now + 1 + mark
            if self.events is not None:
                self.events += [(now, Ev.RX_B), (now + 1, Ev.VDC_START),
                                (self._vdc_mark, Ev.VDC_DONE), (now + 1 + cycles, Ev.VDC_END)]
            if entry == "first":
                self.vdc.primed = False
            self.prime = False
            w = self.b_words
            x = VdcInputs(w[0], w[1:7], w[7:13], self.snap_qd, self.cos_q, self.sin_q,
                          list(self.g_words))
            F_a, F_b = self.vdc.step(x)
            self.forces = F_a + F_b
            self.fresh = True
        elif ptype == PacketType.COMM_D:
            # g_C goes to the VDC word by word as it arrives; the rest on a full packet: at
            # once while disarmed, at the commit point while armed.
            w = unpack_words(payload, min(len(payload) // 3, len(COMM_D_WORDS)))
            for k in range(1, min(4, len(w))):
                self.g_words[k - 1] = w[k]
            if len(payload) == PAYLOAD:
                words = [w[0], w[4], w[5], w[6]]
                if self.armed:
                    self.d_next = words
                    self.d_next_base = self._lb
                    self.d_pending = True
                    if self.phase(now) >= self.config[Config.COMMIT]:
                        self.late_d = min(self.late_d + 1, 0xFFFF)
                else:
                    self._take_d(words, self._lb)
                if self.events is not None:
                    self.events.append((now, Ev.RX_D))
                    if not self.armed:
                        self.events.append((now, Ev.COMMIT))
        elif ptype == PacketType.COMM_A:
            reply = self._reply_a()
            if self.events is not None:
                self.events += [(now, Ev.RX_A), (self.reply_cycle(now, ptype), Ev.TX_A)]
        elif ptype == PacketType.COMM_C:
            reply = self._reply_c()
            if self.events is not None:
                self.events += [(now, Ev.RX_C), (self.reply_cycle(now, ptype), Ev.TX_C)]
        elif ptype == PacketType.CONFIG:
            recs = [(payload[k], int.from_bytes(payload[k + 1:k + 5], "little"))
                    for k in range(0, len(payload) - 4, 5)]
            if recs:                        # they act in the next cycle (module docstring)
                self._cfg_pending.append((now + 1, recs))
        elif ptype == PacketType.PARAM and len(payload) >= 3:
            bank, addr = payload[0] & 3, int.from_bytes(payload[1:3], "little")
            for j, w in enumerate(unpack_words(payload, min(12, (len(payload) - 3) // 3), 3)):
                self._param(bank, (addr + j) & 0x1FF, w)
        self.last_packet = now
        return reply

    def reply_cycle(self, now: int, ptype: int) -> int:
        """Cycle in which the reply FSM leaves Idle with the reply to a request of type
        ``ptype`` taken in cycle ``now`` (after :meth:`packet`): the next cycle, for Comm C
        not before the cycle after the last VDC run's MARK. Assumes the FSM idle (the
        previous reply has left)."""
        if ptype == PacketType.COMM_C:
            return max(now, self._vdc_mark) + 1
        return now + 1

    # --- helpers ------------------------------------------------------------------------------
    def _watch(self, now: int) -> None:
        """State visible in cycle ``now``: a pending command lands; the watchdog trips one
        cycle after the silence reaches the timeout (silence 0 in the cycle after a packet),
        and PRIME follows the trip one cycle later."""
        landing = self._landing
        if landing is not None and now >= landing[0]:
            self.torque = landing[1]
            self._landing = None
        self._now = now
        if self.armed and not self.tripped:
            trip = self.last_packet + 2 + self.config[Config.TIMEOUT]
            if now >= trip:
                self.tripped = True
                self.trip_cycle = trip
                self.hold_pos, self.hold_fixed = None, False
                self.still_cycle, self.still_run = None, 0
                self._prime_due = trip + 1
        prime_due = self._prime_due
        if prime_due is not None and now >= prime_due:
            self.prime = True
            self._prime_due = None

    @property
    def status(self) -> Status:
        # the bits as plain ints (_ST_*), one Status at the end: every boundary and every
        # Comm C reply forms it, and flag arithmetic on the enum costs a call per operation
        s = _ST_ARMED if self.armed else 0
        if self.tripped:
            s |= _ST_TRIPPED
            if self.holding_at(self._now):
                s |= _ST_HOLD
            elif self.torque == 0:
                s |= _ST_SAFE
            if self.brake_at(self._now):
                s |= _ST_BRAKE
            if self.stop_limit_at(self._now):
                s |= _ST_STOP_LIMIT
        if self.fresh:
            s |= _ST_FRESH
        if self.prime:
            s |= _ST_PRIME
        if self.dmp_select:
            s |= _ST_DMP
        return Status(s | (self.config[_CFG_MODE] << 5))

    def _reply_a(self) -> bytes:
        torque, status, errors, overruns, sync, late = self._snap
        out = (self.snap_count & 0xFFFFFFFF).to_bytes(4, "little")
        out += pack_words([self.snap_qd, torque])
        out += status.to_bytes(2, "little") + errors.to_bytes(2, "little")
        out += bytes([self.tc_value])
        for v in (overruns, sync, late, self.upload_crc, self.upload_count, *self.link_health,
                  self.dmp.overruns):
            out += v.to_bytes(2, "little")
        return out + bytes(PAYLOAD - len(out))

    def set_link(self, up_errors=None, down_errors=None, rx_stats=None,
                 dropped: int = 0) -> None:
        """The counters of the node's :class:`~hdl.link.node.LinkNode` as they stand now.

        Parameters
        ----------
        up_errors, down_errors : dict, optional
            :class:`~hdl.link.chars.ErrorCounts` fields of the upstream and downstream codec
            (missing: zero).
        rx_stats : dict, optional
            :class:`~hdl.link.packet.RxStats` fields of the depacketizer.
        dropped : int
            The router's discarded packets.
        """
        up, down, rx = up_errors or {}, down_errors or {}, rx_stats or {}
        self.link_health = (
            saturating_sum_ref(up.get(f, 0) for f in ERROR_CLASSES),
            saturating_sum_ref(down.get(f, 0) for f in ERROR_CLASSES),
            saturating_sum_ref(rx.get(f, 0) for f in RX_DROPS),
            int(dropped) & 0xFFFF)

    def _reply_c(self) -> bytes:
        out = pack_words(self.forces)
        out += int(self.status).to_bytes(2, "little") + bytes([self.tc_value])
        return out + bytes(PAYLOAD - len(out))

    def _config(self, now: int, reg: int, value: int) -> None:
        self._tc_apply(now)
        signed = value - (1 << 32) if value >> 31 else value
        if reg == Config.MODE and value < len(JOINT_MODES):
            self.config[Config.MODE] = value
        elif reg == Config.TICK and 0 < value < (1 << 16):
            self.config[Config.TICK] = value
        elif reg == Config.TIMEOUT:
            self.config[Config.TIMEOUT] = value
        elif reg == Config.RAMP:
            self.config[Config.RAMP] = value & 0xFFFFFF
        elif reg in (Config.TAU_MIN, Config.TAU_MAX):
            self.config[Config(reg)] = saturate(((signed + (1 << 23)) % (1 << 24)) - (1 << 23))
        elif reg == Config.PERIOD and 2 <= value < (1 << 24):
            self.config[Config.PERIOD] = value
            self._relength(now)             # the timer compares with the new value from now + 1
        elif reg == Config.TC_DISCIPLINE and value < (1 << DISCIPLINE_BITS):
            self.config[Config.TC_DISCIPLINE] = value
            self.tc_loop = (0, 0, 0)        # the write clears the loop (and a step under way)
            self._tc_pending = None
            self._relength(now)
        elif reg in (Config.SYNC_WINDOW, Config.COMMIT) and value < (1 << 24):
            self.config[Config(reg)] = value
        elif reg == Config.ARM:
            if value:
                self.arm_pending = True
                if now == self._nb - 1:     # the period's last cycle: too late for this boundary
                    self._pre_seen = self._nb
            else:
                self.armed = self.arm_pending = self.arming = False
                self.torque = 0
                self._landing = None
        elif reg == Config.PRIME:
            self.prime = True
        elif reg in (Config.STOP_CYCLES, Config.BRAKE_CYCLES) and value < (1 << 24):
            self.config[Config(reg)] = value
        elif reg == Config.STANDSTILL and value < (1 << 24):
            self.config[Config.STANDSTILL] = value
        elif reg in (Config.STANDSTILL_TICKS, Config.STOP_TRAIL) and value < (1 << 16):
            self.config[Config(reg)] = value
        elif reg == Config.DMP_STEP and 2 <= value < (1 << 24):
            self.config[Config.DMP_STEP] = value
        elif reg == Config.DMP and value in (DmpControl.OFF, DmpControl.START, DmpControl.STOP):
            self._dmp_control(now, value)
        elif reg == Config.PRESET:
            self.presets.append((now, signed))
            if self.encoder_preset is not None:
                self.encoder_preset(now, signed)

    def _dmp_control(self, now: int, value: int) -> None:
        """CONFIG DMP in cycle ``now`` (:class:`~protocol.regs.DmpControl`; the registers it
        sets are seen from ``now + 1``)."""
        if value == DmpControl.START:
            self.dmp.start(now)
            self.dmp_waiting, self.dmp_running = True, False
            self._select(False)
            return
        self.dmp.stop()
        self.dmp_waiting = self.dmp_running = False
        if value == DmpControl.OFF:
            self._select(False)
        elif self.dmp_select:                    # STOP: hold the last position
            self.d_words = [self.d_words[0], self.dmp.qd0, 0, 0]

    def _select(self, on: bool) -> None:
        if self.dmp_select and not on:
            self.d_words, self.d_base = list(self.cd_words), self.cd_base
        self.dmp_select = on

    def _param(self, bank: int, addr: int, w: int) -> None:
        if bank == Bank.DMP:
            self.dmp.write(addr, w)
            return
        if bank not in (Bank.JOINT, Bank.VDC):
            return
        if bank == Bank.JOINT:
            mc = joint_microcode(self.joint.params.pid_shift)
            names = {mc.addr(n): n for n in self.joint.params.words()}
            if addr in names:
                setattr(self.joint.params, names[addr], w)
            states = {mc.addr("qdes"): "q_des", mc.addr("vdes"): "v_des",
                      mc.addr("ilo_s"): "i_lo", mc.addr("ihi_s"): "i_hi"}
            if addr in states:
                setattr(self.joint, states[addr], w)
            return
        mc = vdc_microcode()
        name = next((r.name for r in mc.regs.values() if r.addr == addr and r.kind in
                     ("param", "state", "host")), None)
        if name is None:
            return
        p, links = self.vdc.params, {"A": 0, "B": 1}
        if name == "invT":
            p.inv_T = w
        elif name[0] == "K" and name[1] in links:
            p.K[links[name[1]]][int(name[2:])] = w
        elif name.startswith("th"):
            self.vdc.theta[links[name[2]]][int(name[3:])] = w
        elif name.startswith(("lo", "hi")):
            arr = p.lower if name.startswith("lo") else p.upper
            arr[links[name[2]]][int(name[3:])] = w
        elif name[0] == "r" and name[1] in links:
            p.rho_T[links[name[1]]][int(name[2:])] = w
        elif name.startswith("pC"):
            self.vdc.prev_C[int(name[2:])] = w
        elif name == "pqdr":
            self.vdc.prev_qd_r = w
        elif name.startswith("gC"):
            self.g_words[int(name[2:])] = w
