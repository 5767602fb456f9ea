"""The gateware backends of the closed loop: :class:`hdl.system.System` simulated or compiled.

:class:`LineSide` implements :class:`cosim.gateware_side.GatewareSide` at character level over
one cycle primitive, ``async run(n, inputs, outputs) -> dict`` (inputs set, outputs sampled,
then a clock edge, per cycle: the semantics of :meth:`cosim.compiled.CompiledModel.run`):
the master's packets framed into the master port's transmit FIFO, received characters
assembled into frames and checked, the plant's encoder lines as quadrature levels, line faults
on the chain's wires. :class:`PysimBackend` (Amaranth's simulator, the loop inside one
testbench) and :class:`CompiledBackend` (Verilator) each supply the primitive.
"""

from __future__ import annotations

import fnmatch
import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mrm_cosim.cosim.gateware_side import GatewareSide, Observed, PlantLines, Reply, drive
from mrm_cosim.errors import InputError
from mrm_cosim.hdl.link.chain import char_int, char_value
from mrm_cosim.models.encoder import quadrature_levels
from mrm_cosim.protocol import packet as ref
from mrm_cosim.protocol.fixed import FORCE
from mrm_cosim.protocol.link import DEFAULT_SLOTS
from mrm_cosim.protocol.regs import NodeEvent
from mrm_cosim.units import CLOCK_HZ

__all__ = ["LineSide", "CompiledBackend", "PysimBackend", "VcdWindow", "drive",
           "system_verilog", "compiled_parts", "CLOCK_HZ"]

#: One cycle of the gateware's clock in picoseconds (20 ns).
_PERIOD_PS = 1_000_000_000_000 // CLOCK_HZ
_NODE_EVENTS = tuple((int(f), f.name) for f in NodeEvent)
#: Characters the master port's transmit FIFO holds.
_TX_FIFO = 192


_FINGERPRINTED: tuple[str, ...] | None = None


def _hdl_fingerprint() -> str:
    """Hash of the source files the gateware is built from, with Amaranth's version: every
    module of the gateware, the protocol room and the kernel that the process had imported once
    :mod:`mrm_cosim.hdl.system` and :mod:`mrm_cosim.hdl.tops` were (the Verilog of a design
    depends on nothing else; the references and the master are not among them)."""
    import hashlib
    import sys
    from pathlib import Path

    import amaranth

    global _FINGERPRINTED
    if _FINGERPRINTED is None:
        import mrm_cosim.hdl.system  # noqa: F401 - the gateware is imported before it is fingerprinted
        import mrm_cosim.hdl.tops  # noqa: F401

        rooms = ("mrm_cosim.hdl", "mrm_cosim.protocol")
        kernel = ("mrm_cosim", "mrm_cosim.errors", "mrm_cosim.units")
        _FINGERPRINTED = tuple(sorted(name for name in list(sys.modules)
                                      if name.startswith(rooms) or name in kernel))
    digest = hashlib.sha256(amaranth.__version__.encode())
    for name in _FINGERPRINTED:
        path = getattr(sys.modules[name], "__file__", None)
        if path is None:  # a namespace package
            continue
        digest.update(name.encode())
        digest.update(Path(path).read_bytes())
    return digest.hexdigest()


_IMPORTED_FINGERPRINT: str | None = None


def _imported_fingerprint() -> str:
    """The gateware fingerprint of the code this process runs: taken once, right after the
    whole gateware (:mod:`hdl.system` and what it imports) is imported. Files edited later (by
    a concurrent editor) do not change it, so a cache entry is always stored and looked up
    under the sources the running design was built from — not the files on disk now."""
    global _IMPORTED_FINGERPRINT
    if _IMPORTED_FINGERPRINT is None:
        _IMPORTED_FINGERPRINT = _hdl_fingerprint()
    return _IMPORTED_FINGERPRINT


