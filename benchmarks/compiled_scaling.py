"""What one simulated cycle of the gateware costs in Verilator, by design size.

Run on purpose (each build takes 1-3 minutes here), not in CI::

    .venv/bin/python benchmarks/compiled_scaling.py [--cycles 200000] [--rounds 3]

Builds the ``system`` top with 1, 2, 3 and 6 slave nodes (3 and 6: ``mrm3``, ``mrm6``; the
master's link port and a daisy chain of nodes, each with its two codecs, router, packet layer
and compute core), the ``node_core`` top alone and the idle DMP generator, with the
co-simulation's default Verilator build
(:class:`cosim.compiled.CompiledModel`), and times ``tick(n)``: the C++ loop of the model with
the inputs held, no Python per cycle, nothing of the plant or the master. After a warm-up the
links have started and send NULLs, the nodes sit unarmed, and each core's encoder pipeline runs
as it does every cycle. That is the least the closed loop can cost per cycle: in closed loop
the engines also run and packets cross the links, and the Python side adds its share.

Prints, per design, the best nanoseconds of CPU time per cycle of ``--rounds`` rounds taken in
turn (the machine is shared: only figures from one run compare), the increment per node, the
DMP generator alone (every node carries one; idle here, as in most cycles of a run), and what the
``compiled`` goal of issue 18 (RTF <= 60, i.e. 1,200 ns per 20 ns cycle for everything) leaves.
``--json`` prints the same as one JSON object.
"""

from __future__ import annotations

import argparse
import json
import time

from mrm_cosim.cosim.compiled import CompiledModel
from mrm_cosim.hdl.tops import build_top

#: the closed loop's cycle: 20 ns at 50 MHz; RTF 60 (issue 18) allows 1,200 ns per cycle
CYCLE_NS = 20.0
GOAL_RTF = 60.0


def _designs() -> list[tuple[str, str, dict]]:
    return [("system, 1 node", "system", {"n_nodes": 1}),
            ("system, 2 nodes", "system", {"n_nodes": 2}),
            ("system, 3 nodes", "system", {"n_nodes": 3}),
            ("system, 6 nodes", "system", {"n_nodes": 6}),
            ("node_core alone", "node_core", {}),
            ("dmp_generator alone", "dmp_generator", {})]


def measure(cycles: int, rounds: int, warmup: int = 20_000) -> dict:
    models = {}
    for label, top, params in _designs():
        t0 = time.perf_counter()
        model = CompiledModel(build_top(top, **params), top)
        model.tick(warmup)
        models[label] = model
        print(f"# built and warmed {label} in {time.perf_counter() - t0:.0f} s", flush=True)
    best = dict.fromkeys(models, float("inf"))
    for _ in range(rounds):
        for label, model in models.items():
            t0 = time.process_time()        # one thread; the machine is shared
            model.tick(cycles)
            best[label] = min(best[label], (time.process_time() - t0) / cycles * 1e9)
    ns = {label: round(v, 1) for label, v in best.items()}
    per_node = (best["system, 3 nodes"] - best["system, 1 node"]) / 2
    per_node_3_6 = (best["system, 6 nodes"] - best["system, 3 nodes"]) / 3
    return {
        "cycles": cycles, "rounds": rounds,
        "ns_per_cycle": ns,
        "ns_per_node": round(per_node, 1),
        "ns_per_node_3_to_6": round(per_node_3_6, 1),
        "ns_fixed": round(best["system, 1 node"] - per_node, 1),
        "dmp_share_of_node": round(best["dmp_generator alone"] / per_node, 3),
        "rtf_3_nodes_model_alone": round(best["system, 3 nodes"] / CYCLE_NS, 1),
        "rtf_6_nodes_model_alone": round(best["system, 6 nodes"] / CYCLE_NS, 1),
        "goal_ns_per_cycle": GOAL_RTF * CYCLE_NS,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=200_000)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    result = measure(args.cycles, args.rounds)
    if args.json:
        print(json.dumps(result, sort_keys=True))
        return 0
    for label, v in result["ns_per_cycle"].items():
        print(f"{label:18s} {v:8.1f} ns/cycle  ({1e9 / v:10,.0f} cycles/s, "
              f"RTF {v / CYCLE_NS:6.1f})")
    print(f"per node (link + core): {result['ns_per_node']:.1f} ns/cycle from 1 to 3 nodes, "
          f"{result['ns_per_node_3_to_6']:.1f} from 3 to 6; "
          f"master port and the rest: {result['ns_fixed']:.1f} ns/cycle")
    print(f"the DMP generator alone (idle): {result['ns_per_cycle']['dmp_generator alone']:.1f} "
          f"ns/cycle, {100 * result['dmp_share_of_node']:.0f} % of a node's increment")
    print(f"issue 18's compiled goal (RTF {GOAL_RTF:g}) allows {result['goal_ns_per_cycle']:.0f} "
          f"ns/cycle for the model, the plant, the master and the loop together")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
