"""mrm-cosim: cycle-accurate FPGA co-simulation of a modular robot manipulator.

The package ``mrm`` holds the command-line interface and what every layer shares (input
errors). The system itself lives in the top-level packages ``hdl`` (gateware), ``master``
(upper controller and trajectories) and ``models`` (robot descriptions and the plant).
"""

__version__ = "0.1.0"
