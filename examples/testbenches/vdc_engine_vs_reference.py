"""A testbench of a node block against its bit-exact reference over random inputs: the VDC engine.

Run it:  python examples/testbenches/vdc_engine_vs_reference.py [--periods 12] [--vcd DIR]

The block is the node's VDC unit (``mrm_cosim.hdl.node.vdc.VdcUnit``: the shared-multiplier
engine running the VDC program of :mod:`mrm_cosim.protocol.vdc_program`), the reference its
Python twin (``mrm_cosim.hdl.node.vdc_ref.VdcModel``). Random gains, adaptation rates and
parameter bounds around Table 1's Type II module are loaded through the engine's host port, as
the node does after a PARAM upload; then every period random velocities, gravity and joint
state go in, the engine runs (``first`` in period 0, ``main`` after it), and the testbench
requires the twelve force words (F_a, F_b) *and* every state word the program keeps from one
period to the next (parameter estimates, velocity history) to equal the reference's, word for
word. tests/test_node_vdc.py does the same with hypothesis drawing extreme words.
"""

import argparse

import numpy as np
from amaranth.sim import Simulator

from mrm_cosim.hdl.node.vdc import VdcUnit
from mrm_cosim.hdl.node.vdc_ref import VdcInputs, VdcModel, vdc_input_words, vdc_state_words
from mrm_cosim.models.robot import load_robot
from mrm_cosim.protocol.isa import IO_BASE
from mrm_cosim.protocol.vdc_program import VdcParams, theta_words, vdc_microcode, vdc_param_words
from mrm_cosim.testbench import run_simulation

G0 = 9.81                           # m/s²


def random_reference(rng) -> VdcModel:
    """The reference with random gains K (6 per link), rates ρ (13 per link) and bounds ±30 %
    around the Type II module's nominal parameters θ."""
    theta = load_robot("mrm3").nominal_theta[1]
    K = rng.uniform(5.0, 200.0, (2, 6))
    rho = rng.uniform(0.0, 1.0, (2, 13)) * np.array([50.0] + [2.0] * 3 + [0.05] * 9)
    lower = theta - np.abs(theta) * 0.3 - 1e-4
    upper = theta + np.abs(theta) * 0.3 + 1e-4
    return VdcModel(VdcParams.from_float(K, rho, lower, upper, 1e-3), theta_words(theta))


def random_inputs(rng, scale: float) -> VdcInputs:
    """q̇_r (rad/s), V and V_r in {C} (m/s, rad/s), q̇, q (rad), gravity in {C} (m/s²)."""
    g = rng.normal(size=3)
    return VdcInputs.from_float(rng.normal() * scale, rng.normal(size=6) * scale,
                                rng.normal(size=6) * scale, rng.normal() * scale,
                                rng.uniform(-np.pi, np.pi), g * G0 / np.linalg.norm(g))


def main(periods: int = 12, seed: int = 3, vcd_dir=None) -> list:
    rng = np.random.default_rng(seed)
    model = random_reference(rng)
    mc = vdc_microcode()
    dut = VdcUnit()
    inputs = [random_inputs(rng, scale=(0.3, 2.0)[p % 2]) for p in range(periods)]
    force_index = [mc.addr(f"F{link}{k}") - IO_BASE for link in "AB" for k in range(6)]
    mismatches = []

    async def write(ctx, words):
        for name, value in words.items():           # host port: one word per cycle, idle only
            ctx.set(dut.host_addr, mc.addr(name))
            ctx.set(dut.host_wdata, value)
            ctx.set(dut.host_we, 1)
            await ctx.tick()
        ctx.set(dut.host_we, 0)

    async def read(ctx, name):
        ctx.set(dut.host_addr, mc.addr(name))
        await ctx.tick()
        return ctx.get(dut.host_rdata)

    async def testbench(ctx):
        await write(ctx, {**vdc_param_words(model.params), **vdc_state_words(model)})
        for period, x in enumerate(inputs):
            await write(ctx, vdc_input_words(x))
            ctx.set(dut.entry, mc.entries["first" if period == 0 else "main"])
            ctx.set(dut.start, 1)
            await ctx.tick()
            ctx.set(dut.start, 0)
            await ctx.tick().until(dut.done)
            await ctx.tick()
            got = [ctx.get(dut.outputs[i]) for i in force_index]
            F_a, F_b = model.step(x)                     # the reference, one period
            if got != F_a + F_b:
                mismatches.append((period, "forces", got, F_a + F_b))
            for name, want in vdc_state_words(model).items():
                value = await read(ctx, name)
                if value != want:
                    mismatches.append((period, name, value, want))

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, "vdc_engine_vs_reference", vcd_dir)
    return mismatches


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--periods", type=int, default=12, help="VDC runs with random inputs")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--vcd", metavar="DIR", help="write the waveform into DIR")
    args = ap.parse_args()
    bad = main(args.periods, args.seed, args.vcd)
    assert not bad, f"RTL != reference: {bad[:3]}"
    print(f"{args.periods} periods of random inputs: the VDC engine equals its reference, "
          f"forces and state, word for word")
