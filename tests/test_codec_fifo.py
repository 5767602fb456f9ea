# amaranth: UnusedElaboratable=no
"""The codecs' block-RAM receive FIFO equals Amaranth's SyncFIFO cycle for cycle (hdl/link/fifo.py).

Both FIFOs get the same random writes and reads (bursts that fill them, runs that drain them,
reads of an empty and writes into a full FIFO); every output is compared in every cycle,
``r_data`` included even while the FIFO is empty (stale data must agree too).
"""

import numpy as np
import pytest
from amaranth import Module
from amaranth.lib.fifo import SyncFIFO
from amaranth.sim import Simulator

from mrm_cosim.hdl.link.fifo import BlockRamFIFO


@pytest.mark.parametrize("depth", [64, 9, 1])
def test_block_ram_fifo_equals_sync_fifo(depth):
    width, n_cycles = 10, 3000
    m = Module()
    m.submodules.ref = ref = SyncFIFO(width=width, depth=depth)
    m.submodules.dut = dut = BlockRamFIFO(width=width, depth=depth)
    rng = np.random.default_rng(depth)
    # phases of write and read probabilities: fill, drain, balanced, idle
    phases = [(0.9, 0.1), (0.1, 0.9), (0.5, 0.5), (0.0, 0.0), (1.0, 1.0), (0.7, 0.3)]

    async def bench(ctx):
        for cycle in range(n_cycles):
            p_w, p_r = phases[(cycle // 97) % len(phases)]
            w_en, r_en = int(rng.random() < p_w), int(rng.random() < p_r)
            data = int(rng.integers(0, 1 << width))
            for f in (ref, dut):
                ctx.set(f.w_en, w_en)
                ctx.set(f.w_data, data)
                ctx.set(f.r_en, r_en)
            for port in ("w_rdy", "r_rdy", "r_data", "level"):
                want, got = ctx.get(getattr(ref, port)), ctx.get(getattr(dut, port))
                assert got == want, f"cycle {cycle}: {port} {got} != SyncFIFO's {want}"
            await ctx.tick()

    sim = Simulator(m)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    sim.run()
