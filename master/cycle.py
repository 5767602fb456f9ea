"""The master's 1 ms communication cycle (MRM paper §4, Fig. 3): time-code, A, B, C, D.

The master is event-driven and knows nothing of how packets travel: the harness (``cosim``)
calls :meth:`Master.poll` at its time grid and :meth:`Master.on_packet` for every good packet
received, and sends what the master returns. Per period p, starting at cycle
``P = start + p·period_cycles``:

1. time-code ``p mod 64`` and a broadcast Comm A request (nodes snapshot at the time-code);
2. when every node's Comm A is in, after ``kinematics_cycles`` of modelled master compute:
   VDC — required joint velocities and the actual and required 6-D velocities of every {C_k}
   base → tip, one Comm B per node, then a broadcast Comm C request;
3. when every Comm C is in, after ``force_cycles``: required forces tip → base, one Comm D per
   node with the projection ``τ_Lr``, gravity in {C_k} for the next period and the references
   at the period start (PID modes skip B and C: Comm D follows Comm A directly).

Everything the master knows about the robot is nominal: Table 1 parameters, the kinematics,
encoder counts and the nodes' velocity words. Every reply is checked, never silently absorbed:
the harness drops frames whose link CRC fails (and counts them); a reply must come from a
node, be of the kind the master is waiting for in this period and well formed (else
``unexpected``), answer this period's request — the sequence number of the request, where the
harness passes it, and the period (time-code) the node echoes (else ``late``, and ignored) —
and come before the period ends (else the period is an ``overrun`` and the replies not in are
``missing``; so is a period whose Comm D was still waiting to be sent; the harness's
:meth:`Master.finish` judges a run's last period the same way if it has ended). The nodes' own
counters, reported in every Comm A (control ticks skipped, time-codes outside the sync window,
Comm D packets after the commit phase, illegal encoder transitions), are kept per node
(:attr:`Master.node_counters`); a run with any of them non-zero says so. So is each node's
view of the link — its two codecs' error totals, the frames its depacketizer dropped, the
packets its router discarded (:data:`protocol.regs.LINK_HEALTH`, :attr:`Master.node_link`,
:meth:`Master.link_totals`): a fault anywhere on the chain is counted where it happened.

Uploads. Given the CONFIG and PARAM packets sent to the nodes before the run
(:meth:`Master.expect_uploads`), the master computes what each node must report in every
Comm A — the CRC-16 of those payloads in order and their number
(:func:`protocol.regs.upload_check`) — and counts every Comm A that disagrees
(:attr:`Master.upload_errors`, per node): an upload lost, corrupted or reordered on the way.

The nodes act on their own period timer (docs/node.md "Timing"): the master's period grid
must be the nodes' (``period_cycles`` = CONFIG PERIOD, period 0 at a multiple of it from the
nodes' reset), and its Comm D must reach every node before the commit phase.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mrm_cosim.protocol.packet import BROADCAST, PacketType
from mrm_cosim.protocol.fixed import FORCE, VEL
from mrm_cosim.protocol.regs import (
    LINK_HEALTH, Status, pack_comm_b, pack_comm_d, parse_comm_a, parse_comm_c, upload_check,
)
from mrm_cosim.errors import InputError
from mrm_cosim.master.recovery import ON_TRIP, Blend, fit_blend
from mrm_cosim.master.vdc import (
    force_chain, joint_rotations, mounts, required_velocities, velocity_chain,
)
from mrm_cosim.models.robot import Robot
from mrm_cosim.units import CLOCK_HZ

__all__ = ["Send", "Master", "MasterTiming", "PeriodRecord", "CONTROLLERS", "NODE_COUNTERS",
           "REFERENCES", "ON_TRIP"]

CONTROLLERS = ("vdc", "pid-fpga", "pid-1khz")
#: What Comm D's references are (docs/dmp.md "The master"): ``full`` — ``q_d, q̇_d, q̈_d`` at
#: the period start (the joint interpolates to the next); ``hold`` — ``q_d`` only, held by the
#: joint for the period (the traditional architecture of the motion-primitive paper);
#: ``dmp`` — the joints generate their references from primitives deployed before the run
#: and started by the master at period 0 (Comm D's references then only stand until the start).
REFERENCES = ("full", "hold", "dmp")
#: Comm A fields that count problems in a node (cumulative since its reset)
NODE_COUNTERS = ("overruns", "sync_errors", "late_d", "errors", "dmp_overruns")
#: Comm A status bits of a node that tripped (as an int: one ``&`` a reply, not three enum ops)
_TRIP_BITS = int(Status.TRIPPED | Status.HOLD | Status.BRAKE)
_FRESH = int(Status.FRESH)


@dataclass(frozen=True)
class Send:
    """An action for the link: a packet (``dest``, ``ptype``, ``payload``) or a time-code."""

    kind: str                     # "packet" or "timecode"
    dest: int = 0
    ptype: int = 0
    payload: bytes = b""
    seq: int = 0
    time: int = 0


@dataclass(frozen=True)
class MasterTiming:
    """Timing of the cycle, in 20 ns FPGA cycles.

    Attributes
    ----------
    period_cycles : int
        1 ms = 50,000 cycles.
    kinematics_cycles, force_cycles : int
        Modelled compute time of the master's two steps (the paper's master is a 300 MHz
        PowerPC; 20 µs each by default).
    """

    period_cycles: int = 50_000
    kinematics_cycles: int = 1_000
    force_cycles: int = 1_000


@dataclass
class PeriodRecord:
    """What happened in one period (cycles are absolute)."""

    index: int
    start: int
    q: np.ndarray | None = None          # joint angles from Comm A (rad)
    qd: np.ndarray | None = None         # joint velocities from Comm A (rad/s)
    tau: np.ndarray | None = None        # torques the nodes applied at the snapshot (N·m)
    events: dict = field(default_factory=dict)   # name -> cycle, e.g. "A_done", "B_sent"
    arrivals: dict = field(default_factory=dict)  # (phase, node) -> cycle
    complete: bool = False
    #: (NodeEvent name, node) -> cycle of its first strobe in [start, start + period_cycles),
    #: e.g. ("RX_B", 2): the nodes' observation ports (:meth:`Master.on_node_event`)
    node_events: dict = field(default_factory=dict)


class Master:
    """The master node.

    Parameters
    ----------
    robot : Robot
    controller : str
        ``"vdc"``, ``"pid-fpga"`` or ``"pid-1khz"``.
    trajectory : callable
        ``trajectory(t) -> (q_d, q̇_d, q̈_d)`` arrays of shape (n,) at time ``t`` (s) from the
        first period's start.
    counts_per_rev : ndarray of int, shape (n,)
    timing : MasterTiming
    lam : float, 1/s
        λ of the required joint velocity.
    base_fb : float
        VDC: the share of joint 1's velocity error the link level feeds back
        (:attr:`~master.uploads.Gains.vdc_base_fb`; 1: all, the paper's VDC).
    pid : dict, optional
        ``kp``, ``ki``, ``kd`` arrays (N·m/rad, N·m/(rad·s), N·m·s/rad) of the 1 kHz PID.
    clock_hz : float
    uploads : list of (dest, type, payload), optional
        The packets sent to the nodes before the run (:meth:`expect_uploads`).
    references : str
        What Comm D's references are (:data:`REFERENCES`). With ``"dmp"`` the uploads must
        have deployed a primitive to every node; the master starts them once period 0's
        Comm A has confirmed every node's uploads (CONFIG DMP = START to every node: their
        primitives take over at period 1's boundary), or, if any node's upload check failed,
        starts none and counts the nodes in :attr:`dmp_errors` — before any motion, since the
        trajectory of a primitive run starts at period 1. From period 2 every Comm A must
        report the generator selected (``Status.DMP``); one that does not is counted too.
    on_trip : str or None
        What to do when nodes trip or stop answering (:data:`ON_TRIP`,
        :mod:`master.recovery`): ``"rearm"``, ``"end"``, or ``None`` (only count it).
    rearm_blend : float, s
        With ``"rearm"``: the blend from the held positions back to the trajectory.
    """

    def __init__(self, robot: Robot, controller: str, trajectory, counts_per_rev,
                 timing: MasterTiming | None = None, lam: float = 50.0, pid=None,
                 clock_hz: float = float(CLOCK_HZ), uploads=None, references: str = "full",
                 on_trip: str | None = None, rearm_blend: float = 0.2, base_fb: float = 1.0):
        if not 0.0 <= base_fb <= 1.0:
            raise ValueError(f"base_fb must lie in [0, 1], not {base_fb!r}")
        #: share of joint 1's velocity error fed back by the VDC's link level (Gains.vdc_base_fb)
        self.base_fb = float(base_fb)
        if on_trip is not None and on_trip not in ON_TRIP:
            raise ValueError(f"on_trip must be one of {ON_TRIP} or None, not {on_trip!r}")
        if not rearm_blend > 0.0:
            raise ValueError(f"rearm_blend must be positive, not {rearm_blend!r}")
        self.on_trip = on_trip
        self.rearm_blend = float(rearm_blend)
        #: why the master stopped sending (``on_trip = "end"``), None while it runs
        self.ended: str | None = None
        #: nodes whose Comm A went missing in some period (silent: their watchdogs trip)
        self.lost: set[int] = set()
        #: what the master saw and did about trips: (cycle, text)
        self.recovery_log: list[tuple[int, str]] = []
        self.rearms = 0          # re-arm sequences sent (on_trip = "rearm")
        self._blend: Blend | None = None
        self._rearm_period = -1  # the period the last ARM lands in
        self._waiting = False    # tripped nodes still stopping (re-arm waits)
        if controller not in CONTROLLERS:
            raise ValueError(f"controller must be one of {CONTROLLERS}, not {controller!r}")
        if references not in REFERENCES:
            raise ValueError(f"references must be one of {REFERENCES}, not {references!r}")
        if references == "dmp" and uploads is None:
            raise ValueError("references 'dmp' needs the uploads that deployed the primitives")
        self.references = references
        #: node -> problems with its primitive: the deploy's read-back failed (no start), or a
        #: Comm A after the start without the generator selected
        self.dmp_errors: dict[int, int] = {k: 0 for k in range(1, robot.n + 1)}
        self.dmp_started = False
        self._uploads = list(uploads) if uploads is not None else None
        self.robot = robot
        self.n = robot.n
        self.controller = controller
        self.trajectory = trajectory
        self.counts_per_rev = np.asarray(counts_per_rev, dtype=float)
        self.timing = timing = timing or MasterTiming()
        self.lam = lam
        self.pid = pid
        self.dt = timing.period_cycles / clock_hz
        self.start = None
        self.records: list[PeriodRecord] = []
        #: every ``(cycle, node)`` BOUNDARY strobe from half a period before period 0 on (a
        #: record keeps only each period's first: a node starting a period early strobes late
        #: in the previous one, period 0's before the master's start)
        self.boundary_strobes: list[tuple[int, int]] = []
        self._early_strobes: list[tuple[int, int]] = []     # BOUNDARY strobes before begin()
        self.overruns = 0        # periods whose exchange did not finish within the period
        self.missing = 0         # replies that never came
        self.unexpected = 0      # replies that were not asked for, or malformed
        self.late = 0            # replies to an earlier period's request (ignored)
        #: node -> Comm A replies whose upload CRC or count differed from the expected
        self.upload_errors: dict[int, int] = {}
        #: node -> (CRC, count) every Comm A must report; None: no check
        self.expected_uploads: dict[int, tuple[int, int]] | None = None
        #: nodes that reported a watchdog trip in a Comm A
        self.tripped: set[int] = set()
        #: node -> the counters of its last Comm A (cumulative in the node)
        self.node_counters: dict[int, dict] = {}
        #: node -> its link counters (:data:`~protocol.regs.LINK_HEALTH`) in its last Comm A
        self.node_link: dict[int, dict] = {}
        self._seq = 0
        self._pending: list[tuple[int, list[Send]]] = []   # (cycle, actions)
        self._due: int | None = None    # the earliest cycle in _pending (None: it is empty)
        self._wake = 0           # no poll before this cycle has anything to do
        self._ref_at = None      # (t, references) of the last trajectory evaluation
        self._integral = np.zeros(self.n)
        self._rec: PeriodRecord | None = None
        self._judged: PeriodRecord | None = None     # the last period judged
        self._a = {}
        self._c = {}
        self._req = {}           # packet type -> sequence number of this period's request
        if uploads is not None:
            self.expect_uploads(uploads)

    def expect_uploads(self, uploads) -> None:
        """Check every Comm A against the uploads ``[(dest, type, payload), ...]`` sent to the
        nodes since their reset, in order (CONFIG and PARAM count; broadcasts go to every
        node). Replaces any earlier expectation; clears :attr:`upload_errors`."""
        from mrm_cosim.protocol.packet import BROADCAST as _ALL

        kinds = (PacketType.CONFIG, PacketType.PARAM)
        self.expected_uploads = {
            k: upload_check([bytes(p) for d, t, p in uploads
                             if t in kinds and d in (k, _ALL)])
            for k in range(1, self.n + 1)}
        self.upload_errors = {k: 0 for k in range(1, self.n + 1)}

    def upload_error_total(self) -> int:
        """Comm A replies, over all nodes, whose upload check failed."""
        return int(sum(self.upload_errors.values()))

    def node_totals(self) -> dict:
        """Sum over the nodes of each of :data:`NODE_COUNTERS`, as last reported."""
        return {k: int(sum(c[k] for c in self.node_counters.values())) for k in NODE_COUNTERS}

    def link_totals(self) -> dict:
        """Sum over the nodes of each link counter (:data:`~protocol.regs.LINK_HEALTH`), as
        last reported (each is cumulative since the node's reset)."""
        return {k: int(sum(c[k] for c in self.node_link.values())) for k in LINK_HEALTH}

    # --- scheduling ------------------------------------------------------------------------
    def begin(self, start_cycle: int) -> None:
        """Start the cycle: period 0 begins at ``start_cycle``."""
        self.start = start_cycle
        self._wake = 0
        early = start_cycle - self.timing.period_cycles // 2
        self.boundary_strobes += [s for s in self._early_strobes if s[0] >= early]
        self._early_strobes = []

    def poll(self, now: int) -> list[Send]:
        """Actions due at cycle ``now`` or before (called by the harness on its time grid, and
        at :meth:`next_due`). Before the next period's start and the earliest computed packet
        (:attr:`_wake`) there is nothing to do and nothing is computed."""
        if now < self._wake:
            return []
        if self.ended is not None:
            self._pending, self._due = [], None
            self._wake = 1 << 62        # silent for good
            return []
        out = []
        period = self.timing.period_cycles
        if self.start is not None and now >= self.start:
            index = (now - self.start) // period
            if self._rec is None or index > self._rec.index:
                out += self._new_period(index, self.start + index * period)
        pending, due = [], None          # what stays, and the earliest of it
        for c, actions in self._pending:
            if c <= now:
                out += actions
            else:
                pending.append((c, actions))
                if due is None or c < due:
                    due = c
        self._pending, self._due = pending, due
        wake = None if self.start is None else (
            self.start + (max(now - self.start, -1) // period + 1) * period)
        if due is not None and (wake is None or due < wake):
            wake = due
        self._wake = now + 1 if wake is None else wake
        return out

    def quiet_end(self, step: int) -> int:
        """For a harness stepping ``step`` cycles at a time, polling at each step's first cycle
        and splitting its steps at :meth:`next_due`: the latest end cycle up to which no step
        needs the master (its poll has nothing to do, no packet is due inside). Valid until the
        master is next called."""
        due = self._due
        end = self._wake - 1 + step
        return end if due is None or due > end else due

    def next_due(self) -> int | None:
        """The earliest cycle a computed packet is waiting for (None: none waits). A harness
        that polls on a coarser grid splits its step there, so packets leave when due."""
        return self._due

    def _later(self, cycle: int, actions: list[Send]) -> None:
        self._pending.append((cycle, actions))
        if self._due is None or cycle < self._due:
            self._due = cycle
        if cycle < self._wake:
            self._wake = cycle

    def _packet(self, dest: int, ptype: PacketType, payload: bytes) -> Send:
        self._seq = (self._seq + 1) & 0xFF
        return Send("packet", dest, int(ptype), bytes(payload), self._seq)

    def _judge(self, rec: PeriodRecord) -> None:
        """Period ``rec`` has ended: replies not in, or a Comm D still waiting, make it an
        overrun and the replies ``missing`` (once per period)."""
        if self._judged is rec:
            return
        self._judged = rec
        if self.ended is not None:
            return                      # the master is silent: nothing was asked
        if not rec.complete or self._pending:
            self.overruns += 1
            if not rec.complete:
                self.missing += (self.n - len(self._a)) + (
                    0 if self.controller != "vdc" else self.n - len(self._c))
            rec.complete = False
        silent = [k for k in range(1, self.n + 1) if k not in self._a]
        if silent:
            new = [k for k in silent if k not in self.lost]
            self.lost.update(silent)
            end = rec.start + self.timing.period_cycles
            if new:
                self.recovery_log.append((end, f"period {rec.index}: no Comm A from node "
                                          f"{', '.join(map(str, new))} (link lost?)"))
            if self.on_trip == "end":
                self._end(end, f"link lost: no Comm A from node "
                          f"{', '.join(map(str, silent))} in period {rec.index}")

    def _end(self, now: int, reason: str) -> None:
        """``on_trip = "end"``: stop sending for good (the nodes' watchdogs trip, they stop,
        hold and brake)."""
        if self.ended is None:
            self.ended = reason
            self.recovery_log.append((now, f"ended: {reason}"))
            self._pending, self._due = [], None

    def finish(self, now: int) -> None:
        """The run ends at cycle ``now`` (both harnesses call this once, after their last
        step). The last period is judged as the next period's start would judge it, if it has
        ended by ``now``: a run of whole periods counts the faults of its last one too. A
        period the run cuts short is not judged — its replies may still be on the way — and
        keeps ``complete`` as it stands."""
        rec = self._rec
        if rec is not None and now >= rec.start + self.timing.period_cycles:
            self._judge(rec)

    def _new_period(self, index: int, start: int) -> list[Send]:
        if self._rec is not None:
            self._judge(self._rec)
        if self.ended is not None:
            return []
        self._rec = PeriodRecord(index, start)
        self.records.append(self._rec)
        self._a, self._c = {}, {}
        self._pending, self._due = [], None
        request = self._packet(BROADCAST, PacketType.COMM_A, b"\0")
        self._req = {PacketType.COMM_A: request.seq}
        if getattr(self, "_expect_next", False):     # the uploads sent last period are in
            errors = dict(self.upload_errors)
            self.expect_uploads(self._uploads)
            self.upload_errors = errors
            self._expect_next = False
        extra, self._extra = getattr(self, "_extra", []), []
        # this period's Comm A is taken before they arrive (the request goes first): it is
        # judged against the uploads as they were, the next ones against all of them
        self._expect_next = bool(extra) and self._uploads is not None
        return [Send("timecode", time=index & 0x3F), request, *extra]

    # --- what the nodes did (their observation ports) -------------------------------------
    def on_node_event(self, now: int, node: int, name: str) -> None:
        """Node ``node`` (1-based) strobed the observation-port flag ``name`` (a
        :class:`protocol.regs.NodeEvent` name) in cycle ``now``. Kept in the record of the
        period ``[start, start + period_cycles)`` holding ``now`` as the first such cycle;
        before period 0, or in a period without a record, ignored. The master does not act on
        it: the harnesses (``cosim.closed_loop``, ``cosim.model``) report it for the timeline."""
        self.on_node_events(((now, node, name),))

    def on_node_events(self, events) -> None:
        """:meth:`on_node_event` for each ``(cycle, node, name)`` of ``events``, in order (the
        harness's call for a piece's strobes: the period's record looked up once, not per
        strobe)."""
        start = self.start
        if start is None:               # (period 0's early boundaries: begin() keeps them)
            early = self._early_strobes
            early += [(now, node) for now, node, name in events if name == "BOUNDARY"]
            if len(early) > 64:
                del early[:-32]
            return
        period = self.timing.period_cycles
        lo = hi = start         # the period [lo, hi) whose record's strobes are ``seen``
        seen = None
        for now, node, name in events:
            if not lo <= now < hi:
                if now < start:
                    if name == "BOUNDARY" and now >= start - period // 2:
                        self.boundary_strobes.append((now, node))
                    continue
                index = (now - start) // period
                lo = start + index * period
                hi = lo + period
                seen = None
                for r in reversed(self.records):
                    if r.index == index:
                        seen = r.node_events
                        break
                    if r.index < index:
                        break
            if name == "BOUNDARY":
                self.boundary_strobes.append((now, node))
            if seen is not None:
                key = (name, node)
                if seen.setdefault(key, now) > now:     # the first strobe in the period
                    seen[key] = now

    # --- replies ---------------------------------------------------------------------------
    def stale(self, ptype: int, seq: int) -> bool:
        """Whether a reply of type ``ptype`` whose header carries ``seq`` answers an earlier
        request than this period's (the node echoes its request's sequence number); such a
        reply is counted ``late`` and must not be passed to :meth:`on_packet`. Both harnesses
        (``cosim.closed_loop``, ``cosim.model``) call it; :meth:`on_packet` also checks the
        period the reply echoes."""
        if ptype in self._req and seq != self._req[ptype]:
            self.late += 1
            return True
        return False

    def on_packet(self, now: int, src: int, ptype: int, payload: bytes,
                  seq: int | None = None) -> None:
        """A good packet from node ``src`` (1-based) arrived complete at cycle ``now``.

        ``seq``: the sequence number of its header, if known (:meth:`stale`)."""
        rec = self._rec
        if rec is None or not 1 <= src <= self.n:
            self.unexpected += 1
            return
        if seq is not None and self.stale(ptype, seq):
            return
        try:
            if ptype == PacketType.COMM_A:
                a = parse_comm_a(payload)
                if a["period"] != rec.index & 0x3F:     # the node answered another period
                    self.late += 1
                elif src in self._a:
                    self.unexpected += 1
                else:
                    self._on_a(now, src, a)
            elif ptype == PacketType.COMM_C and self.controller == "vdc":
                c = parse_comm_c(payload)
                if c[3] != rec.index & 0x3F:
                    self.late += 1
                elif src in self._c or PacketType.COMM_C not in self._req:
                    self.unexpected += 1
                else:
                    self._c[src] = c
                    rec.arrivals[("C", src)] = now
                    if len(self._c) == self.n:
                        rec.events["C_done"] = now
                        self._after_c(now)
            else:
                self.unexpected += 1
        except ValueError:
            self.unexpected += 1

    def _on_a(self, now: int, src: int, a: dict) -> None:
        rec = self._rec
        self._a[src] = a
        self.node_counters[src] = {k: a[k] for k in NODE_COUNTERS}
        self.node_link[src] = {k: a[k] for k in LINK_HEALTH}
        if int(a["status"]) & _TRIP_BITS:
            self.tripped.add(src)
        exp = self.expected_uploads
        if exp is not None and (a["upload_crc"], a["upload_count"]) != exp[src]:
            self.upload_errors[src] += 1
        rec.arrivals[("A", src)] = now
        if len(self._a) == self.n:
            rec.events["A_done"] = now
            if self.references == "dmp":
                self._dmp_check(now)
            if self.on_trip is not None and self._on_trip(now):
                return
            self._after_a(now)

    def _on_trip(self, now: int) -> bool:
        """Every Comm A of the period is in: if a node reports a trip, recover as
        :attr:`on_trip` says (:mod:`master.recovery`) and return True (no motion this period)."""
        rec = self._rec
        tripped = sorted(k for k, a in self._a.items()
                         if a["status"] & (Status.TRIPPED | Status.HOLD | Status.BRAKE))
        if not tripped or rec.index == self._rearm_period:
            # (the period the ARM lands in: its snapshot, at the boundary, is from before it)
            return False
        names = ", ".join(map(str, tripped))
        rec.complete = True                 # nothing more is asked this period
        if self.on_trip == "end":
            self.recovery_log.append((now, f"period {rec.index}: node {names} tripped"))
            self._end(now, f"node {names} tripped (period {rec.index})")
            return True
        moving = [k for k in tripped
                  if not self._a[k]["status"] & (Status.BRAKE | Status.SAFE)]
        if moving:                          # re-arm only once every stop is complete: the
            if not self._waiting:           # joint at rest on its brake (no windup of a
                self._waiting = True        # loop that re-arms against a moving joint)
                self.recovery_log.append((now, f"period {rec.index}: node {names} tripped; "
                                          "waiting for their stops to complete (BRAKE)"))
            return True
        self._waiting = False
        if self.references == "dmp":        # the joints' generators would ignore the blend
            self._end(now, f"cannot re-arm node {names}: their references come from "
                      "primitives (re-arm them with a new deploy)")
            return True
        exp = self.expected_uploads
        bad = [k for k, a in self._a.items()
               if exp is not None and (a["upload_crc"], a["upload_count"]) != exp[k]]
        if bad:
            self._end(now, f"cannot re-arm: the upload read-back of node "
                      f"{', '.join(map(str, sorted(bad)))} disagrees (period {rec.index})")
            return True
        from mrm_cosim.protocol.regs import Config, config_payloads

        a = [self._a[k + 1] for k in range(self.n)]
        q = np.array([x["count"] for x in a]) * (2 * math.pi) / self.counts_per_rev
        # tripped nodes: held at rest; the others keep their reported velocity (no ARM)
        v = np.array([0.0 if k + 1 in tripped else VEL.decode(a[k]["qd"])
                      for k in range(self.n)])
        z = np.zeros(self.n)
        arm = [self._packet(k, PacketType.CONFIG, p)
               for k in tripped for p in config_payloads({Config.ARM: 1})]
        sends = self._comm_d(z, q, q, v, z) + arm
        self._later(now + self.timing.kinematics_cycles, sends)
        if self._uploads is not None:       # the ARM joins what every Comm A reads back
            self._uploads += [(s.dest, PacketType.CONFIG, s.payload) for s in arm]
            errors = dict(self.upload_errors)
            self.expect_uploads(self._uploads)
            self.upload_errors = errors
        t0 = (rec.index + 1) * self.dt         # the nodes re-arm at the next boundary
        self._rearm_period = rec.index + 1
        self._blend = fit_blend(self.trajectory, q + v * self.dt, t0, self.rearm_blend,
                                self._joint_inertia(q), self.robot.peak_torques, v_hold=v)
        self._integral = np.zeros(self.n)
        self.rearms += 1
        self.recovery_log.append((now, f"period {rec.index}: uploads read back on every "
                                  f"node; hold, ARM node {names}; blend back to the "
                                  f"trajectory from "
                                  f"{t0:.4f} s to {self._blend.t1:.4f} s"))
        return True

    def _joint_inertia(self, q) -> np.ndarray:
        """Each joint's nominal inertia at ``q`` (kg·m²): the mass matrix's diagonal (the
        robot's nominal bodies) plus the reflected rotor inertia."""
        import pinocchio as pin

        from mrm_cosim.models.actuators import ACTUATORS

        model = self.robot.pinocchio_model()
        M = pin.crba(model, model.createData(), np.asarray(q, dtype=float))
        return np.diag(M) + np.array([ACTUATORS[m.type.actuator].output_inertia
                                      for m in self.robot.modules])

    def _references(self, t: float):
        """The references at ``t``; the trajectory (a function of ``t``; after a re-arm the
        blend back to it) is evaluated once for the Comm B and Comm D of a period (the arrays
        are only read)."""
        source = self.trajectory if self._blend is None else self._blend
        last = self._ref_at
        if last is not None and last[0] == t and last[2] is source:
            return last[1]
        q_d, qd_d, qdd_d = source(t)
        q_d, qd_d, qdd_d = (np.asarray(x, float) for x in (q_d, qd_d, qdd_d))
        if self.references == "hold":
            qd_d, qdd_d = np.zeros_like(qd_d), np.zeros_like(qdd_d)
        self._ref_at = (t, (q_d, qd_d, qdd_d), source)
        return q_d, qd_d, qdd_d

    def send_uploads(self, packets) -> None:
        """Send ``packets`` ``[(dest, type, payload), ...]`` (e.g. a primitive's new goal or τ,
        :func:`master.uploads.dmp_retarget`) at the next period's start, after its Comm A
        request; CONFIG and PARAM ones join what every later Comm A must read back."""
        self._extra = getattr(self, "_extra", []) + [
            self._packet(d, PacketType(t), p) for d, t, p in packets]
        if self._uploads is not None:
            self._uploads += [(d, PacketType(t), bytes(p)) for d, t, p in packets]

    def _dmp_check(self, now: int) -> None:
        """Primitives: start them after period 0's Comm A confirmed every node's uploads;
        from period 2 every node must report its generator selected."""
        from mrm_cosim.protocol.regs import Config, DmpControl, config_payloads

        rec = self._rec
        if rec.index == 0 and not self.dmp_started:
            exp = self.expected_uploads
            bad = [k for k, a in self._a.items()
                   if exp is None or (a["upload_crc"], a["upload_count"]) != exp[k]]
            for k in bad:
                self.dmp_errors[k] += 1
            if bad:
                return
            start = config_payloads({Config.DMP: DmpControl.START})
            sends = [self._packet(k, PacketType.CONFIG, p)
                     for k in range(1, self.n + 1) for p in start]
            self._later(now, sends)
            self._uploads += [(s.dest, PacketType.CONFIG, s.payload) for s in sends]
            errors = dict(self.upload_errors)
            self.expect_uploads(self._uploads)
            self.upload_errors = errors
            self.dmp_started = True
        elif rec.index >= 2 and self.dmp_started:
            for k, a in self._a.items():
                if not a["status"] & Status.DMP:
                    self.dmp_errors[k] += 1

    def _after_a(self, now: int) -> None:
        rec = self._rec
        a = [self._a[k + 1] for k in range(self.n)]
        rec.q = np.array([x["count"] for x in a]) * (2 * math.pi) / self.counts_per_rev
        rec.qd = np.array([VEL.decode(x["qd"]) for x in a])
        rec.tau = np.array([FORCE.decode(x["torque"]) for x in a])
        t = rec.index * self.dt
        q_d, qd_d, qdd_d = self._references(t)
        send_at = now + self.timing.kinematics_cycles
        if self.controller == "vdc":
            qd_r, qdd_r, qd = (x.tolist() for x in required_velocities(
                q_d, qd_d, qdd_d, rec.q, rec.qd, self.lam, self.base_fb))
            for name, x in (("qd", qd), ("qd_r", qd_r), ("qdd_r", qdd_r)):
                if not all(map(math.isfinite, x)):      # (the trajectory's values)
                    raise InputError(name, "must be finite")
            chain = velocity_chain(self.robot, rec.q, qd, qd_r, qdd_r)
            prime = rec.index == 0
            actions = []
            for k, (C, _) in enumerate(chain):
                V_C, Vr_C, _ = C.tolist()
                actions.append(self._packet(k + 1, PacketType.COMM_B,
                                            pack_comm_b(qd_r[k], V_C, Vr_C, prime)))
            request = self._packet(BROADCAST, PacketType.COMM_C, b"\0")
            self._req[PacketType.COMM_C] = request.seq
            actions.append(request)
            rec.events["B_sent"] = send_at
            self._later(send_at, actions)
            return
        if self.controller == "pid-1khz":
            e = q_d - rec.q
            self._integral += e * self.dt
            tau = (self.pid["kp"] * e + self.pid["ki"] * self._integral
                   + self.pid["kd"] * (qd_d - rec.qd))
            tau = np.clip(tau, -self.robot.peak_torques, self.robot.peak_torques)
        else:                                    # pid-fpga: the node closes the loop
            tau = np.zeros(self.n)
        rec.events["D_sent"] = send_at
        self._later(send_at, self._comm_d(tau, rec.q, q_d, qd_d, qdd_d))
        rec.complete = True

    def _after_c(self, now: int) -> None:
        rec = self._rec
        c = [self._c[k + 1] for k in range(self.n)]
        # every FORCE word decoded at once (FORCE.decode's value: a power-of-two scale, exact)
        F = np.ldexp(np.array([F_a + F_b for F_a, F_b, _, _ in c], dtype=float), FORCE.lsb)
        for _, _, status, _ in c:
            if not int(status) & _FRESH:
                self.unexpected += 1       # forces not computed from this period's Comm B
        # the required force at every {A_k}; τ_Lr its z moment (propagate_forces, unchecked)
        F_A = force_chain(self.robot, joint_rotations(rec.q), F[:, :6], F[:, 6:])
        # The counterbalance springs of Type II modules are part of the joint: their nominal
        # torque is known, so the joint needs τ_Lr less what the spring already gives.
        tau_lr = F_A[:, 5] - self.robot.spring_torque(rec.q)
        t = rec.index * self.dt
        q_d, qd_d, qdd_d = self._references(t)
        send_at = now + self.timing.force_cycles
        rec.events["D_sent"] = send_at
        self._later(send_at, self._comm_d(tau_lr, rec.q, q_d, qd_d, qdd_d))
        rec.complete = True

    def gravity_in_C(self, q) -> np.ndarray:
        """Upward gravity ``[0, 0, 9.81]`` expressed in every {C_k} at joint angles ``q``."""
        # R_Cᵀ (0, 0, 9.81) is 9.81 times R_C's third row (the other products are zeros).
        # R_C by Robot.link_frames' products (T_C = T_A,k−1 · mount_k, T_A = T_C · Rz(q_k),
        # BLAS's, through ndarray.dot), the joint transforms built at once
        c, s = [math.cos(x) for x in q], [math.sin(x) for x in q]    # (robot.rot_z's)
        H = np.zeros((self.n, 4, 4))
        H[:, 0, 0] = c
        H[:, 0, 1] = [-x for x in s]
        H[:, 1, 0] = s
        H[:, 1, 1] = c
        H[:, 2, 2] = H[:, 3, 3] = 1.0
        T = np.eye(4)
        rows = []
        for M, H_k in zip(mounts(self.robot)[0], H, strict=True):
            T_C = T.dot(M)
            rows.append(T_C[2, :3])
            T = T_C.dot(H_k)
        return np.array(rows) * 9.81

    def _comm_d(self, tau, q, q_d, qd_d, qdd_d) -> list[Send]:
        # Gravity for the next period's VDC run, at the angles expected then.
        g = self.gravity_in_C(q + self.dt * (qd_d + self.lam * (q_d - q))).tolist()
        tau, q_d, qd_d, qdd_d = (np.asarray(x, dtype=float).tolist()
                                 for x in (tau, q_d, qd_d, qdd_d))
        return [self._packet(k + 1, PacketType.COMM_D,
                             pack_comm_d(tau[k], g[k], q_d[k], qd_d[k], qdd_d[k], int(cpr)))
                for k, cpr in enumerate(self.counts_per_rev.tolist())]

    def initial_packets(self, q0) -> list[Send]:
        """Comm D before period 0: gravity for the first VDC run, zero torque, rest."""
        z = np.zeros(self.n)
        return self._comm_d(z, np.asarray(q0, float), np.asarray(q0, float), z, z)
