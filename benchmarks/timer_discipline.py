"""Node period timers on clocks of their own: skew against the master with and without the
time-code discipline (issue 21 item 3).

Run on purpose (not a test): ``python benchmarks/timer_discipline.py [--periods N] [--seeds K]``.
Four nodes, one per chain position (hops 1–4), clocks +100, −100, +50, −50 ppm with random
phases, each the bit-exact timer reference (:class:`~hdl.node.timer_ref.TimerModel`) in exact
integer time against a master that sends a time-code at each period start; the arrival waits
10 cycles per hop plus 0–4 per hop for the character on the line
(:mod:`mrm_cosim.testbench.discipline`). Per node and setting it prints the skew of the node's
period start against the master's (master cycles, 20 ns each; positive: the node late) — max
and RMS over the whole run and from period 60 —, the derived bound, the lock period (first
period from which |skew| stays within it), the resyncs and the largest error of the loop's
rate estimate from period 60 (cycles per period). Settings: off
(TC_DISCIPLINE 0, today's timer), on from a common reset, on with each node out of reset at a
random cycle of the master's first period (acquisition by the first time-code). Seeds vary the
phases, start cycles and jitter; the worst over seeds is printed.
``tests/test_timer_discipline.py`` checks the same cases. ``--plot PNG`` also draws seed 0's
skew over the run, off and on (:func:`~cosim.plots.plot_skew`; docs/img/timer_skew.png).
"""

import argparse
import time

import numpy as np

from mrm_cosim.testbench.discipline import (GAINS, drift_per_period, random_clocks,
                                            run_discipline, skew_bound)

LOCKED = 60     # periods: from here the bound's premise holds (tests/test_timer_discipline.py)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--periods", type=int, default=1000, help="master periods (1 ms each)")
    parser.add_argument("--seeds", type=int, default=10, help="seeds; the worst is printed")
    parser.add_argument("--plot", metavar="PNG", help="draw seed 0's skew over the run here")
    args = parser.parse_args()
    t0 = time.process_time()
    settings = [("off", None, False), ("on", GAINS, False), ("on, late reset", GAINS, True)]
    print(f"{args.periods} periods of 50,000 cycles, {args.seeds} seeds (worst shown); "
          f"gains kp={GAINS.kp} ki={GAINS.ki}; skew in cycles of 20 ns")
    print(f"{'setting':16} {'ppm':>5} {'hop':>3} {'max|skew|':>10} {'RMS':>8} "
          f"{'max from 60':>11} {'RMS from 60':>11} {'bound':>6} {'lock':>5} {'resyncs':>8} "
          f"{'rate error':>10}")
    for name, disc, late in settings:
        rows = {}
        for seed in range(args.seeds):
            clocks = random_clocks(seed, late=late)
            for r in run_discipline(clocks, args.periods, discipline=disc, seed=seed):
                bound = skew_bound(r.clock.hop)
                lock = r.lock_period(bound) if disc else 0
                mx, rms = r.stats()
                lmx, lrms = r.stats(LOCKED)
                wander = (np.max(np.abs(r.rates[LOCKED:] + drift_per_period(r.clock.ppm)))
                          if disc else 0.0)
                row = rows.setdefault(r.clock.hop, [r.clock.ppm, 0, 0, 0, 0, bound, 0, 0, 0])
                for i, v in ((1, mx), (2, rms), (3, lmx), (4, lrms), (6, lock or 10**9),
                             (7, r.resyncs), (8, wander)):
                    row[i] = max(row[i], v)
        for hop, (ppm, mx, rms, lmx, lrms, bound, lock, rs, wander) in sorted(rows.items()):
            lk = "-" if lock in (0, 10**9) else str(lock)
            wd = f"{wander:.3f}" if wander else "-"
            print(f"{name:16} {ppm:+5d} {hop:3d} {mx:10.2f} {rms:8.2f} {lmx:11.2f} {lrms:11.2f} "
                  f"{bound:6.1f} {lk:>5} {rs:8d} {wd:>10}")
    print(f"CPU {time.process_time() - t0:.1f} s")
    if args.plot:
        from mrm_cosim.cosim.plots import plot_skew

        runs = {}
        for name, disc in (("discipline off", None), ("discipline on (from a common reset)",
                                                       GAINS)):
            nodes = run_discipline(random_clocks(0), args.periods, discipline=disc, seed=0)
            runs[name] = np.stack([r.skew for r in nodes], axis=1)
        ppms = ", ".join(f"{r.clock.ppm:+d}" for r in nodes)
        plot_skew(args.plot, runs, f"Node period starts against the master's: clocks {ppms} "
                  "ppm at hops 1–4, bit-exact timer reference, seed 0")
        print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
