"""mrm-cosim: cycle-accurate FPGA co-simulation of a modular robot manipulator.

One import root for everything installed. The rooms, each a folder of the repository mapped
under this package by ``pyproject.toml`` (docs/architecture.md has the picture and the import
rules, which ``tests/test_architecture.py`` enforces):

- :mod:`mrm_cosim.protocol` — what travels on the link and how the nodes' words are encoded
  (pure Python; imported by the gateware, the references and the master alike);
- :mod:`mrm_cosim.hdl` — the gateware (Amaranth) and, as its siblings, the bit-exact references;
- :mod:`mrm_cosim.master` — the upper controller and the trajectories (no Amaranth);
- :mod:`mrm_cosim.models` — the physical world (robot descriptions, plant, drives, encoders);
- :mod:`mrm_cosim.cosim` — the closed loop that wires them, with every backend behind one
  interface, and the experiments;
- :mod:`mrm_cosim.mrm` — only the command line.

This module and its siblings ``errors``, ``units`` and ``results`` are the kernel every room may
use: input errors named after fields, the clock, and the result-folder writer.
"""

__version__ = "0.1.0"