def system_verilog(factory, key: str) -> tuple[str, dict]:
    """Verilog of the design ``factory()`` builds and its ports' signedness, cached under
    ``key`` plus the gateware sources' fingerprint (converting the three-node system takes
    ~15 s; reading it back, milliseconds). On a cache hit the design is not even built."""
    import json

    from amaranth.back import verilog

    from mrm_cosim.cosim.cache import mark_used
    from mrm_cosim.cosim.compiled import cache_dir, signed_port_map
    from mrm_cosim.results import atomic_write_text

    fingerprint = _imported_fingerprint()
    path = cache_dir() / "verilog" / f"{key}-{fingerprint[:20]}.v"
    side = path.with_suffix(".json")
    if path.exists() and side.exists():
        mark_used(path, side)
        return path.read_text(), json.loads(side.read_text())
    design = factory()
    if getattr(design, "clocks", "common") == "node":     # the node domains' clocks as ports
        text = verilog.convert(design, name="system", emit_src=False,
                               ports=design.verilog_ports())
    else:
        text = verilog.convert(design, name="system", emit_src=False)
    if _hdl_fingerprint() != fingerprint:
        # The sources changed while this process ran: a module imported lazily after the
        # edit could mix old and new code, so this Verilog is used but not cached.
        return text, signed_port_map(design)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, text)
    signed = signed_port_map(design)
    atomic_write_text(side, json.dumps(signed))
    return text, signed


