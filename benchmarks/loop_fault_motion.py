"""The joints during a closed-loop fault campaign's run: each joint's deviation from the same
run without faults, with the faults marked (docs/faults.md, "joint motion during a stop").

Reruns one point (one seed) of a ``level = "loop"`` campaign spec and its reference::

    python benchmarks/loop_fault_motion.py configs/sweeps/link-faults-loop-start.toml --seed 1 \\
        --png docs/img/faults_loop_motion.png
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def main(argv=None) -> int:
    from mrm_cosim.cosim import sweep
    from mrm_cosim.cosim.closed_loop import LineFault
    from mrm_cosim.cosim.experiment_config import from_dict
    from mrm_cosim.cosim.loop_campaign import run_probe
    from mrm_cosim.errors import InputError

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spec")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--png", required=True)
    args = ap.parse_args(argv)
    spec = sweep.load_spec(args.spec)
    if getattr(spec, "level", None) != "loop":
        raise InputError("spec", "must be a campaign of level = \"loop\"")
    points = [p for p in sweep.expand(spec) if p["seed"] == args.seed]
    if not points:
        raise InputError("--seed", f"not one of the spec's seeds {list(spec.seeds)}")
    task = points[0]["task"]
    config = from_dict(task["resolved"])
    run = (config, task["controller"], task["backend"], task["duration"], task["seed"])
    ref, *_ = run_probe(*run)
    faults = [LineFault(f["node"], f["direction"], f["kind"], f["cycle"], f["cycles"])
              for f in task["faults"]]
    res, *_ = run_probe(*run, faults=faults)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(2, 1, figsize=(7.5, 5.2), sharex=True)
    for j in range(res.q.shape[1]):
        ax.plot(1e3 * res.t, 1e6 * (res.q[:, j] - ref.q[:, j]), lw=1, label=f"joint {j + 1}")
        bx.plot(1e3 * res.t, res.tau[:, j], lw=1, label=f"joint {j + 1}")
    for f in task["faults"]:
        t0 = f["cycle"] / 50e6 * 1e3
        for a in (ax, bx):
            a.axvspan(t0, t0 + f["cycles"] / 50e6 * 1e3, color="red", alpha=0.25, lw=0)
        ax.annotate(f"{f['kind']}:{f['direction']}:{f['node']}", (t0, 0), fontsize=6,
                    rotation=90, va="bottom")
    tripped = sorted(res.master.tripped)
    ax.set_ylabel("q − q without faults (µrad)")
    ax.set_title(f"{spec.name}, seed {args.seed}: faults in red; watchdog tripped on node(s) "
                 f"{', '.join(map(str, tripped)) or 'none'}", fontsize=8)
    bx.set_ylabel("torque command (N·m)")
    bx.set_xlabel("time from period 0 (ms)")
    for a in (ax, bx):
        a.grid(True, lw=0.3)
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.png, dpi=110)
    d = np.abs(res.q - ref.q).max(axis=0)
    print(f"largest deviation per joint (µrad): {np.round(1e6 * d, 2).tolist()}; "
          f"tripped nodes {tripped}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
