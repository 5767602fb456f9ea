"""Where the ``compiled`` backend's closed loop spends its CPU time: the model or the rest.

Run on purpose, not in CI (the first run builds the model: 2-3 minutes here)::

    .venv/bin/python benchmarks/compiled_speed.py [--robot mrm3] [--cycles 250000] [--rounds 3]

``mrm bench``'s compiled window (the VDC loop on the paper's test profile, period 0 at cycle
50,000, ``--cycles`` timed after it), with the process's CPU time split between the calls into
the Verilated model (:meth:`cosim.compiled.CompiledModel.run`: the C++ loop over the chunk's
cycles and the numpy packing of its per-cycle inputs and outputs) and everything else (plant,
master, encoder lines, the loop). Prints per simulated cycle: the whole window, the model
calls, the rest, and the real-time factors on wall and CPU time, the median of ``--rounds``
runs. What it showed on 25 Nov (docs/performance.md, "Compiled backend (issue 18)"): the rest
is about a tenth, so no rework of the Python side can bring the backend near issue 18's goal
(RTF 60, 1,200 ns per cycle for everything). ``--json`` prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time


from mrm_cosim.units import CLOCK_HZ

START = 50_000
GOAL_RTF = 60.0


def _once(robot_name: str, cycles: int) -> dict:
    from mrm_cosim.cosim.backends import CompiledBackend
    from mrm_cosim.cosim.closed_loop import ClosedLoop
    from mrm_cosim.cosim.track import loop_system, loop_system_key
    from mrm_cosim.master.uploads import Gains, node_uploads
    from mrm_cosim.models.robot import load_robot

    robot = load_robot(robot_name)
    from mrm_cosim.cosim.bench import bench_master_and_plant

    master, plant = bench_master_and_plant(robot)
    backend = CompiledBackend(lambda: loop_system(robot), loop_system_key(robot), quiet=False)
    model = backend.model
    run = model.run
    spent = {"model": 0.0, "on": False}

    def timed_run(*args, **kwargs):
        t0 = time.process_time()
        try:
            return run(*args, **kwargs)
        finally:
            if spent["on"]:
                spent["model"] += time.process_time() - t0

    begin = backend.begin

    def timed_begin(*args, **kwargs):
        spent["on"] = True          # period 0: the window the loop's own clocks time
        return begin(*args, **kwargs)

    model.run = timed_run
    backend.begin = timed_begin
    loop = ClosedLoop(robot, backend, master, plant, START, node_uploads(robot, "vdc", Gains()))
    result = loop.run(cycles)
    model.close()
    return {"wall": result.window_wall_s, "cpu": result.window_cpu_s, "model": spent["model"],
            "hash": result.trace_sha256}


def measure(robot: str, cycles: int, rounds: int) -> dict:
    _once(robot, 10_000)                              # build, warm caches
    runs = [_once(robot, cycles) for _ in range(rounds)]
    sim_s = cycles / CLOCK_HZ
    wall = statistics.median(r["wall"] for r in runs)
    cpu = statistics.median(r["cpu"] for r in runs)
    share = statistics.median(r["model"] / r["cpu"] for r in runs)
    ns = cpu / cycles * 1e9
    return {"robot": robot, "cycles": cycles, "rounds": rounds,
            "rtf_wall": wall / sim_s, "rtf_cpu": cpu / sim_s,
            "ns_per_cycle": ns, "ns_model": ns * share, "ns_rest": ns * (1 - share),
            "model_share": share, "goal_ns_per_cycle": GOAL_RTF * 1e9 / CLOCK_HZ,
            "same_trace": len({r["hash"] for r in runs}) == 1, "trace_sha256": runs[0]["hash"]}


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
        return 0 if r["same_trace"] else 1
    print(f"{args.robot}, {args.cycles:,} cycles after period 0, median of {args.rounds} runs")
    print(f"RTF {r['rtf_wall']:.1f} (wall), {r['rtf_cpu']:.1f} (CPU); "
          f"{r['ns_per_cycle']:,.0f} ns of CPU per 20 ns cycle")
    print(f"  in the model's run() calls: {r['ns_model']:8,.0f} ns "
          f"({100 * r['model_share']:.0f} %)")
    print(f"  plant, master, lines, loop: {r['ns_rest']:8,.0f} ns "
          f"({100 * (1 - r['model_share']):.0f} %)")
    print(f"issue 18's goal (RTF {GOAL_RTF:g}) allows {r['goal_ns_per_cycle']:,.0f} ns per cycle "
          f"for all of it; trace {r['trace_sha256'][:16]}"
          f"{'' if r['same_trace'] else ' (DIFFERED between runs)'}")
    return 0 if r["same_trace"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
