"""The ``model`` backend: the nodes' bit-exact references at transaction level.

Same master, same plant, same plant step, same seed as :class:`cosim.closed_loop.ClosedLoop`
on the gateware; the gateware is replaced by

* one :class:`~hdl.node.core_ref.NodeModel` per node (:class:`~cosim.model_node.FastNode`:
  period timer, ticks, joint engine, VDC, watchdog, replies), bit-exact and cycle-exact with
  :class:`~hdl.node.core.NodeCore` given the same events;
* one :class:`~cosim.model_node.EncoderEvents` per node: the encoder interface
  (synchronizer, glitch filter, ×4 decoder, M/T velocity estimator) computed from the
  plant's count changes event by event, equal to
  :class:`~hdl.node.encoder_ref.EncoderModel` cycle for cycle;
* a link whose only job is the timeline (:mod:`cosim.model_link`): when each packet's last
  byte reaches each node's core and when each reply reaches the master. These are
  approximations: every node event (the observation port, :attr:`NodeModel.events
  <hdl.node.core_ref.NodeModel.events>`) lies within :data:`~cosim.model_link.EVENT_TOLERANCE`
  cycles of the gateware's. The boundary, the commit and the VDC's durations are exact.

It is the gateware side of the one loop (:class:`cosim.closed_loop.ClosedLoop` runs it
through :class:`cosim.gateware_side.GatewareSide`, at packet level like the other backends):
the master's packets leave at the cycle they are due, the loop splits its plant step there,
and a reply reaches the master in the piece of the step it arrives in.

Why the results are nonetheless the gateware's, bit for bit: the node acts on its own period
timer and on packet *contents* (docs/node.md "Timing"). The torque at every plant step and every
reply payload depend on when packets arrive only through conditions the model checks with a
margin: time-codes inside the sync window, Comm B after the snapshot, every Comm D before the
commit phase, the ARM before the boundary that should arm, no watchdog silence. A run where one
of these is near its edge, or a time-code resynchronises a node, is reported
(:attr:`ModelBackend.violations`, and :class:`ModelAssumptionError` with ``strict=True``); its
results may then differ from the gateware's by the latency error.

Lazy evaluation (``ModelBackend(lazy=True)``, the default). The plant samples the torque
words once per plant step (500 cycles, 10 control ticks), so a tick whose torque the next tick
overwrites before anything reads it (the plant's sample, a boundary's snapshot, a reply, the
watchdog's ramp) need not compute it. Such *dead* ticks run in one call per plant step and
node: in VDC and torque mode the joint's state is ``(q_des, v_des)`` from Part B, a function of
the committed Comm D words and the tick's time only, so only the last dead tick's Part B is
kept (applied by the next tick that computes); in PID mode the integral carries from tick to
tick and is updated on every one (exact integer arithmetic, same roundings, the clip where it
binds). Their velocity strobes are deferred and folded into the next real sample
(:meth:`EncoderEvents.defer <cosim.model_node.EncoderEvents.defer>`), and the encoder
interfaces take the plant's count changes (:meth:`Plant.encoder_changes
<models.plant.Plant.encoder_changes>`) instead of per-cycle arrays. ``lazy=False`` keeps the
eager path (every tick, every strobe, per-cycle counts);
both give the same plant trace, torque words, replies and node state bit for bit
(tests/test_model_backend.py, 200 ms of the quintic per controller and a clipped PID
integral).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from mrm_cosim.cosim.gateware_side import GatewareSide, Observed, PlantLines, Reply
from mrm_cosim.cosim.model_link import LINK_UP_CYCLE, LinkTiming
from mrm_cosim.cosim import model_kernel_src as ksrc
from mrm_cosim.cosim import pin_shim
from mrm_cosim.cosim.model_kernel import (KernelArrays, KernelEncoder, KernelNode,
                                          KernelVdc, kernel_choice, load, load_plant)
from mrm_cosim.errors import InputError
from mrm_cosim.cosim.model_node import EncoderEvents, FastNode
from mrm_cosim.hdl.node.core_ref import NodeModel
from mrm_cosim.protocol import packet as ref
from mrm_cosim.hdl.node.joint_ref import JointModel
from mrm_cosim.protocol.encoder import encoders_per_node
from mrm_cosim.protocol.joint_program import JointParams, pid_shifts_per_node
from mrm_cosim.protocol.fixed import FORCE
from mrm_cosim.protocol.regs import Config, NodeEvent

_COMMIT = int(Config.COMMIT)
_FORCE_LSB = FORCE.decode(1)                # 2^−13: FORCE.decode(w) = w · this, exactly
#: the observation port's flags by value: their names (what the master is handed)
_EVENT_NAMES = {int(f): f.name for f in NodeEvent}


def _arrival(e):
    """An inbox entry's order: its cycle, then its sequence."""
    return e[0], e[1]

__all__ = ["ModelBackend", "ModelAssumptionError"]

_MARGIN = 500           # cycles of margin the model wants around every timing condition


