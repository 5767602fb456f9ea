"""Line faults in the running closed loop: is every one counted, what does it cost, does the loop
recover?

Each run is the 3-module VDC loop on the compiled gateware (``cosim.track.run_track``) with one
fault (``cosim.closed_loop.LineFault``) injected at a random cycle of period 2 — on a random
line, direction and kind, seeded — and three more periods after it. Per run it prints where the
fault was counted (``link_error_detail``: the master's dropped frames, the master port codec,
each node's two codecs, dropped frames and router discards), the periods that lost replies
(overruns, missing replies) and whether every period after the faulty one completed. A fault
counted nowhere is flagged: either it changed nothing on the wire (a wire forced to the level
it already had, a bit flipped in the idle gap of a lower rate...) or it was absorbed silently,
which the link must never do; the run's VCD window (``--vcd``) tells which.

Run on purpose (minutes; not in CI)::

    python benchmarks/fault_campaign.py --runs 16 --seed 1
    python benchmarks/fault_campaign.py --runs 4 --kinds cut --json results/faults.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from mrm_cosim.cosim.closed_loop import FAULT_KINDS, LineFault
from mrm_cosim.cosim.track import link_fault_places, run_track

PERIOD = 50_000
LENGTHS = {"bit": (1, 1), "cut": (10, 120), "stuck-d": (10, 120)}   # cycles, min and max


def draw(rng, kinds, n_nodes: int = 3) -> LineFault:
    kind = str(rng.choice(kinds))
    lo, hi = LENGTHS[kind]
    return LineFault(node=int(rng.integers(1, n_nodes + 1)),
                     direction=str(rng.choice(["down", "up"])), kind=kind,
                     cycle=2 * PERIOD + int(rng.integers(0, PERIOD)),
                     cycles=int(rng.integers(lo, hi + 1)))


def one(fault: LineFault) -> dict:
    t0 = time.perf_counter()
    result, s = run_track(controller="vdc", backend="compiled", duration=0.006, faults=[fault])
    records = result.master.records
    late = [r.index for r in records if not r.complete]
    return {"fault": f"{fault.kind}:{fault.direction}:{fault.node}@+{fault.cycle - 2 * PERIOD}"
                     f"+{fault.cycles}", "counted": s["link_errors"],
            "where": link_fault_places(s["link_error_detail"]),
            "incomplete_periods": late, "overruns": s["overruns"],
            "missing": s["missing_replies"],
            "recovered": all(r.complete for r in records if r.index > 2),
            "wall_s": time.perf_counter() - t0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=12)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--kinds", nargs="+", default=sorted(FAULT_KINDS), choices=sorted(FAULT_KINDS))
    ap.add_argument("--json", default=None, help="also save the rows here")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    rows = []
    for _ in range(args.runs):
        row = one(draw(rng, args.kinds))
        rows.append(row)
        flag = "" if row["counted"] else "   <-- counted nowhere"
        print(f"{row['fault']:28s} counted {row['counted']:2d} ({row['where']}); "
              f"incomplete {row['incomplete_periods']}, missing {row['missing']}, "
              f"recovered {row['recovered']}{flag}", flush=True)
    counted = sum(1 for r in rows if r["counted"])
    print(f"{counted}/{len(rows)} faults counted; {sum(r['recovered'] for r in rows)}/{len(rows)} "
          f"runs recovered; {sum(r['overruns'] for r in rows)} overrun periods", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