_TIME_RE = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(s|ms|us|µs|ns)?\s*$")
_UNIT = {None: 1.0, "s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}


def parse_time(text: str, field: str) -> float:
    """Seconds from ``"0.0012"``, ``"1.2ms"``, ``"40us"``, ``"20ns"``; ``InputError(field)``
    for anything else."""
    m = _TIME_RE.match(str(text))
    if m is None:
        raise InputError(field, f"{text!r} is not a time (e.g. 0.0012, 1.2ms, 40us)")
    return float(m.group(1)) * _UNIT[m.group(2)]


@dataclass(frozen=True)
class VcdWindow:
    """A waveform request: the cycles ``[start, stop)`` and the signals to record.

    Times are counted from the backend's first cycle (reset), one cycle = 20 ns; the VCD's
    time stamps are the same, in picoseconds, so two VCDs of the same window line up.

    Attributes
    ----------
    start, stop : int
        First cycle recorded and first cycle not recorded.
    path : Path
        Where the waveform goes (written atomically when the window closes): a VCD, or FST
        if it ends in ``.fst`` (:mod:`cosim.waves`); a GTKWave save file ``.gtkw`` beside
        it opens it with the key signals grouped.
    signals : str
        Comma-separated shell patterns (``fnmatch``, case-sensitive) on the signals' dotted
        names below the design's top: ``torque1``, ``node1.link.up_codec.*``,
        ``node*.core.watchdog.*,rx_*``. ``*`` takes everything.
    """

    start: int
    stop: int
    path: Path
    signals: str = "*"

    def __post_init__(self):
        if not (isinstance(self.start, int) and isinstance(self.stop, int)
                and 0 <= self.start < self.stop):
            raise InputError("vcd", f"the window must satisfy 0 <= start < stop, not "
                                      f"{self.start}:{self.stop} (cycles)")
        if not self.signals or not any(p.strip() for p in self.signals.split(",")):
            raise InputError("signals", "needs at least one pattern")

    @classmethod
    def parse(cls, spec: str, path, signals: str | None = None,
              offset: float = 0.0) -> VcdWindow:
        """``"T0:T1"`` in seconds (or with a unit: ``1ms:1.02ms``, ``20us:30us``, ``ns``).

        ``offset`` (s) is added to both ends: a caller whose t = 0 is not the backend's first
        cycle (e.g. period 0 of a closed-loop run) passes where its t = 0 lies.
        """
        parts = str(spec).split(":")
        if len(parts) != 2:
            raise InputError("vcd", f"must be T0:T1 (seconds, or with ms/us/ns), not {spec!r}")
        times = []
        for part in parts:
            times.append(parse_time(part, "vcd") + offset)
        t0, t1 = times
        if not t1 > t0 >= 0:
            raise InputError("vcd", f"needs 0 <= T0 < T1, not {spec!r}")
        start = int(round(t0 * CLOCK_HZ))
        stop = max(start + 1, int(round(t1 * CLOCK_HZ)))
        if signals is not None and any(not p.strip() for p in str(signals).split(",")):
            raise InputError("signals", f"comma-separated non-empty patterns, not {signals!r}")
        return cls(start, stop, Path(path), signals or "*")

    @property
    def format(self) -> str:
        """``"fst"`` for a path ending in ``.fst``, else ``"vcd"``."""
        return "fst" if Path(self.path).suffix == ".fst" else "vcd"

    def matches(self, name: str) -> bool:
        """Whether the dotted signal name is selected."""
        return any(fnmatch.fnmatchcase(name, p.strip()) for p in self.signals.split(",")
                   if p.strip())


def _atomic_target(path: Path) -> Path:
    """A temporary file beside ``path`` (to be renamed over it when complete)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    return Path(tmp)


def _slice_inputs(inputs: dict, n: int, lo: int, hi: int) -> dict:
    return {k: np.broadcast_to(np.asarray(v), (n,))[lo:hi] for k, v in inputs.items()}


class LineSide(GatewareSide):
    """:class:`~cosim.gateware_side.GatewareSide` at character level over ``run``.

    Subclasses supply ``async run(n, inputs, outputs) -> dict`` on a :class:`hdl.system.System`
    (its port names). A packet is encoded to characters (:func:`protocol.packet.encode`)
    and written into the master port's FIFO as room allows, from the cycle it was sent; a
    time-code strobes ``tick_in`` in the first cycle of the next :meth:`advance`; received
    characters are assembled into frames and checked (CRC, length) with their arrival cycle.

    Parameters
    ----------
    faults : sequence of cosim.closed_loop.LineFault
        Line faults to inject, cycles counted from period 0 (:meth:`begin`); the system must
        have been built with ``line_faults=True`` (``line_slots`` slots per line).
    record : bool
        Keep every per-cycle output sample the loop reads (:meth:`trace`).
    """

    def __init__(self, faults=(), line_slots: int = DEFAULT_SLOTS, record: bool = False):
        self.cycle = 0
        self.n = 0
        self._faults = list(faults)
        self._line_slots = line_slots
        self._start: int | None = None
        self._tx: list[int] = []          # raw Char values waiting for the FIFO
        self._tx_level = 0
        self._rx: list[int] = []
        self._timecode: int | None = None
        self._running = False
        self._torque = np.zeros(0)
        self._brake = np.zeros(0, dtype=bool)
        self._lines: PlantLines | None = None
        self._enc = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
        self.crc_errors = 0
        self.link_errors = 0
        self.samples: dict[str, list] | None = {} if record else None

    # --- GatewareSide ----------------------------------------------------------------------
    def power_on(self, counts) -> None:
        self.n = len(counts)
        self._torque = np.zeros(self.n)
        self._brake = np.zeros(self.n, dtype=bool)
        for f in self._faults:
            if f.node > self.n:
                raise InputError("fault.node", f"the robot has {self.n} nodes, not {f.node}")

    @property
    def link_up(self) -> bool:
        return self._running

    @property
    def torque(self) -> np.ndarray:
        return self._torque

    def brake(self) -> np.ndarray:
        return self._brake

    def send(self, action) -> None:
        if action.kind == "timecode":
            self._timecode = action.time
            return
        chars = ref.encode(ref.Header(action.dest, ref.MASTER_ADDRESS, action.ptype,
                                      action.seq), action.payload)
        self._tx += [char_value(c) for c in chars]

    def begin(self, cycle: int, period_cycles: int) -> None:
        self._start = cycle

    async def advance(self, n: int, lines: PlantLines, offset: int = 0) -> Observed:
        enc_a, enc_b = self._encoder_lines(lines, offset, n)
        inputs = {"enc_a": enc_a, "enc_b": enc_b}
        k = min(len(self._tx), max(0, _TX_FIFO - self._tx_level), n)
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
        names = ["rx_valid", "rx_char", "tx_level", "running", "link_errors"] + \
            [f"{port}{j + 1}" for port in ("torque", "events", "brake") for j in range(self.n)]
        out = await self.run(n, inputs, names)
        if self.samples is not None:
            for name, v in out.items():
                self.samples.setdefault(name, []).append(np.array(v))
        events = self._node_events(out)
        valid = np.nonzero(out["rx_valid"])[0]
        replies = self._take_rx(self.cycle + valid, out["rx_char"][valid]) if len(valid) else []
        self._tx_level = int(out["tx_level"][-1])
        self._running = bool(out["running"][-1])
        self.link_errors = int(out["link_errors"][-1])
        # torque words at the next cycle's edge are the ones sampled last in this chunk
        self._torque = np.array([FORCE.decode(int(out[f"torque{j + 1}"][-1]))
                                 for j in range(self.n)])
        self._brake = np.array([bool(out[f"brake{j + 1}"][-1]) for j in range(self.n)])
        self.cycle += n
        return Observed(events, replies)

    async def run(self, n: int, inputs: dict, outputs) -> dict:
        """``n`` cycles: per cycle the ``inputs`` (arrays of n, or scalars) set, the
        ``outputs`` sampled, a clock edge; returns the samples, arrays of n per name. An
        input not given keeps its last value."""
        raise NotImplementedError

    def trace(self, name: str) -> np.ndarray:
        """Every sample of output ``name`` the loop read, in cycle order (``record=True``)."""
        if self.samples is None:
            raise RuntimeError("this backend was made without record=True")
        return np.concatenate(self.samples[name])

    # --- lines -----------------------------------------------------------------------------
    def _encoder_lines(self, lines: PlantLines, offset: int, n: int):
        """``enc_a``, ``enc_b`` (bit k: node k + 1) for cycles ``offset …`` of ``lines``."""
        if lines is not self._lines:
            self._lines = lines
            if lines.at_rest:
                a, b = quadrature_levels(lines.counts)
                self._enc = (int(sum(int(x) << k for k, x in enumerate(a))),
                             int(sum(int(x) << k for k, x in enumerate(b))))
            else:
                cyc = lines.cycles()
                weights = 1 << np.arange(self.n, dtype=np.int64)
                self._enc = (cyc.a.astype(np.int64) @ weights, cyc.b.astype(np.int64) @ weights)
        a, b = self._enc
        if isinstance(a, int):
            return np.full(n, a, dtype=np.int64), np.full(n, b, dtype=np.int64)
        return a[offset:offset + n], b[offset:offset + n]

    def _take_rx(self, cycles: np.ndarray, chars: np.ndarray) -> list[Reply]:
        replies = []
        for cyc, raw in zip(cycles.tolist(), chars.tolist(), strict=True):
            c = char_int(raw)
            self._rx.append(c)
            if c in (ref.EOP, ref.EEP):
                verdict, header, payload = ref.check_frame(self._rx)
                self._rx = []
                if verdict != ref.Verdict.GOOD:
                    self.crc_errors += 1
                    continue
                replies.append(Reply(cyc, header.src, header.type, header.seq, bytes(payload)))
        return replies

    def _node_events(self, out: dict) -> list:
        """The nodes' observation-port strobes of a chunk (a few per period: found with
        ``np.nonzero``)."""
        events = []
        for k in range(self.n):
            ev = out[f"events{k + 1}"]
            for i in np.nonzero(ev)[0].tolist():
                bits = int(ev[i])
                for flag, name in _NODE_EVENTS:
                    if bits & flag:
                        events.append((self.cycle + i, k + 1, name))
        return events

    def _fault_inputs(self, inputs: dict, n: int) -> None:
        """Every fault port, every chunk (an input not passed keeps its last value)."""
        for k in range(1, self.n + 1):
            for d in ("down", "up"):
                inputs[f"fault_{d}{k}"] = np.zeros(n, dtype=np.int64)
        if self._start is None:
            return
        for f in self._faults:
            first = self._start + f.cycle
            lo, hi = max(first, self.cycle), min(first + f.cycles, self.cycle + n)
            if lo < hi:
                inputs[f.port][lo - self.cycle:hi - self.cycle] |= f.value(self._line_slots)


def compiled_parts(segment, key: str, quiet: bool = True) -> list:
    """:class:`cosim.compiled.SplitModel`'s parts: ``segment = (n_nodes, build)``,
    ``build(k)`` node ``k``'s part (:func:`cosim.track.loop_segment`), each a
    :class:`~cosim.compiled.CompiledModel` of its own, its Verilog and build cached under
    ``key`` and ``k``. Returns ``[(k, 1, model), …]``, node 1 first."""
    from mrm_cosim.cosim.compiled import CompiledModel

    n, build = segment
    parts = []
    for k in range(1, n + 1):
        text, signed = system_verilog(lambda k=k: build(k), f"{key}-node{k}of{n}")
        parts.append((k, 1, CompiledModel(None, "system", quiet=quiet, verilog_text=text,
                                          signed_ports=signed)))
    return parts


class CompiledBackend(LineSide):
    """Verilator build of the system (Verilog and binary cached by content hashes).

    Parameters
    ----------
    factory : callable
        Builds the design (called only when its Verilog is not cached).
    key : str
        Cache name of the design (``system3``).
    vcd : VcdWindow, optional
        Record that window: the model is then a ``--trace`` build (its own cache entry, a
        little slower), tracing switched on only inside the window.
    faults, line_slots, record
        As :class:`LineSide`.
    clocks : cosim.clocks.ClockPlan, optional
        A clock per node: ``factory`` builds a ``System(..., clocks="node")`` and the model
        runs the event-ordered loop over every clock's edges (docs/clocks.md); a waveform then
        has every signal at each of its domain's rising edges, in femtoseconds.
    threads : int
        With ``segment``, one clock and no waveform: run the system as one model per node
        (:class:`cosim.compiled.SplitModel`) on this many threads (at most one a node), the
        same cycles bit for bit; 1 (the default): the whole system's model, as before.
    segment : (int, callable), optional
        ``(n_nodes, build)``: ``build(k)`` makes node ``k``'s part
        (:func:`cosim.track.loop_segment`); its Verilog is cached under ``key`` and ``k``.
    """

    name = "compiled"

    def __init__(self, factory, key: str, quiet: bool = True, vcd: VcdWindow | None = None,
                 faults=(), line_slots: int = DEFAULT_SLOTS, record: bool = False,
                 clocks=None, threads: int = 1, segment=None):
        from mrm_cosim.cosim.compiled import BuildError, CompiledModel, SplitModel
        from mrm_cosim.cosim.executors import default_workers

        super().__init__(faults, line_slots, record)
        # at most a thread a node, and a core a thread: a thread more than the cores would
        # wait for its turn on a core every cycle (measured: ×2–×19 slower than one)
        use = min(threads, segment[0], default_workers()) if segment is not None else 1
        self.threads = 1
        self.model = None
        if use > 1 and clocks is None and vcd is None:
            try:
                self.model = SplitModel(compiled_parts(segment, key, quiet), use)
                self.threads = self.model.threads
            except BuildError as exc:       # the same results on one thread: say so, go on
                import warnings

                first = (str(exc).strip().splitlines() or [""])[0]
                warnings.warn(f"compiled backend: {threads} threads unavailable ({first}); "
                              "running the whole system's model on one thread",
                              RuntimeWarning, stacklevel=2)
        if self.model is None:
            text, signed = system_verilog(factory, key)
            self.model = CompiledModel(None, "system", quiet=quiet, verilog_text=text,
                                       signed_ports=signed,
                                       trace=False if vcd is None else vcd.format)
        self.clocks = clocks
        if clocks is not None:
            from mrm_cosim.cosim.clocks import system_lines

            n_nodes = clocks.n_domains - 1
            self.model.setup_clocks(clocks, system_lines(n_nodes), _observed(n_nodes))
        self.vcd = vcd
        self._raw: Path | None = None
        self._vcd_done = False

    @property
    def merged_strobes(self) -> int:
        """Node strobes merged into a master cycle that held the same one (docs/clocks.md)."""
        return self.model.merged_strobes if self.clocks is not None else 0

    async def run(self, n, inputs, outputs):
        run = self.model.run if self.clocks is None else self.model.run_clocked
        if self.vcd is None or self._vcd_done:
            return run(n, inputs, outputs)
        parts, lo = [], 0
        while lo < n:
            cycle = self.model.cycles
            if self._raw is None and self.vcd.start <= cycle < self.vcd.stop:
                self._open()
            elif self._raw is not None and cycle >= self.vcd.stop:
                self.finish()
            edge = self.vcd.start if self._raw is None else self.vcd.stop
            hi = n if edge <= cycle or self._vcd_done else min(n, lo + edge - cycle)
            parts.append(run(hi - lo, _slice_inputs(inputs, n, lo, hi), outputs))
            lo = hi
        if self._raw is not None and self.model.cycles == self.vcd.stop:
            self.finish()
        return {k: np.concatenate([p[k] for p in parts]) for k in outputs}

    def _open(self) -> None:
        fd, raw = tempfile.mkstemp(prefix="mrm-trace-", suffix=f".{self.vcd.format}")
        os.close(fd)
        self._raw = Path(raw)
        self.model.trace_open(self._raw)

    def finish(self) -> list[str] | None:
        """Close the window now (also at its end, or if the run ends inside it) and write the
        waveform of the selected signals (and its ``.gtkw``). Returns their names, or ``None``
        if nothing was open."""
        from mrm_cosim.cosim.compiled import filter_vcd
        from mrm_cosim.cosim.waves import filter_fst, write_gtkw

        if self._raw is None:
            return None
        self.model.trace_close()
        tmp = _atomic_target(self.vcd.path)
        try:
            rewrite = filter_fst if self.vcd.format == "fst" else filter_vcd
            names = rewrite(self._raw, tmp, "system", self.vcd.matches, _PERIOD_PS,
                            fs=self.clocks is not None)
            os.replace(tmp, self.vcd.path)
            write_gtkw(self.vcd.path, names)
        finally:
            tmp.unlink(missing_ok=True)
            self._raw.unlink(missing_ok=True)
            self._raw = None
            self._vcd_done = True
        return names


class PysimBackend(LineSide):
    """Amaranth's simulator: the reference, slow. The loop runs inside one testbench
    (:meth:`execute`).

    Parameters
    ----------
    system : Component
    vcd : VcdWindow, optional
        Record that window. The signal names come from the simulator's own view of the
        design, so the simulator must be made by :meth:`simulator`.
    faults, line_slots, record
        As :class:`LineSide`.
    """

    name = "pysim"

    def __init__(self, system, vcd: VcdWindow | None = None, faults=(),
                 line_slots: int = DEFAULT_SLOTS, record: bool = False, clocks=None):
        super().__init__(faults, line_slots, record)
        self.system = system
        self.clocks = clocks
        self._engine = None
        self.vcd = vcd
        self._cycle = 0
        self._ctx = None
        self._names = None
        self._trace = None

    def simulator(self):
        """A ``Simulator`` of the system with its 50 MHz clock (and the names for the VCD)."""
        from amaranth.sim import Simulator

        sim = Simulator(self.system)
        if self.clocks is not None:
            # cycle 0 of clock d from its phase to its first rising edge (docs/clocks.md)
            plan = self.clocks
            for d in range(plan.n_domains):
                sim.add_clock(_fs(plan.periods[d]), phase=_fs(plan.phases[d] + plan.periods[d]),
                              domain="sync" if d == 0 else f"n{d}")
        else:
            sim.add_clock(1 / CLOCK_HZ)
        if self.vcd is not None:
            # Amaranth 0.5 names signals per fragment only inside the simulator it built
            # (Simulator.write_vcd cannot start late or select signals): take them from there.
            self._names = _pysim_names(sim._design, self.vcd)
        return sim

    def bind(self, ctx) -> None:
        """Run in the testbench whose context is ``ctx`` (:meth:`execute` does it)."""
        self._ctx = ctx
        if self.vcd is not None and self._names is None:
            raise RuntimeError("a VCD from pysim needs the simulator made by "
                               "PysimBackend.simulator()")

    def execute(self, coroutine):
        """Run the loop's ``coroutine`` in one testbench of a fresh :meth:`simulator`."""
        box = {}

        async def bench(ctx):
            self.bind(ctx)
            box["result"] = await coroutine

        sim = self.simulator()
        sim.add_testbench(bench)
        sim.run()
        return box["result"]

    async def run(self, n, inputs, outputs):
        if self.clocks is not None:
            return await self._run_clocked(n, inputs, outputs)
        ctx, dut = self._ctx, self.system
        ins = [(getattr(dut, k), np.broadcast_to(np.asarray(v), (n,))) for k, v in inputs.items()]
        outs = [getattr(dut, k) for k in outputs]
        rec = np.zeros((n, len(outs)), dtype=np.int64)
        vcd = self.vcd
        for i in range(n):
            for sig, values in ins:
                ctx.set(sig.as_value() if hasattr(sig, "as_value") else sig, int(values[i]))
            for j, sig in enumerate(outs):
                rec[i, j] = ctx.get(sig.as_value() if hasattr(sig, "as_value") else sig)
            if vcd is not None and vcd.start <= self._cycle < vcd.stop:
                self._sample(ctx)
            await ctx.tick()
            self._cycle += 1
            if vcd is not None and self._cycle == vcd.stop:
                self.finish()
        return {k: rec[:, j] for j, k in enumerate(outputs)}

    async def _run_clocked(self, n, inputs, outputs):
        """:meth:`run` on the master's grid with every clock's edges in time order: the same
        loop as the compiled harness's (:mod:`cosim.clocks`, ``mrm_clk_run``). Before an edge
        at ``t`` (at ``t − 1`` fs) its domain's line inputs are set and its outputs taken;
        after it (at ``t + 1``) its line outputs are recorded."""
        from mrm_cosim.cosim.clocks import ClockedEngine, system_lines

        ctx, dut, plan = self._ctx, self.system, self.clocks
        eng = self._engine

        def get(name):
            sig = getattr(dut, name)
            return ctx.get(sig.as_value() if hasattr(sig, "as_value") else sig)

        if eng is None:
            n_nodes = plan.n_domains - 1
            eng = self._engine = ClockedEngine(plan, system_lines(n_nodes))
            self._now = 0
            self._obs = _observed(n_nodes)
            self._latest = {name: get(name) for name, _d, _s in self._obs}
            self._acc = {name: 0 for name, _d, strobe in self._obs if strobe}
            for i, (src, _s, _dst, _r) in enumerate(eng.lines):
                eng.hist[i][0] = get(src)
        ins = [(getattr(dut, k), np.broadcast_to(np.asarray(v), (n,))) for k, v in inputs.items()]
        rec = np.zeros((n, len(outputs)), dtype=np.int64)
        vcd = self.vcd

        async def until(t):
            if t > self._now:
                await ctx.delay((t - self._now) * 1e-15)
                self._now = t

        async def edges(group, t):
            await until(t - 1)
            for d in group:
                for i, (_src, _s, dst, r) in enumerate(eng.lines):
                    if r == d:
                        ctx.set(getattr(dut, dst), eng.level_word(i, d))
                for name, od, strobe in self._obs:
                    if od == d:
                        v = get(name)
                        if strobe:
                            if self._acc[name] & v:
                                eng.merged += 1
                            self._acc[name] |= v
                        else:
                            self._latest[name] = v
            await until(t + 1)
            for d in group:
                eng.cycle[d] += 1
                eng.record(d, get)
            if vcd is not None and vcd.start <= self._cycle < vcd.stop:
                self._sample(ctx, t)           # after the edges of this instant, stamped t fs

        for g in range(n):
            for sig, values in ins:
                ctx.set(sig.as_value() if hasattr(sig, "as_value") else sig, int(values[g]))
            t1 = eng.edge(0)
            master_done = False
            while (group := eng.node_group(t1)) is not None:
                t = eng.edge(group[0])
                master_done = t == t1           # (nodes at the master's edge: before it)
                await edges(group + [0] if master_done else group, t)
                if master_done:
                    break
            if not master_done:
                await edges([0], t1)
            for j, name in enumerate(outputs):
                rec[g, j] = self._acc[name] if name in self._acc else self._latest[name]
            for name in self._acc:
                self._acc[name] = 0
            self._cycle += 1
            if vcd is not None and self._cycle == vcd.stop:
                self.finish()
                vcd = None
        return {k: rec[:, j] for j, k in enumerate(outputs)}

    @property
    def merged_strobes(self) -> int:
        return 0 if self._engine is None else self._engine.merged

    def _sample(self, ctx, fs: int | None = None) -> None:
        """Sample the window's signals: at the current cycle, or (clocks of their own) at
        ``fs``, the time in femtoseconds of the edges just taken (as the compiled backend's
        per-node-clock waveform: one sample per instant with a rising edge)."""
        if self._trace is None:
            # FST: the VCD goes to a hidden file beside the target first (finish converts it)
            target = (self.vcd.path if self.vcd.format == "vcd"
                      else _atomic_target(self.vcd.path))
            self._trace = _VcdOut(target, self._names, fs=self.clocks is not None)
        self._trace.sample(self._cycle if fs is None else fs,
                           [ctx.get(sig) for sig in self._trace.signals])

    def finish(self) -> list[str] | None:
        """Close the window now (also at its end, or if the run ends inside it) and write the
        waveform (an FST converted from the VCD by :func:`cosim.waves.vcd_to_fst`) and its
        ``.gtkw``. Returns the names of the signals in it, or ``None`` if nothing was
        recorded."""
        from mrm_cosim.cosim.waves import vcd_to_fst, write_gtkw

        if self._trace is None:
            return None
        vcd = self._trace.path
        names, self._trace = self._trace.close(), None
        if self.vcd.format == "fst":
            tmp = _atomic_target(self.vcd.path)
            try:
                vcd_to_fst(vcd, tmp)
                os.replace(tmp, self.vcd.path)
            finally:
                vcd.unlink(missing_ok=True)
                tmp.unlink(missing_ok=True)
        write_gtkw(self.vcd.path, names)
        self.vcd = None
        return names


