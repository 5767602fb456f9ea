"""Two codecs on independent clocks: does the link hold, ≥ 10⁶ characters each way?

Run on purpose (not a test): ``python benchmarks/link_clocks.py [--chars N] [--quick]``.
Each codec is the bit-exact reference (:class:`~hdl.link.codec_ref.CodecRef`) on its own clock
(:mod:`mrm_cosim.testbench.clocks`): side ``b``'s clock is ``ppm`` faster than ``a``'s (negative:
slower), each line resampled onto the other side's sample grid; both hosts stream 40-byte
packets as fast as the link takes them. Per case it prints the characters delivered intact
each way, wrong characters, errors counted, how often each end entered Run, the cycles run and
the CPU time. The default receiver (6 samples per cycle, 2 per bit at 150 Mbit/s) runs at
±1 % and ±100 ppm; the receiver of before (3 samples per cycle, 1 per bit) at ±100 ppm for
comparison (it fails: every 10⁴ bits of a faster peer two transitions share a sample), 2·10⁴
characters; the margin rows (+33 % holds, +34 % loses characters) 10⁵.
``tests/test_link_clocks.py`` runs the same cases with 3,000 characters.
"""

import argparse
import time

from mrm_cosim.testbench.clocks import run_two_clocks

OLD = {"slots": 3, "run_div": 1}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--chars", type=int, default=1_000_000,
                        help="characters each way per case (default 10⁶)")
    parser.add_argument("--quick", action="store_true",
                        help="only the default receiver at +1 %% and +100 ppm")
    parser.add_argument("--case", type=int, action="append",
                        help="run only these rows (0-based, repeatable)")
    args = parser.parse_args()
    cases = [("default receiver", {}, ppm) for ppm in (10_000, -10_000, 100, -100)]
    cases += [("1-sample receiver (before)", OLD, ppm) for ppm in (100, -100)]
    cases += [("default receiver, margin", {}, ppm) for ppm in (330_000, 340_000)]
    if args.quick:
        cases = cases[0:1] + cases[2:3]
    elif args.case:
        cases = [cases[i] for i in args.case]
    print(f"{'receiver':28} {'peer':>9} {'delivered a/b':>19} {'wrong':>9} {'Run entries':>11}"
          f" {'errors':>30} {'cycles a':>10} {'CPU s':>7}")
    for label, params, ppm in cases:
        # The receiver of before fails within 10⁴ bits; the margin rows need fewer characters.
        chars = min(args.chars, 20_000 if "before" in label else
                    100_000 if "margin" in label else args.chars)
        t0 = time.process_time()
        r = run_two_clocks(ppm, chars=chars, params=params,
                           max_cycles=None if "before" not in label else 100_000)
        cpu = time.process_time() - t0
        errs = {w: {k: v for k, v in e.items() if v} for w, e in r.errors.items()}
        peer = f"{ppm / 1e4:+.2f} %" if abs(ppm) >= 1000 else f"{ppm:+d} ppm"
        print(f"{label:28} {peer:>9} {r.received['a']:>9,}/{r.received['b']:<9,}"
              f" {r.wrong['a']:>4}/{r.wrong['b']:<4} {r.runs['a']:>5}/{r.runs['b']:<5}"
              f" {str(errs):>30} {r.cycles['a']:>10,} {cpu:7.1f}"
              f"  {'error-free' if r.error_free else 'FAILED'}", flush=True)


if __name__ == "__main__":
    main()
