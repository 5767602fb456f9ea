"""The motion-primitive comparison over plant seeds: does the order of the architectures hold
on plants other than seed 0?

Runs `cosim.dmp_table2.run_architecture` for one path of ``configs/dmp_table2.toml`` and one
master period over seeds 1..N (seed 0 is the published table's), every architecture, side by
side on the machine's cores, and prints the median and the 5–95 % range of each
architecture's RMSE (eq. 11) and RMS tool position error, and on how many seeds the order
modularized < traditional holds.

    python benchmarks/dmp_seeds.py --path line --period 10 --seeds 8 --jobs 2
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from functools import partial

import numpy as np

from mrm_cosim.cosim.dmp_table2 import (ARCHITECTURES, load_dmp_config, prepare_path,
                                        run_architecture)
from mrm_cosim.cosim.executors import LocalExecutor


def _point(ctx, item, report):
    cfg, ref, dmp, period = ctx
    seed, arch = item
    run = run_architecture(replace(cfg, seed=seed), cfg.robot, ref, dmp, arch, period)
    return {"seed": seed, "architecture": arch, **run.rmse(),
            "clean": run.summary["dmp_errors"] == 0 and not any(
                run.summary["node_counters"].values())}



def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--path", default="line")
    ap.add_argument("--period", type=int, default=10, help="master period, ms")
    ap.add_argument("--seeds", type=int, default=8, help="seeds 1..N")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", default=None, help="write every run's figures here")
    args = ap.parse_args(argv)
    cfg = load_dmp_config()
    spec = next(p for p in cfg.paths if p.name == args.path)
    _, ref, dmp, fit = prepare_path(cfg, spec)
    items = [(s, a) for s in range(1, args.seeds + 1) for a in ARCHITECTURES]
    rows = []
    with LocalExecutor(args.jobs) as ex:
        for i, status, value in ex.run(partial(_point, (cfg, ref, dmp, args.period)), items):
            if status != "ok":
                raise SystemExit(f"run {items[i]} failed: {value}")
            rows.append(value)
            print(f"seed {value['seed']} {value['architecture']}: eq.11 {value['paper']:.3e}, "
                  f"RMS position {value['rms_position_mm']:.3f} mm", flush=True)
    print(f"\n{args.path}, {args.period} ms master, seeds 1..{args.seeds} (primitive fit "
          f"{fit * 1e3:.2f} mrad):")
    print("| architecture | RMSE eq. (11), median [5–95 %] | RMS position (mm), median "
          "[5–95 %] | clean runs |")
    print("|---|---|---|---|")
    for arch in ARCHITECTURES:
        r = [x for x in rows if x["architecture"] == arch]
        p = np.array([x["paper"] for x in r])
        m = np.array([x["rms_position_mm"] for x in r])
        print(f"| {arch} | {np.median(p):.2e} [{np.percentile(p, 5):.2e}, "
              f"{np.percentile(p, 95):.2e}] | {np.median(m):.3f} [{np.percentile(m, 5):.3f}, "
              f"{np.percentile(m, 95):.3f}] | {sum(x['clean'] for x in r)}/{len(r)} |")
    by = {(x["seed"], x["architecture"]): x["paper"] for x in rows}
    holds = sum(by[(s, "modularized")] < by[(s, "traditional")]
                for s in range(1, args.seeds + 1))
    print(f"\nmodularized < traditional on {holds} of {args.seeds} seeds")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
