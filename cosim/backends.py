"""Backends that run :class:`hdl.system.System` for the closed loop.

Each offers ``async run(n, inputs, outputs) -> dict`` with the semantics of
:meth:`cosim.compiled.CompiledModel.run` (inputs set, outputs sampled, then a clock edge, per
cycle); the loop is written once, as a coroutine, in :mod:`cosim.closed_loop`.
"""

from __future__ import annotations

import fnmatch
import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mrm_cosim.errors import InputError
from mrm_cosim.units import CLOCK_HZ

__all__ = ["CompiledBackend", "PysimBackend", "Recorder", "VcdWindow", "drive",
           "system_verilog", "CLOCK_HZ"]

#: One cycle of the gateware's clock in picoseconds (20 ns).
_PERIOD_PS = 1_000_000_000_000 // CLOCK_HZ


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

    from mrm_cosim.cosim.compiled import cache_dir, signed_port_map
    from mrm_cosim.results import atomic_write_text

    fingerprint = _imported_fingerprint()
    path = cache_dir() / "verilog" / f"{key}-{fingerprint[:20]}.v"
    side = path.with_suffix(".json")
    if path.exists() and side.exists():
        return path.read_text(), json.loads(side.read_text())
    design = factory()
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
        Where the VCD goes (written atomically when the window closes).
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


class CompiledBackend:
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
    """

    name = "compiled"

    def __init__(self, factory, key: str, quiet: bool = True, vcd: VcdWindow | None = None):
        from mrm_cosim.cosim.compiled import CompiledModel

        text, signed = system_verilog(factory, key)
        self.model = CompiledModel(None, "system", quiet=quiet, verilog_text=text,
                                   signed_ports=signed, trace=vcd is not None)
        self.vcd = vcd
        self._raw: Path | None = None
        self._vcd_done = False

    async def run(self, n, inputs, outputs):
        if self.vcd is None or self._vcd_done:
            return self.model.run(n, inputs, outputs)
        parts, lo = [], 0
        while lo < n:
            cycle = self.model.cycles
            if self._raw is None and self.vcd.start <= cycle < self.vcd.stop:
                self._open()
            elif self._raw is not None and cycle >= self.vcd.stop:
                self.finish()
            edge = self.vcd.start if self._raw is None else self.vcd.stop
            hi = n if edge <= cycle or self._vcd_done else min(n, lo + edge - cycle)
            parts.append(self.model.run(hi - lo, _slice_inputs(inputs, n, lo, hi), outputs))
            lo = hi
        if self._raw is not None and self.model.cycles == self.vcd.stop:
            self.finish()
        return {k: np.concatenate([p[k] for p in parts]) for k in outputs}

    def _open(self) -> None:
        fd, raw = tempfile.mkstemp(prefix="mrm-trace-", suffix=".vcd")
        os.close(fd)
        self._raw = Path(raw)
        self.model.trace_open(self._raw)

    def finish(self) -> list[str] | None:
        """Close the window now (also at its end, or if the run ends inside it) and write the
        VCD of the selected signals. Returns their names, or ``None`` if nothing was open."""
        from mrm_cosim.cosim.compiled import filter_vcd

        if self._raw is None:
            return None
        self.model.trace_close()
        tmp = _atomic_target(self.vcd.path)
        try:
            names = filter_vcd(self._raw, tmp, "system", self.vcd.matches, _PERIOD_PS)
            os.replace(tmp, self.vcd.path)
        finally:
            tmp.unlink(missing_ok=True)
            self._raw.unlink(missing_ok=True)
            self._raw = None
            self._vcd_done = True
        return names


class Recorder:
    """Wraps a backend and keeps every per-cycle output sample it returns (for comparisons)."""

    def __init__(self, backend):
        self.backend = backend
        self.samples: dict[str, list] = {}

    def bind(self, ctx) -> None:
        self.backend.bind(ctx)

    async def run(self, n, inputs, outputs):
        out = await self.backend.run(n, inputs, outputs)
        for k, v in out.items():
            self.samples.setdefault(k, []).append(np.array(v))
        return out

    def trace(self, name: str) -> np.ndarray:
        return np.concatenate(self.samples[name])


class PysimBackend:
    """Amaranth's simulator: the reference, slow. The loop runs inside one testbench.

    Parameters
    ----------
    system : Component
    vcd : VcdWindow, optional
        Record that window. The signal names come from the simulator's own view of the
        design, so the simulator must be made by :meth:`simulator`.
    """

    name = "pysim"

    def __init__(self, system, vcd: VcdWindow | None = None):
        self.system = system
        self.vcd = vcd
        self.cycle = 0
        self._ctx = None
        self._names = None
        self._trace = None

    def simulator(self):
        """A ``Simulator`` of the system with its 50 MHz clock (and the names for the VCD)."""
        from amaranth.sim import Simulator

        sim = Simulator(self.system)
        sim.add_clock(1 / CLOCK_HZ)
        if self.vcd is not None:
            # Amaranth 0.5 names signals per fragment only inside the simulator it built
            # (Simulator.write_vcd cannot start late or select signals): take them from there.
            self._names = _pysim_names(sim._design, self.vcd)
        return sim

    def bind(self, ctx) -> None:
        self._ctx = ctx
        if self.vcd is not None and self._names is None:
            raise RuntimeError("a VCD from pysim needs the simulator made by "
                               "PysimBackend.simulator()")

    async def run(self, n, inputs, outputs):
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
            if vcd is not None and vcd.start <= self.cycle < vcd.stop:
                self._sample(ctx)
            await ctx.tick()
            self.cycle += 1
            if vcd is not None and self.cycle == vcd.stop:
                self.finish()
        return {k: rec[:, j] for j, k in enumerate(outputs)}

    def _sample(self, ctx) -> None:
        if self._trace is None:
            self._trace = _VcdOut(self.vcd.path, self._names)
        self._trace.sample(self.cycle, [ctx.get(sig) for sig in self._trace.signals])

    def finish(self) -> list[str] | None:
        """Close the window now (also at its end, or if the run ends inside it) and write the
        VCD. Returns the names of the signals in it, or ``None`` if nothing was recorded."""
        if self._trace is None:
            return None
        names, self._trace = self._trace.close(), None
        self.vcd = None
        return names


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
    """Value changes of chosen signals, one sample per cycle, written like ``filter_vcd``."""

    def __init__(self, path: Path, names):
        self.path = path
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

        lines = vcd_header("system", [(scope, var(name, k)) for scope, name, k in self._vars])
        self._file.write("\n".join(lines) + "\n")

    def sample(self, cycle: int, values) -> None:
        raw = [int(v) & ((1 << w) - 1) for v, w in zip(values, self._widths, strict=True)]
        changed = [k for k, v in enumerate(raw) if self._last is None or self._last[k] != v]
        if not changed:
            return
        out = [f"#{cycle * _PERIOD_PS}"]
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


def drive(coro):
    """Run a coroutine that never really suspends (the compiled backend) to completion."""
    try:
        coro.send(None)
    except StopIteration as stop:
        return stop.value
    raise RuntimeError("the closed loop suspended outside a simulator")


_imported_fingerprint()     # now, while the sources on disk are the ones being imported
