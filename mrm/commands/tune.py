"""``mrm tune``: one tuning procedure for every controller (issue 20 item 3), each evaluation a
sweep (:mod:`cosim.tune`, :mod:`cosim.sweep`); ``--apply`` writes the chosen gains into the
spec's config with their provenance."""

from __future__ import annotations

import json
import sys

from mrm_cosim.mrm.commands.run import THREADS_HELP, _threads
from mrm_cosim.mrm.flags import TUNE, named_by_flags


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "tune", help="tune every controller with the same optimiser, constraints, budget and "
        "tuning set (held out from the test); tune.json, tune.md, tuned_gains.toml",
        epilog="example:\n  mrm tune configs/tuning/table2.toml --out results/tune --apply")
    p.add_argument("spec", metavar="SPEC", help="tuning spec TOML (docs/experiments.md)")
    p.add_argument("--out", required=True, help="result folder: tune.json, tune.md, "
                   "tuned_gains.toml, <controller>/e<k>/ (one sweep per evaluation)")
    p.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: every core; 1: in this process)")
    p.add_argument("--threads", type=_threads, default=None, metavar="N", help=THREADS_HELP)
    p.add_argument("--apply", action="store_true",
                   help="write the chosen gains and their provenance into the spec's config")
    p.add_argument("--json", action="store_true", help="print the chosen gains as JSON")
    p.set_defaults(func=_tune)


@named_by_flags(TUNE)
def _tune(args) -> int:
    from mrm_cosim.cosim.executors import check_executor_args, make_executor
    from mrm_cosim.cosim.sweep import check_out
    from mrm_cosim.cosim.tune import apply_gains, load_tune_spec, run_tuning

    check_executor_args(args.workers, None)
    check_out(args.out)
    spec = load_tune_spec(args.spec)
    log = None if args.quiet else (lambda m: (sys.stderr.write(f"mrm {m}\n"),
                                              sys.stderr.flush()))
    with make_executor(args.workers, None) as executor:
        record = run_tuning(spec, args.out, executor, log=log)
    chosen = {c: {"gains": r["chosen"]["gains"], "objective": r["chosen"]["objective"],
                  "feasible": r["chosen"]["feasible"]}
              for c, r in record["controllers"].items()}
    if args.apply:
        apply_gains(record, spec.config_path)
    if args.json:
        print(json.dumps({"spec": spec.name, "out": str(args.out), "applied": args.apply,
                          "chosen": chosen}, indent=2))
    elif not args.quiet:
        for c, ch in chosen.items():
            print(f"{c}: {ch['gains']} objective {ch['objective']:.4f}"
                  f"{'' if ch['feasible'] else ' — NO FEASIBLE POINT'}")
        print(f"results in {args.out}/ (tune.md, tune.json, tuned_gains.toml)"
              + (f"; gains written into {spec.config_path}" if args.apply else ""))
    return 0 if all(ch["feasible"] for ch in chosen.values()) else 1