def _near_window(node, c: int, phase: int, window: int) -> bool:
    """A time-code in node cycle ``c`` at ``phase`` within the margin of the sync window's
    edge: the window after the boundary, and with TC_DISCIPLINE on the one before it too
    (``rem = PERIOD + adj − phase`` cycles to the boundary, :mod:`protocol.discipline`)."""
    m = min(_MARGIN, window // 2)
    if not node._disciplined:
        return window - phase < m
    return abs(phase - window) < m or abs(node.next_boundary() - c - window) < m


class ModelAssumptionError(RuntimeError):
    """A model run left the conditions under which it equals the gateware."""


class ModelBackend(GatewareSide):
    """The ``model`` backend: the gateware side of the loop on the nodes' references.

    Parameters
    ----------
    encoder : EncoderParams or sequence of EncoderParams, optional
        The nodes' encoder interface: one for every node or one per node, as
        :class:`hdl.system.System` takes it (default: the gateware's default for every node).
    pid_shift : int or sequence of int
        The nodes' PID gain shifts, as :class:`hdl.system.System` takes them.
    strict : bool
        Raise :class:`ModelAssumptionError` at the first violated condition instead of
        recording it in :attr:`violations`.
    lazy : bool
        Compute only the ticks whose torque is observed (:attr:`FastNode.lazy
        <cosim.model_node.FastNode.lazy>`) and feed the encoder interfaces the plant's count
        changes instead of per-cycle arrays. ``False`` is the eager path: every tick computed,
        per-cycle counts; both give the same results bit for bit.
    kernel : {"numba", "python"}, optional
        Where the plain part of each plant step runs (lazy only): the compiled inner loop
        (:mod:`cosim.model_kernel`, the default; the pure-Python path with a warning where
        numba cannot run) or the references in Python. Default ``$MRM_MODEL_KERNEL``, else
        numba. Same results bit for bit.
    clocks : cosim.clocks.ClockPlan, optional
        A clock per node (docs/clocks.md "The model backend"): each node's reference runs in
        cycles of its own clock (:meth:`_run_clocked`), on the pure-Python path; None: one
        clock.

    Attributes
    ----------
    nodes : list of FastNode
    encoders : list of EncoderEvents
    phases : dict
        Latest modelled arrival phase (cycles) of a time-code and of a Comm D, over the run.
    """

    name = "model"

    def __init__(self, encoder=None, strict: bool = False, lazy: bool = True, pid_shift=0,
                 kernel: str | None = None, faults=(), clocks=None):
        for f in faults:
            if f.kind != "cut":
                raise InputError("faults", f"the model backend's link has no bits: it takes "
                                 f"'cut' faults, not {f.kind!r} (use compiled or pysim)")
        self._faults = list(faults)
        #: a clock per node (:class:`cosim.clocks.ClockPlan`; None: one clock): the nodes run
        #: on the pure-Python path, each in cycles of its own clock ("Clocks of their own")
        self.clocks = clocks
        self._times = None
        #: node strobes merged into a master cycle that held the same one (docs/clocks.md)
        self.merged_strobes = 0
        self.kernel = "python" if clocks is not None else kernel_choice(kernel)
        self._kern = None
        self._encoder = encoder
        self._pid_shift = pid_shift
        self.strict = strict
        self.lazy = bool(lazy)
        self._violations: list[str] = []
        self.phases = {"timecode": 0, "comm_d": 0}
        self.cycle = 0
        self.n = 0
        self.nodes: list[FastNode] = []
        self.encoders: list[EncoderEvents] = []
        self._start: int | None = None
        self._early_configs: list[tuple[int, int]] = []   # (node, cycle) before period 0 known

    # --- GatewareSide ----------------------------------------------------------------------
    @property
    def violations(self) -> list[str]:
        return self._violations

    def power_on(self, counts) -> None:
        counts = [int(c) for c in counts]
        self.n = len(counts)
        if self.clocks is not None:
            from mrm_cosim.cosim.clocks import NodeTime

            if self.clocks.n_domains != self.n + 1:
                raise InputError("clocks", f"a plan of {self.clocks.n_domains - 1} nodes for "
                                 f"a chain of {self.n}")
            self._times = [NodeTime(self.clocks, k + 1) for k in range(self.n)]
        encs = encoders_per_node(self._encoder, self.n)
        kern = load() if self.lazy and self.kernel == "numba" else None
        self._kern = kern
        node_cls = FastNode if kern is None else KernelNode
        self.nodes = [node_cls(encoder=enc, joint=JointModel(JointParams.zero(pid_shift=s)))
                      for enc, s in zip(encs, pid_shifts_per_node(self._pid_shift, self.n),
                                        strict=True)]
        if kern is None:
            self.encoders = [EncoderEvents(enc, c) for enc, c in zip(encs, counts, strict=True)]
        else:
            self._arrays = arrays = KernelArrays(self.n)
            self.encoders = [KernelEncoder(kern, arrays, k, enc, c)
                             for k, (enc, c) in enumerate(zip(encs, counts, strict=True))]
            for k, node in enumerate(self.nodes):
                node.bind(arrays, k, kern)
                KernelVdc.adopt(node.vdc)
            self._plain = np.zeros(self.n, dtype=np.int64)     # (plain_step: 1 where plain)
            self._chg_lines = None
            self._fed = 0
            # the fast path's floats: the plant's constants, then the torque outputs
            self._F = np.zeros(ksrc.f_size(self.n))
            self._no_a, self._no_M = np.zeros(self.n), np.zeros((self.n, self.n))
            self._no_brake = np.zeros(self.n, dtype=bool)      # (brake(): read only)
            self._no_brake.flags.writeable = False
        self._horizon_end = None        # fast path: _horizon's (None: recompute)
        self._commits = []              # fast path: _horizon's plain commits (node, cycle)
        self._armed = []                # fast path: those a run armed in the kernel
        self._send_at = None            # send_ahead: the cycle send() sends at (None: now)
        self._fast_seen = None          # fast path: what reached the master (fast_observed)
        #: plant steps the fast path ran, by how the plant step ended (free, stick-slip: the
        #: likely pattern or stuck, the general solve)
        self.fast_steps = {"free": 0, "stick-slip": 0, "solve": 0}
        #: fast runs whose last step handed replies or strobes to the master (fast_observed)
        self.fast_handovers = 0
        #: plant steps the kernel ran on with pinocchio from compiled code (cosim.pin_shim)
        self.pin_steps = 0
        #: fast runs whose last step had node events (its nodes on the general path, _fast)
        self.event_steps = 0
        self._fast_end = 0              # fast path: the end of its last step (node._done)
        for node, encoder in zip(self.nodes, self.encoders, strict=True):
            node.lazy = self.lazy
            node.events = []                    # the observation port, for the timeline
            node.attach(encoder)
        self._samplers = [e.sample for e in self.encoders]
        self._link = LinkTiming(self.n)
        # (the kernel writes the plain nodes' torques)
        self._torque = np.zeros(self.n) if kern is None else \
            self._F[ksrc.F_SIZE + self.n:ksrc.F_SIZE + 2 * self.n]

    def attach_plant(self, plant) -> None:
        """With the compiled kernel, the plant's step runs on it too
        (:meth:`Plant.use_kernel <models.plant.Plant.use_kernel>`, same results bit for bit)."""
        if self._kern is not None and getattr(plant, "_kern", None) is None:
            kern = load_plant()
            if kern is not None:
                plant.use_kernel(kern)

    @property
    def link_up(self) -> bool:
        return self.cycle >= LINK_UP_CYCLE

    @property
    def torque(self) -> np.ndarray:
        return self._torque

    def brake(self) -> np.ndarray:
        """The nodes' ``brake`` outputs in the last cycle run
        (:meth:`NodeModel.brake_at <hdl.node.core_ref.NodeModel.brake_at>`). A node whose
        state the compiled kernel holds is not in a safe stop (:meth:`FastNode.safe_stop_near
        <cosim.model_node.FastNode.safe_stop_near>` keeps those on the reference), so its
        brake is its trip with STOP_CYCLES = 0: tripped by then."""
        c = self.cycle - 1
        if self._times is not None:             # each node's last cycle of master cycle c
            out = []
            for node, tm in zip(self.nodes, self._times, strict=True):
                nc = tm.node_cycle(self.cycle) - 1
                node._watch(nc)
                out.append(bool(node.brake_at(nc)))
            return np.array(out, dtype=bool)
        if self._kern is not None:
            for node in self.nodes:
                if not node.in_kernel:
                    break
            else:               # every node in the kernel: none brakes, the usual case, or
                if not self._kern.any_trip(self._arrays.N, c):      # the list below
                    return self._no_brake
        out = []
        for node in self.nodes:
            if getattr(node, "in_kernel", False):
                item = node._row.item           # (Python ints: no numpy scalar arithmetic)
                out.append(bool(item(ksrc.N_TRIPPED)) or bool(
                    node.armed and c >= item(ksrc.N_LAST_PACKET) + 2 + item(ksrc.N_TIMEOUT)))
            else:
                node._watch(c)
                out.append(bool(node.brake_at(c)))
        return np.array(out, dtype=bool)

    def send(self, action) -> None:
        self._horizon_end = None
        at = self.cycle if self._send_at is None else self._send_at
        self._link.send(action, at)

    def send_ahead(self, due: int, end: int) -> bool:
        """With the compiled kernel, no line cut and the step to ``end`` plain for every node
        (:meth:`_horizon`, before the packets are sent) with nothing reaching the master before
        ``due``: the nodes run the cycles before ``due`` as they would without the packets
        (each is taken after its frame time, after ``due``), and the master learns nothing in
        them, so it may poll at ``due`` first. :meth:`send` then sends at ``due``, until the
        next :meth:`advance` or fast run."""
        if self._kern is None or self._link.cuts or self._link.errors:
            return False
        hz = self._horizon_end
        if hz is None:
            hz = self._horizon_end = self._horizon()
        hard, soon = hz
        if hard < end or soon < due:
            return False
        self._send_at = due
        return True

    async def advance(self, n: int, lines: PlantLines, offset: int = 0) -> Observed:
        self._send_at = None
        start = self.cycle
        end = start + n
        self._horizon_end = None
        if self._fast_end:
            self._sync_done()
        if self._link.errors:                   # a cut's codec errors, before the nodes reply
            self._count_cuts(end)
        if self._times is not None:
            events = self._run_clocked(start, n, lines, offset)
        elif self._kern is not None:
            events = self._run_kernel(start, n, lines, offset)
        elif self.lazy:
            changes = lines.changes()
            whole = offset == 0 and (lines.at_rest or n == self._step_len(lines))
            for k, enc in enumerate(self.encoders):
                ch = changes[k] if whole else [(i - offset, c) for i, c in changes[k]
                                               if offset <= i < offset + n]
                enc.feed_changes(start, n, ch)
        else:
            for k, enc in enumerate(self.encoders):
                enc.feed(start, np.full(n, lines.counts[k]) if lines.at_rest
                         else lines.cycles().counts[offset:offset + n, k])
        if self._kern is None and self._times is None:
            events = self._run_nodes(end)
        if self._link.errors:
            self._count_cuts(end)
        replies = [Reply(c, src, ptype, seq, bytes(payload))
                   for c, src, ptype, payload, seq in self._link.replies_before(end)]
        self.cycle = end
        return Observed(events, replies)

    def _count_cuts(self, end: int) -> None:
        """What line cuts made the nodes count before ``end`` (codec errors, router discards)
        into their link health (what their next Comm A reports), and the master port's codec
        errors."""
        later = []
        for c, k, side in self._link.errors:
            if c >= end:
                later.append((c, k, side))
            elif k == 0:
                self.link_errors += 1
            else:
                node = self.nodes[k - 1]
                up, down, rx, dropped = node.link_health
                if side == "up":
                    up = min(up + 1, 0xFFFF)
                elif side == "down":
                    down = min(down + 1, 0xFFFF)
                else:                           # "router": a packet its router discarded
                    dropped = min(dropped + 1, 0xFFFF)
                node.link_health = (up, down, rx, dropped)
        self._link.errors = later

    def begin(self, cycle: int, period_cycles: int) -> None:
        self._start = cycle
        for f in self._faults:                  # line cuts (cosim.model_link), from period 0
            if f.node > self.n:
                raise InputError("fault.node", f"the robot has {self.n} nodes, not {f.node}")
            self._link.cut(f.node, cycle + f.cycle, f.cycles)
        for k, c in self._early_configs:
            if c >= cycle - _MARGIN:
                self._violate(f"node {k + 1}: CONFIG {c - cycle} cycles before period 0 (an "
                              "ARM may miss its boundary)")
        self._early_configs = []
        for k, node in enumerate(self.nodes):
            if node.config[Config.PERIOD] != period_cycles or cycle % node.config[Config.PERIOD]:
                self._violate(f"node {k + 1}: PERIOD {node.config[Config.PERIOD]} and period 0 "
                              f"at cycle {cycle} are not the master's grid")

    def finish(self) -> None:
        if self._fast_end:
            self._sync_done()
        if self._kern is not None:
            for node in self.nodes:
                node.pull()
        for k, node in enumerate(self.nodes):
            if node.tripped:
                self._violate(f"node {k + 1}: the watchdog tripped")

    # --- the fast path ---------------------------------------------------------------------
    def fast_path(self, plant, rec):
        """With the compiled kernel and the plant on it (:meth:`attach_plant`): whole plain plant
        steps in two calls each — ``pin.aba`` and :func:`cosim.model_kernel_src.fast_step`
        (the rest of the plant step, the trace row, the count changes, every node's ticks and
        torques, then the next step's :func:`models.plant_kernel_src.pre_free`: only a run's
        first step calls that from Python); the stick-slip solve, where a step needs it, in
        Python between them (:meth:`Plant.kernel_parts
        <models.plant.Plant.kernel_parts>`, taken once here). A step stuck on the ``(q, v)``
        of the last ``nonLinearEffects`` and ``crba`` calls takes their results from the
        kernel's stick-slip cache (:func:`cosim.model_kernel_src.stick_cache`), and the kernel
        runs such steps on by itself while they stay plain steps of the run (:attr:`_X`;
        :attr:`stick_cached` counts them). A step is plain when it ends at or before every
        node's next special cycle (:meth:`FastNode.next_special
        <cosim.model_node.FastNode.next_special>`) + 1, every packet or time-code reaching a
        node (:meth:`_horizon`). A step in which observation-port strobes or replies reach the
        master ends the run: :meth:`fast_observed` hands them over, as :meth:`advance` would
        at the end of that step (the master is quiet in it: it learns of them at the step's
        end on either path). The same operations as :meth:`_run_kernel` and
        :meth:`Plant.step <models.plant.Plant.step>` in the same order, so the same results bit
        for bit (tests/test_model_backend.py, tests/test_model_kernel.py). The compliant plant
        (:class:`~models.compliant.CompliantPlant`) has its own: :meth:`_fast_compliant`.

        With pinocchio from compiled code (:mod:`cosim.pin_shim`: a library built on first use
        calling the ``pin`` wheel's own ``aba``, ``nonLinearEffects`` and ``crba`` on a copy
        of the plant's model, checked against ``pin`` bit for bit), the kernel makes those
        calls itself and runs on through the run's plain steps (``fast_step``'s steps run on,
        counted in :attr:`pin_steps`), handing a step back to Python only for the general
        solve; the same operations in the same order, so the same results."""
        from mrm_cosim.models.compliant import CompliantPlant, compiled_kernel
        from mrm_cosim.models.plant import Plant

        if self._kern is None or getattr(plant, "_kern", None) is None:
            return None
        cls = type(plant)
        compliant = cls is CompliantPlant and plant._kern is compiled_kernel()
        if not compliant and (cls.step is not Plant.step or
                              cls._step_kernel is not Plant._step_kernel or
                              cls.kernel_parts is not Plant.kernel_parts):
            return None                 # a plant whose step is not this one's: its own step
        if plant.cycles_per_step > ksrc.CHANGE_CAP or \
                rec.shape[0] != 2 or rec.shape[2] != self.n or rec.dtype != np.float64:
            return None
        F = self._F
        F[ksrc.F_H] = plant.dt
        F[ksrc.F_HH] = 0.5 * plant.dt
        F[ksrc.F_FRICTION] = 1.0 if plant.friction_on else 0.0
        F[ksrc.F_SIZE:ksrc.F_SIZE + self.n] = plant.counts_per_rad
        self._arrays.IB[ksrc.H_CYCLES] = plant.cycles_per_step
        # the stick-slip cache (model_kernel_src.stick_cache): empty for a new plant
        n = self.n
        self._X = X = np.zeros(1 + 3 * n + n * n)
        self._X_M = X[1 + 3 * n:].reshape((n, n))
        #: stick-slip steps that took pinocchio's bias and matrix from the cache
        self.stick_cached = 0
        pk = load_plant()
        step = plant.cycles_per_step
        run = self._fast_compliant if compliant else self._fast
        # the rigid plant's parts, once: its arrays, pinocchio's model and data and the bound
        # methods stay those of use_kernel (a compliant plant's reset rebinds its state and
        # noise stream: asked each run)
        self._parts = None if compliant else plant.kernel_parts()
        # pinocchio from compiled code (cosim.pin_shim): the kernel runs on through steps
        # that need aba, or nonLinearEffects and crba, too (fast_step's _pin_step)
        IB = self._arrays.IB
        IB[ksrc.H_PIN_FN] = IB[ksrc.H_PIN_MODEL] = IB[ksrc.H_RUN_PIN] = 0
        dyn = pin_shim.load()
        handle = dyn.model(plant._model) if dyn is not None else None
        if handle:
            IB[ksrc.H_PIN_FN], IB[ksrc.H_PIN_MODEL] = dyn.fn, handle
            self._pin_model = plant._model          # (the handle lives as long)

        def fast(i: int, stop: int, cycle: int, end_limit: int) -> int:
            return run(plant, pk, rec, step, i, stop, cycle, end_limit)

        return fast

    def _horizon(self) -> tuple[int, int]:
        """``(end, soon)``: the latest end of a plain step from now, and the first cycle of a
        strobe or reply for the master (a run stops after the step holding it;
        :meth:`fast_path`). A node's plain commit point (:meth:`KernelNode.kernel_commit
        <cosim.model_kernel.KernelNode.kernel_commit>`) does not end plain steps: it goes into
        :attr:`_commits` for a run to arm, and its COMMIT strobe, if a Comm D is pending,
        into ``soon``."""
        end = soon = ksrc.NEVER
        inbox = self._link.inbox
        commits = []
        for k, node in enumerate(self.nodes):
            x = node.next_special()
            if x == node._lb + node.config[_COMMIT]:
                kc = node.kernel_commit()       # a plain commit: the kernel takes it
                if kc is not None and kc[0] == x:
                    commits.append((node, x))
                    if node.d_pending and x < soon:
                        soon = x                # its COMMIT strobe reaches the master
                    x = kc[1]
            x += 1
            for e in inbox[k]:
                if e[0] < x:
                    x = e[0]
            if x < end:
                end = x
            for c, _ in node.events:
                if c < soon:
                    soon = c
        for r in self._link.replies:
            if r[0] < soon:
                soon = r[0]
        self._commits = commits
        return end, soon

    def fast_observed(self) -> Observed | None:
        """What reached the master in the last fast run's last step (:meth:`fast_path`), once;
        None if nothing did."""
        seen, self._fast_seen = self._fast_seen, None
        return seen

    def _fast_compliant(self, plant, pk, rec, s: int, i: int, stop: int, cycle: int,
                        lim: int) -> int:
        """:meth:`fast_path`'s callable on the compliant plant (:meth:`CompliantPlant.step
        <models.compliant.CompliantPlant.step>` compiled, :func:`cosim.model_kernel_src.
        fast_step_compliant`): every step completes in two calls — ``pin.aba`` and the kernel —
        and the current-sensor noise of the run's steps is drawn from the plant's stream in
        one call before them (the same values, in the order the plant's own step draws
        them)."""
        hard, soon = self._fast_limits(ksrc.NEVER)
        plain_lim = hard if hard < lim else lim
        events_ok = not (self._link.cuts or self._link.errors)
        if i >= stop or cycle + s > lim or (cycle + s > plain_lim and
                                            not (events_ok and cycle <= soon)):
            return 0
        # the steps this run takes unless one fails (the loop's own bounds): the plain ones,
        # then (_fast) the step with node events where it may; their noise in one draw: the
        # stream's next values in the order the plant's step draws them
        p = min(stop - i, max(0, plain_lim - cycle) // s, max(0, soon - cycle) // s + 1)
        end_p = cycle + p * s
        event = events_ok and p < stop - i and end_p <= soon and end_p + s <= lim
        m = p + event
        self._fast_begin(cycle, plain_lim)
        S, C, model, data, qm, vm, force, noise, stepped = plant.kernel_parts()
        ck = plant._kern
        IB, F, tau = self._arrays.IB, self._F, self._torque
        h, hh = float(F[ksrc.F_H]), float(F[ksrc.F_HH])
        friction = F[ksrc.F_FRICTION] != 0.0
        fast_step, aba, pre = self._kern.fast_step_compliant, pin.aba, ck.pre
        z = noise(m)
        # the kernel runs on through the plain steps with pinocchio from compiled code (its
        # own aba calls): the rows it may, and those whose noise is drawn
        IB[ksrc.H_C_FIRST] = i
        IB[ksrc.H_C_PLAIN_END] = i + p
        IB[ksrc.H_C_DRAWN_END] = i + m
        j = i
        r = 0
        ready = False           # the step's pre done (by the last fast_step_compliant call)
        while j - i < m:
            if not ready and not pre(S, C, tau, z[j - i], h, hh, friction):
                raise InputError("tau_cmd", f"must be finite, not {tau.tolist()!r}")
            if j - i == p:                      # the step with node events
                r = fast_step(IB, F, S, aba(model, data, qm, vm, force), rec, j, cycle, C, z,
                              -1)
                j += 1
                if r == 0:
                    stepped(j - i)
                    return self._event_step(j - i, cycle, s, 0, 0)
                break
            r = fast_step(IB, F, S, aba(model, data, qm, vm, force), rec, j, cycle, C, z,
                          1 if j + 1 - i < m else 0)
            if r >= 64:                 # k more steps run on in the kernel
                k = r >> 6
                r &= 63
                j += k
                cycle += k * s
            j += 1
            cycle += s
            if r == 8:
                raise InputError("tau_cmd", f"must be finite, not {tau.tolist()!r}")
            if r == 24:
                ready = True
                continue
            ready = False
            if r or cycle > soon:
                break
        stepped(j - i)
        self._count_steps(j - i, 0, 0)
        if j - i != m and r not in (2, 3):
            raise AssertionError(f"model kernel: {j - i} compliant steps run, {m} drawn")
        return self._fast_end_run(plant, r, cycle, soon, j - i)

    def _fast(self, plant, pk, rec, s: int, i: int, stop: int, cycle: int, lim: int) -> int:
        """:meth:`fast_path`'s callable. Its plain steps end at the horizon (:meth:`_horizon`);
        where the master stays quiet to the end of the step after them (``lim``), no line is
        cut and nothing reached the master before it, that step runs too, as the run's last:
        its plant part in the kernel as a plain step's (``fast_step``'s ``pre_next`` −1), its
        nodes as :meth:`advance` runs them (:meth:`_run_kernel` on the count changes the kernel
        left), what reached the master handed over at its end (:meth:`fast_observed`) — what
        the general step does, in the same order, without the loop's general step around it
        (:attr:`event_steps`)."""
        hard, soon = self._fast_limits(ksrc.NEVER)
        plain_lim = hard if hard < lim else lim
        # a last step with node events: the master quiet through it, no cut, nothing for the
        # master before it (the plain steps' own stop)
        events_ok = not (self._link.cuts or self._link.errors)
        if i >= stop or cycle + s > lim or (cycle + s > plain_lim and
                                            not (events_ok and cycle <= soon)):
            return 0
        more_lim = lim if events_ok else plain_lim
        self._fast_begin(cycle, plain_lim)
        S, C, model, data, qm, vm, force, solve, stepped = self._parts     # (fast_path's)
        IB, F, tau = self._arrays.IB, self._F, self._torque
        hh = float(F[ksrc.F_HH])
        friction = float(F[ksrc.F_FRICTION])
        pre_free, fast_step = pk.pre_free, self._kern.fast_step
        aba, nle, crba = pin.aba, pin.nonLinearEffects, pin.crba
        no_a, no_M = self._no_a, self._no_M     # (zeros: read, never written)
        X = self._X
        # the run's bounds, for the steps fast_step runs on (its _run_on), and its counts of
        # those that took the stick-slip path
        IB[ksrc.H_STOP] = stop
        IB[ksrc.H_MORE_LIM] = more_lim
        IB[ksrc.H_SOON] = soon
        IB[ksrc.H_PLAIN_LIM] = plain_lim
        IB[ksrc.H_RUN_STICK] = IB[ksrc.H_RUN_CACHED] = 0
        j = i
        r = 0
        n_stick = n_solve = 0
        code = None             # the step's pre_free result, where the last fast_step ran it
        event_step = False
        while j < stop and cycle + s <= lim:
            if cycle + s > plain_lim:           # the step with node events: the run's last
                if not events_ok:
                    break
                event_step = True
                more = -1
            else:
                # the next step runs here too: fast_step runs its pre_free (one call less)
                more = 1 if (j + 1 < stop and cycle + 2 * s <= more_lim
                             and cycle + s <= soon) else 0
            if code is None:
                code = pre_free(S, C, tau, hh, friction)
            if code == 1:
                r = fast_step(IB, F, S, aba(model, data, qm, vm, force), no_M, rec, j, cycle, 1,
                              C, more, X)
            elif code == 0:
                r = 1
            elif code == 2:             # stuck, on the (q, v) of the cache's pinocchio calls
                r = 5
            else:
                raise InputError("tau_cmd", f"must be finite, not {tau.tolist()!r}")
            if r == 1:                  # the stick-slip solve (crba also where stuck needs
                bias = nle(model, data, qm, vm)     # none: it changes nothing they read, and
                M = crba(model, data, qm)           # calling it only where stuck fails costs
                n_stick += 1                        # a second fast_step call there: measured,
                # no gain on mrm3, 1-2 % slower on mrm6, where stuck fails on most of them)
                r = fast_step(IB, F, S, bias, M, rec, j, cycle, 2, C, more, X)
                if r == 4:
                    n_solve += 1
                    solve(M)
                    r = fast_step(IB, F, S, no_a, no_M, rec, j, cycle, 0, C, more, X)
            elif r == 5:                # the same, on the cache's bias and matrix (the same
                n_stick += 1            # values pinocchio would return: no call)
                self.stick_cached += 1
                r = fast_step(IB, F, S, no_a, no_M, rec, j, cycle, 3, C, more, X)
                if r == 4:
                    n_solve += 1
                    solve(self._X_M.copy())             # (solve writes its lower triangle)
                    r = fast_step(IB, F, S, no_a, no_M, rec, j, cycle, 0, C, more, X)
            while r >= 64:              # k more steps run in the kernel (fast_step)
                k = r >> 6
                r &= 63
                j += k
                cycle += k * s
                if r != 4:
                    break
                # the last one (row j) needs the general solve, on the cache's matrix
                n_solve += 1
                solve(self._X_M.copy())
                more = 1 if (j + 1 < stop and cycle + 2 * s <= more_lim
                             and cycle + s <= soon) else 0
                r = fast_step(IB, F, S, no_a, no_M, rec, j, cycle, 0, C, more, X)
            j += 1
            if event_step:
                if r == 0:
                    stepped(j - i)
                    n_stick += self._run_counts()
                    return self._event_step(j - i, cycle, s, n_stick, n_solve)
                break
            if r >= 8:                  # done, and the next step's pre_free with it
                code = (r >> 3) - 2
                cycle += s
                continue
            if r:
                break
            code = None
            cycle += s
            if cycle > soon:            # a strobe or a reply for the master in this step
                break
        stepped(j - i)
        self._count_steps(j - i, n_stick + self._run_counts(), n_solve)
        return self._fast_end_run(plant, r, cycle, soon, j - i)

    def _run_counts(self) -> int:
        """The stick-slip steps the kernel ran on in this run (``fast_step``'s counts): their
        number; those on the cache added to :attr:`stick_cached`."""
        IB = self._arrays.IB
        cached = int(IB[ksrc.H_RUN_CACHED])
        self.stick_cached += cached
        return int(IB[ksrc.H_RUN_STICK]) + cached

    def _count_steps(self, steps: int, n_stick: int, n_solve: int) -> None:
        IB = self._arrays.IB
        self.pin_steps += int(IB[ksrc.H_RUN_PIN])
        IB[ksrc.H_RUN_PIN] = 0
        counts = self.fast_steps
        counts["free"] += steps - n_stick
        counts["stick-slip"] += n_stick - n_solve
        counts["solve"] += n_solve

    def _event_step(self, steps: int, cycle: int, s: int, n_stick: int, n_solve: int) -> int:
        """The nodes' part of a fast run's last step, from ``cycle``, with node events
        (:meth:`_fast`): the plant's part done by the kernel, its count changes in the
        kernel's arrays. The run's armed commits taken or disarmed first (the general path
        takes the latter), the nodes brought to ``cycle`` as :meth:`advance` finds them, then
        :meth:`_run_kernel`'s nodes; what reached the master by the step's end kept for
        :meth:`fast_observed`. Returns the run's steps."""
        self._count_steps(steps, n_stick, n_solve)
        self.event_steps += 1
        self._end_commits()
        self.cycle = self._fed = self._fast_end = cycle
        self._sync_done()
        self._chg_lines = None                  # (the kernel's changes: no PlantLines)
        end = cycle + s
        events = self._run_kernel_nodes(cycle, s, 0)
        replies = [Reply(c, src, ptype, seq, bytes(payload))
                   for c, src, ptype, payload, seq in self._link.replies_before(end)]
        self.cycle = self._fed = self._fast_end = end
        self._horizon_end = None
        self._send_at = None
        if events or replies:
            self.fast_handovers += 1
            self._fast_seen = Observed(events, replies)
        return steps

    def _fast_limits(self, lim: int) -> tuple[int, int]:
        """A fast run offered: ``(lim, soon)``, the run's last end cycle (``lim``
        or the horizon's, if earlier) and the first cycle of something for the master
        (:meth:`_horizon`)."""
        hz = self._horizon_end
        if hz is None:
            hz = self._horizon_end = self._horizon()
        hard, soon = hz
        if hard < lim:
            lim = hard
        return lim, soon

    def _fast_begin(self, cycle: int, reach: int) -> None:
        """A fast run starts at ``cycle``, its plain steps ending by ``reach``: the nodes' rows
        pushed into the kernel, the commits they may pass armed. Raises if the backend is not
        at ``cycle``."""
        self._send_at = None
        if cycle != self.cycle or cycle != self._fed:
            raise ValueError(f"fast path at cycle {cycle}, the backend at {self.cycle}")
        for node in self.nodes:
            if not node.in_kernel:
                node.push()
        # the horizon's plain commits (_fast_limits just ran) that a plain step of this run
        # can pass (its ticks before reach − 1: the kernel takes it in node_plain)
        self._armed = armed = [(node, c) for node, c in self._commits if c + 1 < reach]
        for node, c in armed:
            node.arm_commit(c)

    def _fast_end_run(self, plant, r: int, cycle: int, soon: int, steps: int) -> int:
        """The end of a fast run of ``steps`` steps ending at ``cycle``, the last kernel call
        having returned ``r``: its errors raised, the backend at ``cycle``, what reached the
        master in the last step kept for :meth:`fast_observed`. The commits the run's
        horizon armed are taken on the objects, or disarmed (:meth:`KernelNode.end_commit
        <cosim.model_kernel.KernelNode.end_commit>`)."""
        self._end_commits()
        if r == 2:                      # the plant stepped, the nodes did not
            PlantLines(plant).changes()         # the reference raises EncoderOverspeed
            raise AssertionError("model kernel: an overspeed the reference missed")
        if r == 3:
            raise RuntimeError("model kernel: an unobserved torque word was sampled")
        self.cycle = self._fed = self._fast_end = cycle
        if cycle > soon:                # hand them over as advance() would at this end
            self._horizon_end = None
            self.fast_handovers += 1
            out = []
            for k, node in enumerate(self.nodes):
                if node.events:
                    self._collect(k, node, cycle, out)
            self._fast_seen = Observed(out, [
                Reply(c, src, ptype, seq, bytes(payload))
                for c, src, ptype, payload, seq in self._link.replies_before(cycle)])
        return steps

    def _end_commits(self) -> None:
        """The commits the run armed taken on the objects, or disarmed
        (:meth:`KernelNode.end_commit <cosim.model_kernel.KernelNode.end_commit>`)."""
        if self._armed:
            taken = False
            for node, c in self._armed:
                taken = node.end_commit(c) or taken
            self._armed = []
            if taken:
                self._horizon_end = None        # (those nodes' next events have moved on)

    def _sync_done(self) -> None:
        """After fast steps: the nodes' ``_done``, as :meth:`_run_kernel` leaves it."""
        last = self._fast_end - 1
        self._fast_end = 0
        for node in self.nodes:
            if node._done < last:
                node._done = last

    # --- conditions ------------------------------------------------------------------------
    def _violate(self, message: str) -> None:
        if self.strict:
            raise ModelAssumptionError(message)
        if len(self._violations) < 100:
            self._violations.append(message)

    def _check_packet(self, k: int, node: NodeModel, c: int, ptype: int,
                      nc: int | None = None) -> None:
        start = self._start
        if start is None or c < start:
            if ptype == ref.PacketType.CONFIG:
                if start is None:                   # judged when period 0 is known
                    self._early_configs.append((k, c))
                elif c >= start - _MARGIN:
                    self._violate(f"node {k + 1}: CONFIG {c - start} cycles before period 0 "
                                  "(an ARM may miss its boundary)")
            return
        cfg = node.config
        if nc is None:
            nc = c                              # (with a clock per node: the node's cycle)
        ph = node.phase(nc)
        if ptype == ref.PacketType.COMM_D:
            self.phases["comm_d"] = max(self.phases["comm_d"], ph)
        if ptype == ref.PacketType.COMM_D and node.armed:
            if abs(ph - cfg[Config.COMMIT]) < _MARGIN:
                self._violate(f"node {k + 1}: Comm D at phase {ph}, within {_MARGIN} cycles of "
                              f"the commit phase {cfg[Config.COMMIT]} (cycle {c})")
        elif ptype in (ref.PacketType.COMM_A, ref.PacketType.COMM_B) and (
                (ptype == ref.PacketType.COMM_B and ph < 100)
                or ph > cfg[Config.PERIOD] - _MARGIN):
            # (a Comm A request leaves the master with the time-code: it cannot overtake the
            # boundary; a Comm B needs the boundary's CORDIC, 60 cycles, in the VDC first)
            self._violate(f"node {k + 1}: {ref.PacketType(ptype).name} at phase {ph} "
                          f"(cycle {c}), too near a boundary")
        if node.armed and nc - node.last_packet > cfg[Config.TIMEOUT] - _MARGIN:
            self._violate(f"node {k + 1}: {nc - node.last_packet} cycles without a packet "
                          f"(watchdog timeout {cfg[Config.TIMEOUT]})")

    # --- the nodes -------------------------------------------------------------------------
    @staticmethod
    def _step_len(lines: PlantLines) -> int:
        return lines.plant.cycles_per_step

    def _run_kernel(self, start: int, n: int, lines: PlantLines, offset: int) -> list:
        """:meth:`advance`'s work with the compiled kernel: the count changes into every
        encoder and the nodes without an event in the piece in one call, the others by the
        reference event loop (:meth:`_run_nodes`)."""
        end = start + n
        if start != self._fed:
            raise ValueError(f"feed must continue at cycle {self._fed}, not {start}")
        self._fed = end
        a = self._arrays
        if lines is not self._chg_lines:            # a new plant step: its count changes
            self._chg_lines = lines
            a.CUR[:] = 0
            if lines.at_rest:
                a.NCH[:] = 0
            else:
                plant = lines.plant
                if self._kern.step_changes(np.array(plant.motion()), plant.counts_per_rad,
                                           plant.dt, plant.cycles_per_step, a.CHC, a.CHN,
                                           a.NCH):
                    lines.changes()                 # the reference raises EncoderOverspeed
                    raise AssertionError("model kernel: an overspeed the reference missed")
        return self._run_kernel_nodes(start, n, offset)

    def _run_kernel_nodes(self, start: int, n: int, offset: int) -> list:
        """:meth:`_run_kernel`'s nodes, the step's count changes in the kernel's arrays."""
        a = self._arrays
        end = start + n
        plain = self._plain
        inbox = self._link.inbox
        others = None
        last = end - 1
        for k, node in enumerate(self.nodes):
            box = inbox[k]
            first = ksrc.NEVER
            for e in box:
                if e[0] < first:
                    first = e[0]
            if node.next_special() >= last and first >= end:
                plain[k] = True
                if not node.in_kernel:
                    node.push()
                if node._done < last:
                    node._done = last
            else:               # (KernelNode.run pulls the row where the event loop needs it)
                plain[k] = False
                others = [k] if others is None else others + [k]
        if self._kern.plain_step(a.N, a.P, a.E, a.VIS, a.PIPE, a.DUE, a.PEND, plain, start, n,
                                 offset, a.CHC, a.CHN, a.NCH, a.CUR, self._torque):
            raise RuntimeError("model kernel: an unobserved torque word was sampled")
        if others is None:
            out = []
            for k, node in enumerate(self.nodes):
                if node.events:
                    self._collect(k, node, end, out)
            return out
        return self._run_nodes(end, others)

    def _run_nodes(self, end: int, which=None) -> list:
        """Every node's events of cycles < ``end``; torque words output in cycle ``end − 1``.
        Returns the observation-port strobes before ``end`` ``(cycle, node, name)``.
        ``which``: only these nodes (the others' events are still collected)."""
        out = []
        stay = {"stay": True} if self._kern is not None else {}   # (KernelNode: no row copies)
        for k, node in enumerate(self.nodes):
            if which is not None and k not in which:
                self._collect(k, node, end, out)
                continue
            sample = self._samplers[k]
            if self._link.inbox[k]:
                self._inbox(k, node, end, sample, stay)
            if self._kern is not None:             # (FORCE.decode: w · 2^lsb, exact)
                self._torque[k] = node.run_torque(end - 1, sample) * _FORCE_LSB
            else:
                node.run(end - 1, sample)
                self._torque[k] = FORCE.decode(node.torque_at(end - 1))
            self._collect(k, node, end, out)
        return out

    def _inbox(self, k: int, node, end: int, sample, stay: dict, tm=None) -> None:
        """Node ``k``'s inbox before master cycle ``end`` into the node: each time-code (its
        phase against the sync window checked, a resync reported) and each packet (the
        timing conditions checked, its reply queued on the link). ``tm``: the node's
        :class:`~cosim.clocks.NodeTime` (clocks of their own: a delivery in master cycle ``c``
        reaches the node in ``tm.node_cycle(c)``, a reply leaves in the master cycle of its
        node cycle), None on one clock."""
        box = self._link.inbox[k]
        if len(box) > 1:
            box.sort(key=_arrival)
        start = self._start
        i = 0
        while i < len(box) and box[i][0] < end:
            cm, _, kind, data = box[i]
            c = cm if tm is None else tm.node_cycle(cm)
            i += 1
            if kind == "timecode":
                node.run(c, sample, **stay)
                ph_before = node.phase(c) if c < node.next_boundary() else 0
                window = node.config[Config.SYNC_WINDOW]
                if start is not None and cm >= start:
                    self.phases["timecode"] = max(self.phases["timecode"], ph_before)
                if node.timecode(c, data, sample, **stay):
                    self._violate(f"node {k + 1}: time-code at phase {ph_before} "
                                  f"(cycle {cm}) resynchronised the timer")
                elif _near_window(node, c, ph_before, window):
                    self._violate(f"node {k + 1}: time-code at phase {ph_before}, "
                                  f"near the sync window {window}")
                continue
            ptype, payload, seq = data
            node.run(c + 1, sample, **stay)     # (what run(c), then run(c + 1) do)
            self._check_packet(k, node, cm, ptype, c)
            reply = node.packet(c, ptype, payload, sample=sample, **stay)
            if reply is not None:
                ready = node.reply_cycle(c, ptype)
                self._link.reply(k, ready if tm is None else tm.master_cycle(ready), ptype,
                                 reply, seq)
        del box[:i]

    def _run_clocked(self, start: int, n: int, lines: PlantLines, offset: int) -> list:
        """:meth:`advance`'s nodes with a clock each (:class:`cosim.clocks.NodeTime`): master
        cycles ``start … start + n − 1`` hold node ``k``'s cycles ``N(start) … N(start + n) −
        1``. The encoder lines a master cycle shows reach the node cycles belonging to it, a
        packet or time-code the model link delivers in master cycle ``c`` reaches the node in
        the first of its cycles belonging to ``c`` or later (the link's timeline is the
        master's: :mod:`cosim.model_link`), the torque the plant samples at the end of the
        piece is the node's in its last cycle there, and the node's strobes and replies are
        those of the master cycle their node cycle belongs to — a strobe repeated within one
        master cycle merged and counted (:attr:`merged_strobes`), as the gateware harnesses
        OR them."""
        end = start + n
        at_rest = lines.at_rest
        if self.lazy and not at_rest:
            changes = lines.changes()
            whole = offset == 0 and n == self._step_len(lines)
        elif not self.lazy and not at_rest:
            counts = lines.cycles().counts
        out = []
        for k, (node, enc, tm) in enumerate(zip(self.nodes, self.encoders, self._times,
                                                strict=True)):
            n0, n1 = tm.node_cycle(start), tm.node_cycle(end)
            node_cycle, master_cycle = tm.node_cycle, tm.master_cycle
            # the encoder lines, master cycle by master cycle, onto the node's cycles
            if self.lazy:
                ch = []
                if not at_rest:
                    for i, c in changes[k]:
                        if not whole:
                            if not offset <= i < offset + n:
                                continue
                            i -= offset
                        j = node_cycle(start + i) - n0
                        if ch and ch[-1][0] == j:       # a master cycle with no node cycle
                            self._violate(f"node {k + 1}: encoder changes in master cycles "
                                          f"{start + i - 1} and {start + i} reach one node "
                                          "cycle (the last is taken)")
                            ch[-1] = (j, c)
                        elif j < n1 - n0:
                            ch.append((j, c))
                enc.feed_changes(n0, n1 - n0, ch)
            elif n1 > n0:
                g = np.array([master_cycle(c) for c in range(n0, n1)]) - start
                enc.feed(n0, np.full(n1 - n0, lines.counts[k]) if at_rest
                         else counts[offset + g, k])
            sample = self._samplers[k]
            if self._link.inbox[k]:
                self._inbox(k, node, end, sample, {}, tm)
            node.run(n1 - 1, sample)
            self._torque[k] = FORCE.decode(node.torque_at(n1 - 1))
            if node.events:
                later, seen = [], set()
                for c, flag in node.events:
                    if c >= n1:
                        later.append((c, flag))
                        continue
                    cm = master_cycle(c)
                    if (cm, flag) in seen:
                        self.merged_strobes += 1
                        continue
                    seen.add((cm, flag))
                    name = _EVENT_NAMES.get(flag)
                    out.append((cm, k + 1, flag.name if name is None else name))
                node.events = later
        return out

    @staticmethod
    def _collect(k: int, node, end: int, out: list) -> None:
        """Node ``k``'s observation-port strobes before ``end`` into ``out``."""
        if node.events:
            later = []
            for c, flag in node.events:
                if c < end:
                    name = _EVENT_NAMES.get(flag)      # (flag.name: an enum property call)
                    out.append((c, k + 1, flag.name if name is None else name))
                else:           # (a MARK still ahead waits for its chunk)
                    later.append((c, flag))
            node.events = later
