"""Backends that run :class:`hdl.system.System` for the closed loop.

Each offers ``async run(n, inputs, outputs) -> dict`` with the semantics of
:meth:`cosim.compiled.CompiledModel.run` (inputs set, outputs sampled, then a clock edge, per
cycle); the loop is written once, as a coroutine, in :mod:`cosim.closed_loop`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CompiledBackend", "PysimBackend", "Recorder", "drive", "system_verilog"]


def _hdl_fingerprint() -> str:
    """Hash of every gateware source file: the Verilog of a design depends on nothing else."""
    import hashlib
    from pathlib import Path

    import amaranth

    import hdl

    digest = hashlib.sha256(amaranth.__version__.encode())
    root = Path(hdl.__file__).parent
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def system_verilog(factory, key: str) -> tuple[str, dict]:
    """Verilog of the design ``factory()`` builds and its ports' signedness, cached under
    ``key`` plus the gateware sources' fingerprint (converting the three-node system takes
    ~15 s; reading it back, milliseconds). On a cache hit the design is not even built."""
    import json

    from amaranth.back import verilog

    from cosim.compiled import cache_dir, signed_port_map
    from mrm.output import atomic_write_text

    path = cache_dir() / "verilog" / f"{key}-{_hdl_fingerprint()[:20]}.v"
    side = path.with_suffix(".json")
    if path.exists() and side.exists():
        return path.read_text(), json.loads(side.read_text())
    design = factory()
    text = verilog.convert(design, name="system", emit_src=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, text)
    signed = signed_port_map(design)
    atomic_write_text(side, json.dumps(signed))
    return text, signed


class CompiledBackend:
    """Verilator build of the system (Verilog and binary cached by content hashes)."""

    name = "compiled"

    def __init__(self, factory, key: str, quiet: bool = True):
        from cosim.compiled import CompiledModel

        text, signed = system_verilog(factory, key)
        self.model = CompiledModel(None, "system", quiet=quiet, verilog_text=text,
                                   signed_ports=signed)

    async def run(self, n, inputs, outputs):
        return self.model.run(n, inputs, outputs)


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
    """Amaranth's simulator: the reference, slow. The loop runs inside one testbench."""

    name = "pysim"

    def __init__(self, system):
        self.system = system
        self._ctx = None

    def bind(self, ctx) -> None:
        self._ctx = ctx

    async def run(self, n, inputs, outputs):
        ctx, dut = self._ctx, self.system
        ins = [(getattr(dut, k), np.broadcast_to(np.asarray(v), (n,))) for k, v in inputs.items()]
        outs = [getattr(dut, k) for k in outputs]
        rec = np.zeros((n, len(outs)), dtype=np.int64)
        for i in range(n):
            for sig, values in ins:
                ctx.set(sig.as_value() if hasattr(sig, "as_value") else sig, int(values[i]))
            for j, sig in enumerate(outs):
                rec[i, j] = ctx.get(sig.as_value() if hasattr(sig, "as_value") else sig)
            await ctx.tick()
        return {k: rec[:, j] for j, k in enumerate(outputs)}


def drive(coro):
    """Run a coroutine that never really suspends (the compiled backend) to completion."""
    try:
        coro.send(None)
    except StopIteration as stop:
        return stop.value
    raise RuntimeError("the closed loop suspended outside a simulator")
