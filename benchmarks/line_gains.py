"""VDC gains for the Cartesian line on mrm6, chosen on a held-out move.

``configs/table2.toml``'s VDC gains were tuned on mrm3's quintic; on the six-module arm they
make the torque chatter at the limits whenever the joints are slow (the start and the hold of
``examples/line.toml``). This script runs candidate gain sets on a move the shipped figures do
not use — ``examples/line.toml`` backwards, end pose to start pose — and prints, per set, the
largest tool position and orientation error, the largest torque as a fraction of each
module's peak torque, and the torque's roughness (mean |Δτ| per plant step, N·m). The rule
that picked ``configs/line.toml``'s gains: the smallest position error among the sets whose
torque stays below 80 % of every module's peak torque. It runs for minutes, never in CI.

    python benchmarks/line_gains.py                        # the candidate grid below
    python benchmarks/line_gains.py --set lam=100 k_j=30 K=20 friction_comp=0.5
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from mrm_cosim.cosim.experiment_config import load
from mrm_cosim.cosim.line import run_line
from mrm_cosim.master.trig_planner import plan_line
from mrm_cosim.models.robot import load_robot
from mrm_cosim.master.line_file import load_line_file

#: (lam, k_j, K, friction_comp): table2's, the code's defaults, and steps between them.
CANDIDATES = [(200.0, 60.0, 50.0, 1.0), (50.0, 30.0, 0.0, 0.0), (100.0, 30.0, 0.0, 0.0),
              (100.0, 30.0, 20.0, 0.0), (100.0, 30.0, 20.0, 0.5), (200.0, 60.0, 0.0, 0.0),
              (200.0, 60.0, 20.0, 0.0), (100.0, 30.0, 50.0, 0.5), (200.0, 60.0, 20.0, 0.5)]


def point(gains, config, plan, robot) -> dict:
    t0 = time.perf_counter()
    run = run_line(robot, plan, controller="vdc", backend=config.backend, seed=config.seed,
                   gains=gains, timing=config.timing, plant_config=config.plant)
    tau = run.result.tau
    return {"pos_mm": float(run.errors.position_mm.max()),
            "ori_mrad": float(run.errors.orientation_mrad.max()),
            "peak_frac": float((np.abs(tau).max(axis=0) / robot.peak_torques).max()),
            "rough": float(np.abs(np.diff(tau, axis=0)).mean()),
            "wall_s": time.perf_counter() - t0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=None, help="experiment TOML (default: table2.toml)")
    ap.add_argument("--set", nargs="*", default=None, metavar="NAME=VALUE",
                    help="one gain set instead of the grid")
    args = ap.parse_args(argv)
    config = load(args.config)
    robot = load_robot("mrm6")
    start, end, limits = load_line_file("examples/line.toml")
    plan = plan_line(end, start, limits)                 # held out: the move backwards
    if args.set is not None:
        sets = [{k: float(v) for k, v in (s.split("=", 1) for s in args.set)}]
    else:
        sets = [dict(zip(("lam", "k_j", "K", "friction_comp"), c, strict=True))
                for c in CANDIDATES]
    print("lam k_j K friction_comp | max pos (mm) | max ori (mrad) | max |τ|/peak | "
          "mean |Δτ| (N·m) | wall (s)")
    for s in sets:
        r = point(replace(config.gains, **s), config, plan, robot)
        print(f"{s} | {r['pos_mm']:.4f} | {r['ori_mrad']:.4f} | {r['peak_frac']:.2f} | "
              f"{r['rough']:.4f} | {r['wall_s']:.0f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
