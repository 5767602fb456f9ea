"""Closed loop: the master, the gateware (``hdl.system.System``) and the plant, cycle by cycle.

Time grid. The gateware runs at 50 MHz; the plant advances in fixed steps of ``plant.dt``
(10 µs = 500 cycles). Every step: the torque words the nodes output at the step's first cycle
drive the plant for the step (zero-order hold, the amplifier lag is in the plant); the plant's
encoder lines for each cycle of the step go into the nodes. The master's packets are written
into the master port's transmit FIFO at the cycle they are due (its modelled compute time after
the replies it waited for): the step is run in pieces split there. The harness learns of a
reply at the end of the piece it arrived in, so a compute time shorter than the plant step can
be rounded up to that end (the default, 20 µs, never is). Received characters are assembled
into frames and checked (CRC, length) with their arrival cycle. The same loop drives every
backend that offers ``run(n, inputs, outputs)`` with Amaranth-testbench semantics
(``cosim.compiled.CompiledModel``).

Start-up. Links come up from reset (about 21.4 µs at standard timers), the master uploads
configuration and parameters, then period 0 starts at cycle ``start_cycle``. Until then the
plant's brakes hold it at its home posture (it is not stepped); the brakes release at period 0.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field

import numpy as np

from mrm_cosim.protocol import packet as ref
from mrm_cosim.hdl.link.chain import char_int, char_value, line_fault_layout
from mrm_cosim.protocol.fixed import FORCE
from mrm_cosim.protocol.joint_program import JointParams
from mrm_cosim.protocol.regs import (
    MODES, Config, NodeEvent, config_payloads, joint_upload, vdc_upload,
)
from mrm_cosim.master.cycle import Master, Send
from mrm_cosim.models.actuators import ACTUATORS
from mrm_cosim.models.encoder import counts_per_rad, joint_counts, quadrature_levels
from mrm_cosim.models.plant import Plant
from mrm_cosim.models.robot import Robot
from mrm_cosim.errors import InputError
from mrm_cosim.units import CLOCK_HZ

__all__ = ["Gains", "ClosedLoop", "LoopResult", "LineFault", "FAULT_KINDS", "node_uploads",
           "startup_sends", "EEP", "EOP"]

EOP, EEP = ref.EOP, ref.EEP
_RX_CHUNK_OUTPUTS = ("rx_valid", "rx_char")
_NODE_EVENTS = tuple((int(f), f.name) for f in NodeEvent)


@dataclass(frozen=True)
class Gains:
    """Controller settings uploaded to the nodes or used by the master (SI units).

    Attributes
    ----------
    lam : float, 1/s
        λ of the required joint velocity (master and node alike).
    k_j : float, N·m·s/rad
        VDC joint velocity-error gain.
    K : float
        VDC link velocity-error gain (same for the six axes, N·s/m and N·m·s/rad).
    adapt : float
        Adaptation gain ρ of every parameter (0: no adaptation), with bounds 0.7×/1.3×.
    pid_fpga_hz, pid_1khz_hz : float
        Closed-loop pole frequency of the node's PID and of the master's 1 kHz PID.
    friction_comp : float
        VDC joint friction estimates ``θ̂_J`` (viscous, Coulomb) as this fraction of each
        actuator's nominal (catalogue-level) friction; 0: none. The plant's true friction
        differs from the nominal one by its perturbation, so 1 is a model, not the truth.
    """

    lam: float = 50.0
    k_j: float = 30.0
    K: float = 0.0
    adapt: float = 0.0
    pid_fpga_hz: float = 15.0
    pid_1khz_hz: float = 5.0
    friction_comp: float = 0.0


def _joint_inertia(robot: Robot) -> np.ndarray:
    import pinocchio as pin

    model = robot.pinocchio_model()
    M = pin.crba(model, model.createData(), robot.home)
    return np.diag(M) + np.array([ACTUATORS[m.type.actuator].output_inertia
                                  for m in robot.modules])


def pid_gains(robot: Robot, hz: float) -> dict:
    """PID gains placing a triple pole at ``−2π·hz`` for each joint's nominal inertia."""
    J = _joint_inertia(robot)
    w = 2 * np.pi * hz
    return {"kp": 3 * J * w * w, "ki": J * w**3, "kd": 3 * J * w}