def _observed(n_nodes: int) -> list[tuple[str, int, bool]]:
    """The System outputs a per-node-clock harness keeps on the master's grid: ``(port,
    domain, strobe)`` (:mod:`cosim.clocks`)."""
    from mrm_cosim.cosim.clocks import is_strobe, output_domain

    names = ["rx_valid", "rx_char", "tx_level", "tx_overflow", "running", "link_errors"]
    names += [f"{p}{k}" for k in range(1, n_nodes + 1)
              for p in ("torque", "brake", "status", "count", "events")]
    return [(name, output_domain(name), is_strobe(name)) for name in names]


def _fs(t: int) -> float:
    """Femtoseconds as the seconds Amaranth's simulator truncates back to exactly ``t``."""
    return (t + 0.5) * 1e-15


def _pysim_names(design, vcd: VcdWindow) -> list[tuple[tuple[str, ...], str, object]]:
    """``(scope, name, signal)`` of the selected signals, scope below the top fragment."""
    clocks = set()
    for domain in design.fragment.domains.values():
        clocks |= {id(domain.clk), id(domain.rst)}
    out = []
    for _fragment, info in design.fragments.items():
        scope = tuple(info.name[1:])
        for signal, name in info.signal_names.items():
            # the time grid is the clock: one sample per cycle says nothing about clk or rst;
            # names from "$" are Amaranth's anonymous signals (as in filter_vcd)
            if (id(signal) not in clocks and not name.startswith("$")
                    and vcd.matches(".".join([*scope, name]))):
                out.append((scope, name, signal))
    return out


