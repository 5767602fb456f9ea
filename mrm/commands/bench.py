"""``mrm bench``: speed of each co-simulation backend on the same closed-loop window."""

from __future__ import annotations

import json

from mrm_cosim.errors import InputError
from mrm_cosim.mrm.commands.run import THREADS_HELP, _threads
from mrm_cosim.mrm.flags import BENCH, named_by_flags


def register(subparsers) -> None:
    p = subparsers.add_parser("bench", help="simulated cycles/s and real-time factor per backend",
                              epilog="example:\n  mrm bench --backend model --robot mrm3 "
                              "--robot mrm6 --json")
    p.add_argument("--backend", action="append", choices=["model", "compiled", "pysim"],
                   help="backend(s) to measure, repeatable (default: all)")
    p.add_argument("--robot", action="append",
                   help="built-in name or assembly .toml, repeatable (default: mrm3 and mrm6)")
    p.add_argument("--threads", type=_threads, default=None, metavar="N", help=THREADS_HELP)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=_bench)


@named_by_flags(BENCH)
def _bench(args) -> int:
    from mrm_cosim.cosim.bench import bench_backend
    from mrm_cosim.cosim.track import check_robot_fits
    from mrm_cosim.models.robot import load_robot

    backends = args.backend or ["model", "compiled", "pysim"]
    robots = args.robot or ["mrm3", "mrm6"]
    for flag, given in (("--backend", backends), ("--robot", robots)):
        for name in given:
            if given.count(name) > 1:
                raise InputError(flag, f"{name!r} given more than once")
    for name in robots:                 # every robot checked before anything runs
        check_robot_fits(load_robot(name), "robot")
    out = {"robots": {}}
    for robot in robots:
        out["robots"][robot] = {}
        for name in backends:
            r = out["robots"][robot][name] = bench_backend(name, robot)
            if not args.json:
                threads = f", {r['threads']} threads" if r["threads"] > 1 else ""
                print(f"{robot:6s} {name:9s} {r['cycles_per_s']:12,.0f} cycles/s   "
                      f"RTF {r['rtf']:8.2f} wall, {r['cpu_rtf']:8.2f} CPU   "
                      f"({r['cycles']} cycles in {r['wall_s']:.2f} s{threads})")
    if args.json:
        print(json.dumps(out, indent=2))
    return 0