def node_uploads(robot: Robot, controller: str, gains: Gains, tick_cycles: int = 50,
                 timeout_cycles: int | None = None, period_cycles: int = 50_000,
                 commit_cycles: int | None = None,
                 sync_window: int = 2_500) -> list[tuple[int, int, bytes]]:
    """``(dest, type, payload)`` packets that configure every node before the run (the PID
    gains are zero unless ``controller`` is ``pid-fpga``).

    Homing: the arm rests at ``robot.home`` until period 0 (the brakes hold it), and a node's
    incremental encoder counts from 0 at its reset, so each node's count is preset (CONFIG
    PRESET) to the count of its joint's home angle, ``floor(home · CPR / 2π)``, what the
    plant's encoder shows there. Without it a robot whose home is not all zeros ran with
    every joint's angle off by its home angle, in the master and in the node alike.

    ``period_cycles`` (the master's period), ``commit_cycles`` (the phase at which Comm D takes
    effect) and ``sync_window`` set the nodes' period timer (docs/node.md "Timing"); the
    timing record goes first, so it arrives within the first period after reset. The default
    commit phase is a fifth of the period (200 µs of 1 ms: the measured Comm D reaches the last
    of three nodes at ~82 µs; docs/node.md "Timing" says why the margin). The VDC's
    backward difference (1/T) and adaptation step (ρ·T) are for this period. The default
    watchdog timeout is two periods, at least 2 ms (docs/node.md "Watchdog"): the nodes hear
    from the master once a period, so a timeout that did not follow a longer period would trip
    every node, and before period 0 they hear nothing for up to 1 ms after their ARM.
    """
    if commit_cycles is None:
        commit_cycles = period_cycles // 5
    if timeout_cycles is None:
        # two periods, and never less than the silence between the uploads' ARM and period 0
        # (up to START_CYCLE, 1 ms): two 0.4 ms periods tripped every node before period 0
        timeout_cycles = max(2 * period_cycles, 2 * 50_000)
    mode = {"vdc": MODES["vdc"], "pid-fpga": MODES["pid"], "pid-1khz": MODES["torque"]}
    if period_cycles % tick_cycles or not 0 < period_cycles < (1 << 24):
        raise InputError("period_cycles", f"must be a multiple of the tick ({tick_cycles}) "
                         f"below 2^24, not {period_cycles!r}")
    if not 0 <= commit_cycles < period_cycles:
        raise InputError("commit_cycles", f"must lie in [0, {period_cycles}), "
                         f"not {commit_cycles!r}")
    if not 0 <= sync_window < period_cycles:
        raise InputError("sync_window", f"must lie in [0, {period_cycles}), not {sync_window!r}")
    out = [(k + 1, ref.PacketType.CONFIG, p) for k in range(robot.n) for p in config_payloads(
        {Config.PERIOD: period_cycles, Config.COMMIT: commit_cycles,
         Config.SYNC_WINDOW: sync_window})]
    # The PID words only where the node runs its PID: they scale with the torque per count,
    # and a robot with coarser encoders than mrm3's can need more than the KP word holds,
    # which must not stop a run that never uses them.
    pid = (pid_gains(robot, gains.pid_fpga_hz) if controller == "pid-fpga"
           else dict.fromkeys(("kp", "ki", "kd"), np.zeros(robot.n)))
    home_counts = joint_counts(robot.home, counts_per_rad(robot.counts_per_rev))
    for k, mod in enumerate(robot.modules):
        dest = k + 1
        peak = FORCE.encode(mod.type.peak_torque)
        cfg = {Config.MODE: mode[controller], Config.TICK: tick_cycles,
               Config.TIMEOUT: timeout_cycles, Config.RAMP: FORCE.encode(0.01),
               Config.TAU_MIN: -peak, Config.TAU_MAX: peak}
        out += [(dest, ref.PacketType.CONFIG, p) for p in config_payloads(cfg)]
        theta = robot.nominal_theta[k]
        lo = np.minimum(0.7 * theta, 1.3 * theta)
        hi = np.maximum(0.7 * theta, 1.3 * theta)
        out += [(dest, ref.PacketType.PARAM, p) for p in
                vdc_upload(theta, np.full((2, 6), gains.K), np.full((2, 13), gains.adapt),
                           lo, hi, period=period_cycles / CLOCK_HZ)]
        spec = ACTUATORS[mod.type.actuator]
        joint = JointParams.from_float(
            counts_per_rev=mod.type.counts_per_rev, tick_cycles=tick_cycles, lam=gains.lam,
            k_j=gains.k_j, inertia=spec.output_inertia,
            viscous=gains.friction_comp * spec.viscous_friction,
            coulomb=gains.friction_comp * spec.coulomb_friction,
            k_p=pid["kp"][k], k_i=pid["ki"][k], k_d=pid["kd"][k], i_max=0.05,
            field=f"joint{dest}")
        out += [(dest, ref.PacketType.PARAM, p) for p in joint_upload(joint)]
        out += [(dest, ref.PacketType.CONFIG, p)
                for p in config_payloads({Config.PRESET: int(home_counts[k])})]
        out += [(dest, ref.PacketType.CONFIG, p) for p in config_payloads({Config.ARM: 1})]
    return out


