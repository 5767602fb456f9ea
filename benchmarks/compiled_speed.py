"""The ``compiled`` backend's closed loop before and after issue 18's work, side by side.

Run on purpose, not in CI (the first run builds the model: 2-3 minutes here)::

    .venv/bin/python benchmarks/compiled_speed.py [--robot mrm3] [--cycles 250000] [--rounds 3]

``mrm bench``'s compiled window (the VDC loop on the paper's test profile, period 0 at cycle
50,000, ``--cycles`` timed after it) run in turns, in one process, on the same Verilator
build of the same gateware:

* ``before`` — every chunk exchanged as per-cycle arrays (``CompiledBackend(per_cycle=True)``:
  encoder lines, FIFO characters, time-code and fault inputs for every cycle in, eleven
  outputs for every cycle back, then searched in numpy);
* ``after`` — the default: input changes in, output strobes and last values back
  (:meth:`cosim.compiled.CompiledModel.run_events`).

Both must give the same trace hash and the same frames (checked; exit 1 otherwise). Printed:
cycles/s and real-time factor (wall time / simulated time) of the window, on wall time and on
the process's CPU time (the machine is shared: CPU time is the steadier figure), the median
of ``--rounds`` rounds, and the ratio. ``--json`` prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import statistics

import numpy as np

from mrm_cosim.units import CLOCK_HZ

START = 50_000


def _once(robot_name: str, cycles: int, per_cycle: bool) -> dict:
    from mrm_cosim.cosim.backends import CompiledBackend
    from mrm_cosim.cosim.closed_loop import ClosedLoop
    from mrm_cosim.cosim.preview import paper_test_profile
    from mrm_cosim.cosim.track import loop_system, loop_system_key
    from mrm_cosim.master.cycle import Master, MasterTiming
    from mrm_cosim.master.uploads import Gains, node_uploads, pid_gains
    from mrm_cosim.models.plant import Plant
    from mrm_cosim.models.robot import load_robot

    robot = load_robot(robot_name)
    profile = paper_test_profile(robot)

    def trajectory(t):
        q, qd, qdd, _ = profile.evaluate(np.array([t]))
        return q[0], qd[0], qdd[0]

    master = Master(robot, "vdc", trajectory, robot.counts_per_rev, MasterTiming(),
                    pid=pid_gains(robot, 5.0))
    plant = Plant(robot, seed=0)
    plant.reset(robot.home)
    backend = CompiledBackend(lambda: loop_system(robot), loop_system_key(robot),
                              quiet=False, per_cycle=per_cycle)
    loop = ClosedLoop(robot, backend, master, plant, START, node_uploads(robot, "vdc", Gains()))
    result = loop.run(cycles)
    backend.model.close()
    return {"wall": result.window_wall_s, "cpu": result.window_cpu_s,
            "hash": result.trace_sha256, "frames": result.frames}


def measure(robot: str, cycles: int, rounds: int) -> dict:
    variants = {"before": True, "after": False}
    runs: dict[str, list] = {k: [] for k in variants}
    _once(robot, 10_000, False)                       # build, warm caches
    for _ in range(rounds):
        for name, per_cycle in variants.items():
            runs[name].append(_once(robot, cycles, per_cycle))
    sim_s = cycles / CLOCK_HZ
    out = {"robot": robot, "cycles": cycles, "rounds": rounds}
    for name, rs in runs.items():
        wall = statistics.median(r["wall"] for r in rs)
        cpu = statistics.median(r["cpu"] for r in rs)
        out[name] = {"cycles_per_s": cycles / wall, "rtf_wall": wall / sim_s,
                     "rtf_cpu": cpu / sim_s}
    ref = runs["before"][0]
    out["same_trace"] = all(r["hash"] == ref["hash"] and r["frames"] == ref["frames"]
                            for rs in runs.values() for r in rs)
    out["trace_sha256"] = ref["hash"]
    out["ratio_wall"] = out["before"]["rtf_wall"] / out["after"]["rtf_wall"]
    out["ratio_cpu"] = out["before"]["rtf_cpu"] / out["after"]["rtf_cpu"]
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="mrm3")
    parser.add_argument("--cycles", type=int, default=250_000)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    r = measure(args.robot, args.cycles, args.rounds)
    if args.json:
        print(json.dumps(r, sort_keys=True))
    else:
        print(f"{args.robot}, {args.cycles:,} cycles after period 0, median of "
              f"{args.rounds} rounds taken in turn")
        print(f"{'':8s}{'cycles/s':>12s}{'RTF wall':>10s}{'RTF CPU':>9s}")
        for name in ("before", "after"):
            v = r[name]
            print(f"{name:8s}{v['cycles_per_s']:12,.0f}{v['rtf_wall']:10.1f}{v['rtf_cpu']:9.1f}")
        print(f"after / before: x{r['ratio_wall']:.2f} (wall), x{r['ratio_cpu']:.2f} (CPU); "
              f"trace {'identical' if r['same_trace'] else 'DIFFERENT'} "
              f"({r['trace_sha256'][:16]})")
    return 0 if r["same_trace"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
