"""Simulation speed of the node: the core in Amaranth's pysim, and the transaction-level model.

Run: ``.venv/bin/python benchmarks/node_sim_speed.py [--cycles 20000]``. Prints cycles/s of a
NodeCore free-running its control ticks (encoder lines moving), and control ticks/s and VDC
periods/s of :class:`hdl.node.core_ref.NodeModel` (the ``model`` backend's building block).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from amaranth.sim import Simulator

from mrm_cosim.protocol.packet import PacketType
from mrm_cosim.hdl.node.core import NodeCore
from mrm_cosim.hdl.node.core_ref import NodeModel
from mrm_cosim.protocol.regs import Config, config_payloads, pack_comm_b, pack_comm_d
from mrm_cosim.models.encoder import quadrature_levels


def pysim_speed(cycles: int) -> float:
    dut = NodeCore()
    counts = np.arange(cycles) // 70
    a, b = quadrature_levels(counts)

    async def lines(ctx):
        for k in range(cycles):
            ctx.set(dut.enc_a, int(a[k]))
            ctx.set(dut.enc_b, int(b[k]))
            await ctx.tick()

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(lines)
    t0 = time.perf_counter()
    sim.run()
    return cycles / (time.perf_counter() - t0)


def model_speed(n: int) -> tuple[float, float]:
    """Control ticks/s of the reference on its timer (``run``), then VDC periods/s."""
    model = NodeModel()
    model.packet(0, PacketType.CONFIG, config_payloads({Config.ARM: 1})[0])
    sample = lambda c: (c // 50, 1000, 0)          # noqa: E731 - a moving encoder
    t0 = time.perf_counter()
    model.run(50 * n, sample)
    ticks = n / (time.perf_counter() - t0)
    rng = np.random.default_rng(0)
    b = pack_comm_b(0.1, rng.normal(size=6), rng.normal(size=6))
    d = pack_comm_d(0.0, [0, 0, 9.81], 0.0, 0.0, 0.0)
    start = 50 * n + 50_000
    t0 = time.perf_counter()
    for k in range(200):
        base = start + k * 50_000
        model.timecode(base + 100, k & 63, sample)
        model.packet(base + 200, PacketType.COMM_D, d, sample=sample)
        model.packet(base + 300, PacketType.COMM_B, b, sample=sample)
    return ticks, 200 / (time.perf_counter() - t0)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=20_000)
    args = parser.parse_args()
    print(f"NodeCore in pysim: {pysim_speed(args.cycles):,.0f} cycles/s")
    ticks, periods = model_speed(20_000)
    print(f"NodeModel: {ticks:,.0f} control ticks/s, {periods:,.1f} periods/s "
          "(a time-code, Comm D, Comm B with its VDC run and 1,000 ticks each)")


if __name__ == "__main__":
    main()
