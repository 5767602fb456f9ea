"""Link-level fault campaign: ≥ 10⁵ line faults on two codecs in Run, each judged on its own.

Run on purpose (about 20 min for 10⁵ faults on 2 cores; a small one runs in CI,
tests/test_link_faults.py)::

    python benchmarks/link_fault_campaign.py --faults 100000 --workers 2 --json results/lf.json

Prints the per-kind table of docs/faults.md (cosim/link_faults.py has the method).
"""

from __future__ import annotations

import argparse
import json
import sys

from mrm_cosim.cosim.link_faults import KINDS, run_campaign, summarize, table_markdown


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--faults", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    ap.add_argument("--fifo-depth", type=int, default=64, help="codec rx_fifo_depth")
    ap.add_argument("--json", default=None, help="also save the rows and the summary here")
    args = ap.parse_args(argv)
    rows, wall = run_campaign(args.faults, seed=args.seed, workers=args.workers,
                              kinds=args.kinds, params={"rx_fifo_depth": args.fifo_depth})
    summary = summarize(rows)
    print(table_markdown(summary))
    print(f"{len(rows)} faults in {wall:.0f} s")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"summary": summary, "rows": rows, "wall_s": wall}, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