class _VcdOut:
    """Value changes of chosen signals, one sample per cycle, written like ``filter_vcd``;
    ``fs``: samples stamped in femtoseconds (clocks of their own), timescale 1 fs."""

    def __init__(self, path: Path, names, fs: bool = False):
        self.path = path
        self._scale = 1 if fs else _PERIOD_PS
        self.tmp = _atomic_target(path)
        self._file = open(self.tmp, "w")
        self.signals = []
        index = {}
        for _scope, _name, signal in names:
            if id(signal) not in index:
                index[id(signal)] = len(self.signals)
                self.signals.append(signal)
        self._vars = [(scope, name, index[id(signal)]) for scope, name, signal in names]
        self._widths = [len(sig) for sig in self.signals]
        self._last: list | None = None
        self._ids = [_vcd_id(k) for k in range(len(self.signals))]
        from mrm_cosim.cosim.compiled import vcd_header

        def var(name, k):
            w = self._widths[k]
            rng = f" [{w - 1}:0]" if w > 1 else ""
            return f"$var wire {w} {self._ids[k]} {name}{rng} $end"

        lines = vcd_header("system", [(scope, var(name, k)) for scope, name, k in self._vars],
                           "1fs" if fs else "1ps")
        self._file.write("\n".join(lines) + "\n")

    def sample(self, stamp: int, values) -> None:
        """Values at ``stamp``: a cycle number, or femtoseconds for a ``fs`` writer."""
        raw = [int(v) & ((1 << w) - 1) for v, w in zip(values, self._widths, strict=True)]
        changed = [k for k, v in enumerate(raw) if self._last is None or self._last[k] != v]
        if not changed:
            return
        out = [f"#{stamp * self._scale}"]
        if self._last is None:
            out.append("$dumpvars")
        for k in changed:
            w, v = self._widths[k], raw[k]
            out.append(f"{v}{self._ids[k]}" if w == 1 else f"b{v:b} {self._ids[k]}")
        if self._last is None:
            out.append("$end")
        self._last = raw
        self._file.write("\n".join(out) + "\n")

    def close(self) -> list[str]:
        self._file.close()
        os.replace(self.tmp, self.path)
        return [".".join([*scope, name]) for scope, name, _ in self._vars]


def _vcd_id(k: int) -> str:
    """Short VCD identifier of variable ``k`` (printable ASCII 33..126)."""
    chars = []
    while True:
        chars.append(chr(33 + k % 94))
        k //= 94
        if not k:
            return "".join(chars)


_imported_fingerprint()     # now, while the sources on disk are the ones being imported
