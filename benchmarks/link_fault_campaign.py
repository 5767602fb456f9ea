"""Link-level fault campaign: ≥ 10⁵ line faults on two codecs in Run, each judged on its own.

The campaign is a kind of sweep (cosim/fault_campaign.py); run on purpose (about 30-60 min
for 10⁵ faults on 2 shared cores; a small one runs in CI, tests/test_fault_campaign.py)::

    nice mrm sweep configs/sweeps/link-faults.toml --out results/link-faults --workers 2

This script writes the summary (summary.md, summary.json, recovery.png, detectors.png) of a
campaign folder from the points it has finished so far — a campaign still running, or killed
(``mrm sweep ... --resume`` then runs only the rest)::

    python benchmarks/link_fault_campaign.py --summarize results/link-faults

or, without the sweep machinery, runs the campaign in this process and prints the table::

    python benchmarks/link_fault_campaign.py --faults 1000 --workers 2
"""

from __future__ import annotations

import argparse
import json
import sys

from mrm_cosim.cosim.link_faults import KINDS, run_campaign, summarize, table_markdown


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--summarize", default=None, metavar="FOLDER",
                    help="write the summary of this campaign folder and print its table")
    ap.add_argument("--faults", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    ap.add_argument("--fifo-depth", type=int, default=64, help="codec rx_fifo_depth")
    ap.add_argument("--json", default=None, help="also save the rows and the summary here")
    args = ap.parse_args(argv)
    if args.summarize:
        from mrm_cosim.cosim.fault_campaign import summarize_folder

        doc = summarize_folder(args.summarize)
        print(f"{doc['faults']} faults in {doc['finished']} of {doc['points']} points")
        print((__import__("pathlib").Path(args.summarize) / "summary.md").read_text())
        return 0
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
