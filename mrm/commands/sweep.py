"""``mrm sweep``: many independent runs of an experiment (grids, draws, seeds), on all local
cores by default or on a Dask cluster (:mod:`cosim.sweep`, :mod:`cosim.executors`)."""

from __future__ import annotations

import json
import sys

from mrm_cosim.mrm.commands.run import THREADS_HELP, _threads
from mrm_cosim.mrm.flags import SWEEP, named_by_flags


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "sweep", help="run an experiment over grids, random or Latin-hypercube draws, plant "
        "seeds, controllers and backends; points.jsonl as results arrive, summary.md, plots",
        epilog="example:\n  mrm sweep configs/sweeps/table2-seeds.toml --out results/seeds\n"
        "  mrm sweep my.toml --out results/s --scheduler tcp://10.0.0.5:8786\n"
        "  mrm sweep my.toml --out results/s --resume")
    p.add_argument("spec", metavar="SPEC", help="sweep spec TOML (docs/sweeps.md)")
    p.add_argument("--out", required=True, help="result folder: points.jsonl, sweep.toml, "
                   "summary.md, plots, points/<id>/")
    p.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: every core; 1: in this process)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run the points on Dask: tcp://HOST:8786 or local-dask (needs "
                   "pip install 'mrm-cosim[sweep]')")
    p.add_argument("--threads", type=_threads, default=None, metavar="N", help=THREADS_HELP)
    p.add_argument("--resume", action="store_true",
                   help="skip the points --out already has finished")
    p.add_argument("--json", action="store_true", help="print the outcome as JSON on stdout")
    p.set_defaults(func=_sweep)


@named_by_flags(SWEEP)
def _sweep(args) -> int:
    from mrm_cosim.cosim.executors import check_executor_args, make_executor
    from mrm_cosim.cosim.sweep import check_out, expand, load_spec, print_progress, run_sweep

    check_executor_args(args.workers, args.scheduler)
    check_out(args.out, args.resume)
    spec = load_spec(args.spec)
    points = expand(spec)                   # every point validated before anything runs
    if not args.quiet:
        sys.stderr.write(f"mrm sweep: {spec.name}: {len(points)} points\n")
    progress = None if args.quiet else print_progress
    with make_executor(args.workers, args.scheduler) as executor:
        outcome = run_sweep(spec, args.out, executor, resume=args.resume, progress=progress)
    brief = {k: outcome[k] for k in ("total", "ran", "skipped", "failed")}
    if args.json:
        print(json.dumps({"sweep": spec.name, "out": str(args.out), **brief,
                          "executor": executor.name}, indent=2))
    elif not args.quiet:
        print(f"{brief['total']} points: {brief['ran']} run, {brief['skipped']} already done, "
              f"{brief['failed']} failed; results in {args.out}/ (points.jsonl, summary.md)")
    if outcome["failed"]:
        for row in outcome["rows"]:
            if row["status"] != "ok":
                sys.stderr.write(f"mrm sweep: point {row['id']} ({row['controller']}, seed "
                                 f"{row['seed']}, {row['params']}) failed: "
                                 f"{row['error'].strip().splitlines()[-1]}\n")
        return 1
    return 0
