"""Running a simulation, with a waveform on request."""

import contextlib
import os

from amaranth.sim import Simulator

__all__ = ["run_simulation"]


def run_simulation(sim: Simulator, name: str, vcd_dir: str | None = None):
    """Run ``sim``; write ``<name>.vcd`` (every signal) into ``vcd_dir``, or into
    ``$SIM_VCD_DIR`` when that is set and ``vcd_dir`` is not given; no waveform otherwise
    (``SIM_VCD_DIR=waves pytest tests/test_codec_link.py`` dumps every testbench's)."""
    vcd_dir = vcd_dir or os.environ.get("SIM_VCD_DIR")
    if vcd_dir:
        os.makedirs(vcd_dir, exist_ok=True)
        writer = sim.write_vcd(os.path.join(vcd_dir, f"{name}.vcd"))
    else:
        writer = contextlib.nullcontext()
    with writer:
        sim.run()
