"""``mrm cache``: list and prune what the backends keep between runs (Verilog, Verilator
builds, the compiled inner loops)."""

from __future__ import annotations

import argparse
import json
import time

from mrm_cosim.cosim.cache import KINDS


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "cache", help="list or prune the cached Verilog, Verilator builds and compiled loops",
        epilog="example:\n  mrm cache list\n  mrm cache prune --older-than 30\n"
        "the cache: $MRM_CACHE_DIR, else $XDG_CACHE_HOME/mrm-cosim, else ~/.cache/mrm-cosim")
    sub = p.add_subparsers(dest="cache_command", required=True)
    pl = sub.add_parser("list", help="the cache's entries by kind: how many, their size, "
                        "their last use", epilog="example:\n  mrm cache list --entries")
    pl.add_argument("--entries", action="store_true", help="every entry, not only the totals")
    pl.add_argument("--json", action="store_true", help="machine-readable output")
    pl.set_defaults(func=_list)
    pp = sub.add_parser("prune", help="remove entries not used for a while (or all)",
                        epilog="example:\n  mrm cache prune --older-than 30\n  mrm cache "
                        "prune --all --kind verilog\nan entry is used when a run takes it "
                        "from the cache; a build under way is left alone")
    age = pp.add_mutually_exclusive_group(required=True)
    age.add_argument("--older-than", type=_days, metavar="DAYS",
                     help="entries not used for DAYS days (a number >= 0)")
    age.add_argument("--all", action="store_true", help="every entry")
    pp.add_argument("--kind", action="append", choices=KINDS,
                    help="only this kind; repeat for several")
    pp.add_argument("--dry-run", action="store_true", help="say what would go, remove nothing")
    pp.set_defaults(func=_prune)


def _days(text: str) -> float:
    """``--older-than``: a number of days >= 0 (argparse names the flag, exit 2)."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"must be a number of days >= 0, not {text!r}")
    return value


def _mb(size: int) -> str:
    return f"{size / 1e6:,.1f} MB"


def _when(t: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M", time.localtime(t))


def _list(args) -> int:
    from mrm_cosim.cosim.cache import entries
    from mrm_cosim.cosim.compiled import cache_dir

    found = entries()
    if args.json:
        print(json.dumps({"cache": str(cache_dir()), "entries": [
            {"kind": e.kind, "name": e.name, "bytes": e.size, "used": e.used,
             "unfinished": e.unfinished, "paths": [str(p) for p in e.paths]}
            for e in found]}, indent=2))
        return 0
    print(f"cache: {cache_dir()}")
    print(f"{'kind':<10} {'entries':>8} {'size':>12}   last used")
    for kind in KINDS:
        mine = [e for e in found if e.kind == kind]
        if mine:
            print(f"{kind:<10} {len(mine):>8} {_mb(sum(e.size for e in mine)):>12}   "
                  f"{_when(max(e.used for e in mine))}")
    print(f"{'total':<10} {len(found):>8} {_mb(sum(e.size for e in found)):>12}")
    if args.entries:
        for e in found:
            note = "  (unfinished build)" if e.unfinished else ""
            print(f"  {e.kind:<10} {_when(e.used)} {_mb(e.size):>10}  {e.name}{note}")
    return 0


def _prune(args) -> int:
    from mrm_cosim.cosim.cache import prune

    gone = prune(None if args.all else args.older_than, args.kind or KINDS,
                 dry_run=args.dry_run)
    verb = "would remove" if args.dry_run else "removed"
    print(f"{verb} {len(gone)} entries, {_mb(sum(e.size for e in gone))}")
    if args.verbose:
        for e in gone:
            print(f"  {e.kind:<10} {_when(e.used)} {_mb(e.size):>10}  {e.name}")
    return 0
