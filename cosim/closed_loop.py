"""The closed loop: the master, the gateware side and the plant, on every backend.

One loop (:class:`ClosedLoop`) runs every backend through the one interface of the gateware
side, :class:`cosim.gateware_side.GatewareSide` (pysim, compiled, model); docs/architecture.md
"One loop".

Time grid. The gateware runs at 50 MHz; the plant advances in fixed steps of ``plant.dt``
(10 µs = 500 cycles). Every step: the torque words the nodes output at the step's first cycle
drive the plant for the step (zero-order hold, the amplifier lag is in the plant); the plant's
encoder lines for each cycle of the step go into the nodes. The master's packets are handed to
the backend at the cycle they are due (its modelled compute time after the replies it waited
for): the step is run in pieces split there. The loop learns of a reply at the end of the
piece it arrived in, so a compute time shorter than the plant step can be rounded up to that
end (the default, 20 µs, never is).

Start-up. Links come up from reset (about 21.4 µs at standard timers), the master uploads
configuration and parameters (:func:`master.uploads.startup_sends`), then period 0 starts at
cycle ``start_cycle``. Until then the plant's brakes hold it at its home posture (it is not
stepped); the brakes release at period 0.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field

import numpy as np

from mrm_cosim.cosim.gateware_side import GatewareSide, PlantLines
from mrm_cosim.errors import InputError
from mrm_cosim.hdl.link.chain import line_fault_layout
from mrm_cosim.master.cycle import Master
from mrm_cosim.master.uploads import startup_sends
from mrm_cosim.models.plant import Plant
from mrm_cosim.models.robot import Robot
from mrm_cosim.protocol.link import DEFAULT_SLOTS
from mrm_cosim.units import CLOCK_HZ

__all__ = ["ClosedLoop", "LoopResult", "LineFault", "FAULT_KINDS", "PERMANENT"]

#: A fault's ``cycles`` that lasts to the end of any run (``+inf`` in :meth:`LineFault.parse`).
PERMANENT = 1 << 50


#: Line faults :class:`LineFault` can inject (``hdl.link.chain.line_fault_layout`` controls).
FAULT_KINDS = {
    "cut": "both wires cut (D and S read 0 in every slot): a broken cable",
    "bit": ("D and S inverted for the first 6.67 ns of the cycle (one bit at 150 Mbit/s): "
            "one bit's value flipped, framing kept"),
    "stuck-d": "the D wire stuck at 0 (S still toggles)",
}


@dataclass(frozen=True)
class LineFault:
    """A fault on one line of the chain during a closed-loop run (pysim and compiled).

    Attributes
    ----------
    node : int
        The line above node ``node`` (1-based): from the master port or node ``node − 1``.
    direction : str
        ``"down"`` (towards the node) or ``"up"`` (from it towards the master).
    kind : str
        One of :data:`FAULT_KINDS`.
    cycle : int
        First faulty cycle, counted from period 0 (20 ns each).
    cycles : int
        How long it lasts, cycles (:data:`PERMANENT`: to the end of the run).

    The model backend takes ``cut`` faults (:mod:`cosim.model_link`: packets lost while the
    line is down and until the link is back in Run); the others need the bit-level link.
    """

    node: int
    direction: str
    kind: str
    cycle: int
    cycles: int = 1

    def __post_init__(self):
        if isinstance(self.node, bool) or not isinstance(self.node, int) or self.node < 1:
            raise InputError("fault.node", f"must be a node number from 1, not {self.node!r}")
        if self.direction not in ("down", "up"):
            raise InputError("fault.direction", f"must be 'down' or 'up', not {self.direction!r}")
        if self.kind not in FAULT_KINDS:
            raise InputError("fault.kind", f"must be one of {', '.join(FAULT_KINDS)}, "
                             f"not {self.kind!r}")
        for name in ("cycle", "cycles"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < (1 if name == "cycles" else 0):
                raise InputError(f"fault.{name}", f"must be an integer "
                                 f"{'≥ 1' if name == 'cycles' else '≥ 0'}, not {v!r}")

    @classmethod
    def parse(cls, spec: str, field: str = "faults") -> LineFault:
        """``KIND:DIRECTION:NODE@TIME[+DURATION]``, times from period 0 with optional units:
        ``bit:up:2@2.006ms`` (one cycle), ``cut:down:2@10ms+2us``, ``cut:down:1@0.5s+inf``
        (permanent). ``InputError(field)``."""
        from mrm_cosim.cosim.backends import parse_time

        text = str(spec)
        where, _, when = text.partition("@")
        parts = where.split(":")
        if not when or len(parts) != 3:
            raise InputError(field, f"must be KIND:DIRECTION:NODE@TIME[+DURATION] "
                             f"(e.g. bit:up:2@2.006ms), not {text!r}")
        kind, direction, node = (p.strip() for p in parts)
        if not node.isdigit():
            raise InputError(field, f"the node must be a number, not {node!r} in {text!r}")
        at, _, length = when.partition("+")
        cycle = round(parse_time(at, field) * CLOCK_HZ)
        if length.strip() == "inf":
            cycles = PERMANENT
        else:
            cycles = max(1, round(parse_time(length, field) * CLOCK_HZ)) if length else 1
        try:
            return cls(int(node), direction, kind, cycle, cycles)
        except InputError as e:
            raise InputError(field, f"{e.message} (in {text!r})") from None

    @property
    def port(self) -> str:
        """The :class:`hdl.system.System` input it drives."""
        return f"fault_{self.direction}{self.node}"

    def value(self, slots: int = DEFAULT_SLOTS) -> int:
        """The raw value of a ``line_fault_layout(slots)`` port while the fault lasts."""
        every = (1 << slots) - 1
        bit = (1 << max(1, slots // 3)) - 1     # one 6.67 ns bit at 150 Mbit/s
        on = {"cut": {"clear_d": every, "clear_s": every},
              "bit": {"flip_d": bit, "flip_s": bit},
              "stuck-d": {"clear_d": every}}[self.kind]
        layout = line_fault_layout(slots)
        return sum(v << layout[f].offset for f, v in on.items())


@dataclass
class LoopResult:
    """Trace of a closed-loop run, one row per plant step after the brakes released."""

    t: np.ndarray                 # (steps,) s since period 0
    q: np.ndarray                 # (steps, n) true joint angles, rad
    tau: np.ndarray               # (steps, n) torque commands applied, N·m
    master: Master
    link_errors: int              # the master port's codec errors (five classes, summed)
    crc_errors: int               # frames the master dropped: CRC, length or EEP
    frames: list = field(default_factory=list)   # (cycle, src, type) of every good frame
    trace_sha256: str = ""
    violations: list = field(default_factory=list)   # model backend: conditions not met
    window_wall_s: float = 0.0    # wall time from period 0 to the end (start-up excluded)
    window_cpu_s: float = 0.0     # CPU time of this process over the same window
    brake: np.ndarray | None = None   # (steps, n) bool: the plant's brakes holding after each step


class ClosedLoop:
    """The closed loop on one backend: the only one (every backend runs through it).

    Parameters
    ----------
    robot : Robot
    backend : GatewareSide
        The gateware side: :class:`cosim.backends.PysimBackend`,
        :class:`cosim.backends.CompiledBackend` (each of a :class:`hdl.system.System` of
        ``robot.n`` nodes) or :class:`cosim.model.ModelBackend`.
    master : Master
    plant : Plant
    start_cycle : int
        Cycle of period 0 (after link start-up and uploads), a multiple of the plant step.
    uploads : list of (dest, type, payload)
        What the master uploads once the link is up (:func:`master.uploads.node_uploads`).
    """

    def __init__(self, robot: Robot, backend: GatewareSide, master: Master, plant: Plant,
                 start_cycle: int, uploads):
        if not isinstance(backend, GatewareSide):
            raise TypeError(f"backend must be a GatewareSide, not {type(backend).__name__}")
        self.robot = robot
        self.n = robot.n
        self.backend = backend
        self.master = master
        self.plant = plant
        self.step_cycles = round(plant.dt * CLOCK_HZ)
        if start_cycle % self.step_cycles:
            raise InputError("start_cycle", "must be a multiple of the plant step")
        self.start_cycle = start_cycle
        self.cycle = 0
        self.frames = []
        self._uploads = list(uploads)
        self._seq = 0
        self._rest = PlantLines(counts=plant.encoder_counts())
        backend.power_on(self._rest.counts)
        backend.attach_plant(plant)

    # --- the backend's cycles ----------------------------------------------------------------
    async def _advance(self, n: int, lines: PlantLines, offset: int = 0) -> None:
        """``n`` cycles from the step's cycle ``offset``; what reached the master, to it."""
        self._deliver(await self.backend.advance(n, lines, offset))
        self.cycle += n

    def _deliver(self, seen) -> None:
        """What reached the master (:class:`~cosim.gateware_side.Observed`), to it."""
        master = self.master
        if seen.events:
            master.on_node_events(seen.events)
        for r in seen.replies:
            self.frames.append((r.cycle, r.src, r.ptype))
            if not master.stale(r.ptype, r.seq):                # else counted late
                master.on_packet(r.cycle, r.src, r.ptype, r.payload)

    async def _step(self, lines: PlantLines) -> None:
        """One plant step, split where the master has packets due."""
        s = self.step_cycles
        done = 0
        while done < s:
            n = s - done
            due = self.master.next_due()
            if due is not None and self.cycle < due < self.cycle + n:
                n = due - self.cycle
            await self._advance(n, lines, done)
            done += n
            if done < s:
                for action in self.master.poll(self.cycle):
                    self.backend.send(action)

    def _ahead(self, fast, i: int, stop: int) -> int:
        """Before a general step (the fast path has declined it): the master polled at the
        step's first cycle, its packets due inside the step handed over at once, as sent in
        their cycle, where the backend allows it (:meth:`GatewareSide.send_ahead`), and the
        step offered to the fast path again — also when nothing more is due in it (the
        period start: the time-code and Comm A leave at its first cycle, the step becomes
        one with node events). The polls are the general step's: at the step's first cycle,
        then at the packets'. Returns the steps the fast path ran (0: the general step runs;
        it polls again, which returns nothing, and needs no split where the packets left)."""
        master, backend, s = self.master, self.backend, self.step_cycles
        for action in master.poll(self.cycle):
            backend.send(action)
        due = master.next_due()
        if due is not None and self.cycle < due < self.cycle + s:
            if not backend.send_ahead(due, self.cycle + s):
                return 0
            for action in master.poll(due):
                backend.send(action)
        # nothing more due inside the step (the period start's time-code and Comm A went out
        # at its first cycle): the fast path may take it as a step with node events
        return fast(i, stop, self.cycle, master.quiet_end(s))

    # --- the run -----------------------------------------------------------------------------
    def run(self, duration_cycles: int, progress=None) -> LoopResult:
        """Run start-up and ``duration_cycles`` of closed loop; return the trace. The backend
        drives the loop (:meth:`GatewareSide.execute`: pysim in a testbench).

        ``progress(t_sim, t_total)`` (simulated seconds since period 0, and of the run) is
        called every simulated millisecond."""
        return self.backend.execute(self.arun(duration_cycles, progress))

    async def arun(self, duration_cycles: int, progress=None) -> LoopResult:
        """:meth:`run` as a coroutine, for a caller already inside the backend's driver
        (a testbench)."""
        s = self.step_cycles
        backend, master, plant = self.backend, self.master, self.plant
        uploads_sent = False
        steps = duration_cycles // s
        t_rec = np.arange(steps) * s / CLOCK_HZ        # step i starts at cycle i · s
        rec = np.zeros((2, steps, self.n))              # (the fast path writes both at once)
        q_rec, tau_rec = rec[0], rec[1]
        engaged = np.zeros((steps, self.n), dtype=bool)   # the brakes holding, per step
        while self.cycle < self.start_cycle:
            if backend.link_up and not uploads_sent:
                sends, self._seq = startup_sends(self._uploads, master, plant.q, self._seq)
                for a in sends:
                    backend.send(a)
                uploads_sent = True
            await self._advance(s, self._rest)
        if not uploads_sent:
            raise InputError("start_cycle", "the link did not come up before period 0")
        backend.begin(self.start_cycle, master.timing.period_cycles)
        master.begin(self.start_cycle)
        fast = backend.fast_path(plant, rec)
        t_window, cpu_window = time.perf_counter(), time.process_time()
        i = 0
        while i < steps:
            brake = backend.brake()
            braking = True in brake.tolist() or not plant.brake_idle   # (ndarray.any: ~2 µs)
            if braking:         # (else every command is released already: nothing changes)
                plant.set_brake(brake)
            # plain steps in one go (fast_path) while the brakes are released and none is
            # commanded: its compiled plant step carries no brake
            if fast is not None and plant.brake_idle:
                stop = steps if progress is None else min(steps, (i // 100 + 1) * 100)
                k = fast(i, stop, self.cycle, master.quiet_end(s))
                if not k:
                    k = self._ahead(fast, i, stop)
                if k:
                    i += k
                    self.cycle += k * s
                    seen = backend.fast_observed()      # (its last step's, at its end)
                    if seen is not None:
                        self._deliver(seen)
                    if progress is not None and i % 100 == 0:
                        progress(i * s / CLOCK_HZ, steps * s / CLOCK_HZ)
                    continue
            for action in master.poll(self.cycle):
                backend.send(action)
            tau = np.array(backend.torque)
            plant.step(tau)
            lines = PlantLines(plant)
            q_rec[i] = plant.q
            tau_rec[i] = tau
            if braking or not plant.brake_idle:
                engaged[i] = plant.brake_engaged
            await self._step(lines)
            i += 1
            if progress is not None and i % 100 == 0:
                progress(i * s / CLOCK_HZ, steps * s / CLOCK_HZ)
        master.finish(self.cycle)
        window = time.perf_counter() - t_window
        window_cpu = time.process_time() - cpu_window
        backend.finish()
        digest = hashlib.sha256()
        digest.update(q_rec.tobytes())
        digest.update(tau_rec.tobytes())
        return LoopResult(t_rec, q_rec, tau_rec, master, backend.link_errors,
                          backend.crc_errors, self.frames, digest.hexdigest(),
                          violations=list(backend.violations), window_wall_s=window,
                          window_cpu_s=window_cpu, brake=engaged)
