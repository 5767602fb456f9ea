"""Backends that run :class:`hdl.system.System` for the closed loop.

Each offers ``async run(n, inputs, outputs) -> dict`` with the semantics of
:meth:`cosim.compiled.CompiledModel.run` (inputs set, outputs sampled, then a clock edge, per
cycle); the loop is written once, as a coroutine, in :mod:`cosim.closed_loop`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CompiledBackend", "PysimBackend", "drive"]


class CompiledBackend:
    """Verilator build of the system (cached by a hash of its Verilog)."""

    name = "compiled"

    def __init__(self, system, quiet: bool = True):
        from cosim.compiled import CompiledModel

        self.model = CompiledModel(system, "system", quiet=quiet)

    async def run(self, n, inputs, outputs):
        return self.model.run(n, inputs, outputs)


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