def startup_sends(uploads, master: Master, q0, seq: int) -> tuple[list[Send], int]:
    """What the master sends once the link is up, before period 0: every upload ``(dest, type,
    payload)`` with sequence numbers counting on from ``seq``, then its initial Comm D (at the
    plant's posture ``q0``). Returns the sends and the last sequence number used. Both loops
    (this one and ``cosim.model.ModelLoop``) start the same way."""
    sends = []
    for dest, ptype, payload in uploads:
        seq = (seq + 1) & 0xFF
        sends.append(Send("packet", dest, int(ptype), payload, seq))
    return sends + list(master.initial_packets(q0)), seq


#: Line faults :class:`LineFault` can inject (``hdl.link.chain.line_fault_layout`` controls).
FAULT_KINDS = {
    "cut": "both wires cut (D and S read 0 in every slot): a broken cable",
    "bit": "D and S inverted in the cycle's first slot: one bit's value flipped, framing kept",
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
        How long it lasts, cycles.
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
    def parse(cls, spec: str, field: str = "--line-fault") -> LineFault:
        """``KIND:DIRECTION:NODE@TIME[+DURATION]``, times from period 0 with optional units:
        ``bit:up:2@2.006ms`` (one cycle), ``cut:down:2@10ms+2us``. ``InputError(field)``."""
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
        cycles = max(1, round(parse_time(length, field) * CLOCK_HZ)) if length else 1
        try:
            return cls(int(node), direction, kind, cycle, cycles)
        except InputError as e:
            raise InputError(field, f"{e.message} (in {text!r})") from None

    @property
    def port(self) -> str:
        """The :class:`hdl.system.System` input it drives."""
        return f"fault_{self.direction}{self.node}"

    def value(self, slots: int = 3) -> int:
        """The raw value of a ``line_fault_layout(slots)`` port while the fault lasts."""
        every = (1 << slots) - 1
        on = {"cut": {"clear_d": every, "clear_s": every},
              "bit": {"flip_d": 1, "flip_s": 1},
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


class ClosedLoop:
    """The closed loop on one backend.

    Parameters
    ----------
    robot : Robot
    backend : object with ``run(n, inputs, outputs)``
        A compiled or simulated :class:`hdl.system.System` of ``robot.n`` nodes.
    master : Master
    plant : Plant
    start_cycle : int
        Cycle of period 0 (after link start-up and uploads).
    uploads : list of (dest, type, payload)
    faults : sequence of LineFault
        Line faults to inject; the backend's system must have been built with
        ``line_faults=True`` (``line_slots`` slots per line).
    """

    def __init__(self, robot: Robot, backend, master: Master, plant: Plant,
                 start_cycle: int, uploads, faults=(), line_slots: int = 3):
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
        self._tx: list[int] = []          # raw Char values waiting for the FIFO
        self._tx_level = 0
        self._rx: list[int] = []
        self._timecode: int | None = None
        self.crc_errors = 0
        self.link_errors = 0              # the master port's codec errors (System.link_errors)
        self.frames = []
        self._uploads = list(uploads)
        self._faults = list(faults)
        for f in self._faults:
            if f.node > self.n:
                raise InputError("fault.node", f"the robot has {self.n} nodes, not {f.node}")
        self._line_slots = line_slots
        self._torque = np.zeros(self.n)
        self._enc_a = np.zeros(self.step_cycles, dtype=np.int64)
        self._enc_b = np.zeros(self.step_cycles, dtype=np.int64)
        self._link_up = False
        self._seq = 0
        counts = plant.encoder_counts()
        self._set_static_encoder(counts)

    # --- encoder lines ---------------------------------------------------------------------
    def _set_static_encoder(self, counts) -> None:
        a, b = quadrature_levels(np.asarray(counts))
        self._enc_a[:] = int(sum(int(x) << k for k, x in enumerate(a)))
        self._enc_b[:] = int(sum(int(x) << k for k, x in enumerate(b)))

    def _encoder_from_plant(self) -> None:
        cyc = self.plant.encoder_cycles()
        weights = 1 << np.arange(self.n, dtype=np.int64)
        self._enc_a[:] = cyc.a.astype(np.int64) @ weights
        self._enc_b[:] = cyc.b.astype(np.int64) @ weights

    # --- link I/O --------------------------------------------------------------------------
    def _queue(self, action: Send) -> None:
        if action.kind == "timecode":
            self._timecode = action.time
            return
        chars = ref.encode(ref.Header(action.dest, ref.MASTER_ADDRESS, action.ptype,
                                      action.seq), action.payload)
        self._tx += [char_value(c) for c in chars]

    def _take_rx(self, cycles: np.ndarray, chars: np.ndarray) -> None:
        for cyc, raw in zip(cycles.tolist(), chars.tolist(), strict=True):
            c = char_int(raw)
            self._rx.append(c)
            if c in (EOP, EEP):
                verdict, header, payload = ref.check_frame(self._rx)
                self._rx = []
                if verdict != ref.Verdict.GOOD:
                    self.crc_errors += 1
                    continue
                self.frames.append((cyc, header.src, header.type))
                if not self.master.stale(header.type, header.seq):   # else counted late
                    self.master.on_packet(cyc, header.src, header.type, bytes(payload))

    def _node_events(self, out: dict) -> None:
        """The nodes' observation-port strobes of a chunk, to the master's period records (a
        few per period: found with ``np.nonzero``)."""
        for k in range(self.n):
            ev = out[f"events{k + 1}"]
            for i in np.nonzero(ev)[0].tolist():
                bits = int(ev[i])
                for flag, name in _NODE_EVENTS:
                    if bits & flag:
                        self.master.on_node_event(self.cycle + i, k + 1, name)

    async def _chunk(self, n: int, offset: int = 0) -> dict:
        """``n`` cycles from the plant step's cycle ``offset``."""
        inputs = {"enc_a": self._enc_a[offset:offset + n],
                  "enc_b": self._enc_b[offset:offset + n]}
        room = max(0, 192 - self._tx_level)
        k = min(len(self._tx), room, n)
        tx_valid = np.zeros(n, dtype=np.int64)
        tx_char = np.zeros(n, dtype=np.int64)
        if k:
            tx_valid[:k] = 1
            tx_char[:k] = self._tx[:k]
            del self._tx[:k]
        inputs["tx_valid"] = tx_valid
        inputs["tx_char"] = tx_char
        tick = np.zeros(n, dtype=np.int64)
        if self._timecode is not None:
            tick[0] = 1
            inputs["time_in"] = np.full(n, self._timecode, dtype=np.int64)
            self._timecode = None
        inputs["tick_in"] = tick
        if self._faults:
            self._fault_inputs(inputs, n)
        names = [*_RX_CHUNK_OUTPUTS, "tx_level", "running", "link_errors"] + \
            [f"torque{k + 1}" for k in range(self.n)] + [f"events{k + 1}" for k in range(self.n)]
        out = await self.backend.run(n, inputs, names)
        self._node_events(out)
        valid = np.nonzero(out["rx_valid"])[0]
        if len(valid):
            self._take_rx(self.cycle + valid, out["rx_char"][valid])
        self._tx_level = int(out["tx_level"][-1])
        self._link_up = bool(out["running"][-1])
        self.link_errors = int(out["link_errors"][-1])
        # torque words at the next cycle's edge are the ones sampled last in this chunk
        self._torque = np.array([FORCE.decode(int(out[f"torque{j + 1}"][-1]))
                                 for j in range(self.n)])
        self.cycle += n
        return out

    def _fault_inputs(self, inputs: dict, n: int) -> None:
        """Every fault port, every chunk (an input not passed keeps its last value)."""
        for k in range(1, self.n + 1):
            for d in ("down", "up"):
                inputs[f"fault_{d}{k}"] = np.zeros(n, dtype=np.int64)
        for f in self._faults:
            first = self.start_cycle + f.cycle
            lo, hi = max(first, self.cycle), min(first + f.cycles, self.cycle + n)
            if lo < hi:
                inputs[f.port][lo - self.cycle:hi - self.cycle] |= f.value(self._line_slots)

    async def _step(self, s: int) -> None:
        """One plant step of ``s`` cycles, split where the master has packets due."""
        done = 0
        while done < s:
            n = s - done
            due = self.master.next_due()
            if due is not None and self.cycle < due < self.cycle + n:
                n = due - self.cycle
            await self._chunk(n, done)
            done += n
            if done < s:
                for action in self.master.poll(self.cycle):
                    self._queue(action)

    # --- the run ----------------------------------------------------------------------------
    async def run(self, duration_cycles: int, progress=None) -> LoopResult:
        """Run start-up and ``duration_cycles`` of closed loop; return the trace.

        ``progress(t_sim, t_total)`` (simulated seconds since period 0, and of the run) is
        called every simulated millisecond."""
        s = self.step_cycles
        uploads_sent = False
        steps = duration_cycles // s
        t_rec = np.zeros(steps)
        q_rec = np.zeros((steps, self.n))
        tau_rec = np.zeros((steps, self.n))
        while self.cycle < self.start_cycle:
            if self._link_up and not uploads_sent:
                sends, self._seq = startup_sends(self._uploads, self.master, self.plant.q,
                                                 self._seq)
                for a in sends:
                    self._queue(a)
                uploads_sent = True
            await self._chunk(s)
        if not uploads_sent:
            raise InputError("start_cycle", "the link did not come up before period 0")
        self.master.begin(self.start_cycle)
        t_window = time.perf_counter()
        for i in range(steps):
            for action in self.master.poll(self.cycle):
                self._queue(action)
            tau = self._torque
            self.plant.step(tau)
            self._encoder_from_plant()
            t_rec[i] = (self.cycle - self.start_cycle) / CLOCK_HZ
            q_rec[i] = self.plant.q
            tau_rec[i] = tau
            await self._step(s)
            if progress is not None and (i + 1) % 100 == 0:
                progress((i + 1) * s / CLOCK_HZ, steps * s / CLOCK_HZ)
        self.master.finish(self.cycle)
        window = time.perf_counter() - t_window
        digest = hashlib.sha256()
        digest.update(q_rec.tobytes())
        digest.update(tau_rec.tobytes())
        return LoopResult(t_rec, q_rec, tau_rec, self.master, self.link_errors, self.crc_errors,
                          self.frames, digest.hexdigest(), window_wall_s=window)

