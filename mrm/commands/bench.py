"""``mrm bench``: speed of each co-simulation backend on the same closed-loop window."""

from __future__ import annotations

import json

from mrm_cosim.errors import InputError
from mrm_cosim.mrm.flags import BENCH, named_by_flags


def register(subparsers) -> None:
    p = subparsers.add_parser("bench", help="simulated cycles/s and real-time factor per backend",
                              epilog="example:\n  mrm bench --backend model --backend compiled "
                              "--json")
    p.add_argument("--backend", action="append", choices=["model", "compiled", "pysim"],
                   help="backend(s) to measure, repeatable (default: all)")
    p.add_argument("--robot", default="mrm3", help="built-in name or assembly .toml")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=_bench)


@named_by_flags(BENCH)
def _bench(args) -> int:
    from mrm_cosim.cosim.bench import bench_backend

    backends = args.backend or ["model", "compiled", "pysim"]
    for name in backends:
        if backends.count(name) > 1:
            raise InputError("--backend", f"{name!r} given more than once")
    out = {"robot": args.robot, "backends": {}}
    for name in backends:
        out["backends"][name] = bench_backend(name, args.robot)
        if not args.json:
            r = out["backends"][name]
            print(f"{name:9s} {r['cycles_per_s']:12,.0f} cycles/s   RTF {r['rtf']:10.1f}   "
                  f"({r['cycles']} cycles in {r['wall_s']:.2f} s)")
    if args.json:
        print(json.dumps(out, indent=2))
    return 0
