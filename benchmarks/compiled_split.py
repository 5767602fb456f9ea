"""The compiled backend on threads: the 3-node system as one Verilated model per node
(:class:`cosim.compiled.SplitModel`, what ``--threads N`` runs) against the whole system's
model, side by side on a recorded loop.

Run on purpose (the first run builds a model per node: 1-2 minutes each here), not in CI::

    MRM_CACHE_DIR=/tmp/s-cache python benchmarks/compiled_variants.py record --stim /tmp/tape.pkl \\
        [--robot mrm6]
    MRM_CACHE_DIR=/tmp/s-cache python benchmarks/compiled_split.py --stim /tmp/tape.pkl \\
        [--threads 1 --threads 2] [--rounds 3] [--placed]

The tape (``compiled_variants.py record``: the inputs of ``mrm bench``'s VDC loop of its robot,
``mrm3`` unless said, start-up and five periods, chunk by chunk, with the Verilog they were
recorded on; it must be today's gateware's) is replayed through the whole system's model
(:meth:`cosim.compiled.CompiledModel.run`, as the closed loop calls it) and through the
per-node parts on each ``--threads`` (fresh models each round, in turns); with ``--placed``
also through parts named by their place in the chain (``Segment(local=False)``: a build and a
copy of the code per node, as before nodes alike shared theirs). It prints the cycles
per second of each, best of ``--rounds`` on wall time (a run on two threads uses both cores:
its CPU time is up to twice its wall time), the ratio to the whole model, and stops unless
every run returned the same outputs, cycle by cycle, as the whole system's model.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import pickle
import sys
import time
from pathlib import Path

import numpy as np
from amaranth.back import verilog

def _replay(run, chunks):
    digest = hashlib.sha256()
    t0, c0 = time.perf_counter(), time.process_time()
    outs = []
    for n, inputs, outputs in chunks:
        out = run(n, inputs, outputs)
        for v in out.values():
            digest.update(v.tobytes())
        outs.append(out)
    return time.perf_counter() - t0, time.process_time() - c0, digest.hexdigest(), outs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stim", type=Path, required=True, help="compiled_variants.py record's tape")
    ap.add_argument("--threads", type=int, action="append", help="threads (default 1 and 2)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--placed", action="store_true",
                    help="also parts named by place: a build and a copy of the code per node")
    args = ap.parse_args(argv)
    from mrm_cosim.cosim.backends import compiled_parts
    from mrm_cosim.cosim.compiled import CompiledModel, SplitModel
    from mrm_cosim.cosim.track import (THREADS_ENV, loop_backend, loop_segment, loop_system,
                                       loop_system_key)
    from mrm_cosim.models.robot import load_robot

    with open(args.stim, "rb") as f:
        tape = pickle.load(f)
    chunks = tape["chunks"]
    cycles = sum(c[0] for c in chunks)
    robot = load_robot(tape.get("robot", "mrm3"))
    if verilog.convert(loop_system(robot), name="system", emit_src=False) != tape["verilog"]:
        raise SystemExit(f"{args.stim} was recorded on other gateware: record it again")
    os.environ[THREADS_ENV] = "1"
    whole = loop_backend(robot, "compiled", quiet=False).model
    parts = compiled_parts((robot.n, lambda k: loop_segment(robot, k)), loop_system_key(robot),
                           quiet=False)

    def fresh(m):
        return CompiledModel(None, "system", verilog_text=m.verilog,
                             signed_ports={p.name: p.signed for p in m.ports.values()})

    kinds = {"a model per node": parts}
    if args.placed:
        from mrm_cosim.cosim.track import node_encoders, pid_shifts
        from mrm_cosim.hdl.system import Segment

        def placed(k):
            return Segment(robot.n, k, 1, encoder=node_encoders(robot),
                           pid_shift=pid_shifts(robot), line_faults=True)

        kinds["parts named by place"] = compiled_parts(
            (robot.n, placed), loop_system_key(robot) + "-placed", quiet=False)
    print(f"{robot.name}: {len({m._lib._handle for _, _, m in parts})} builds for {robot.n} "
          f"parts", file=sys.stderr)
    runs = {"whole system, 1 thread": lambda: fresh(whole).run}
    for t in args.threads or [1, 2]:
        for kind, ps in kinds.items():
            runs[f"{kind}, {t} thread{'s' if t > 1 else ''}"] = (
                lambda t=t, ps=ps: SplitModel([(a, b, fresh(m)) for a, b, m in ps], t).run)
    best, ref = {}, None
    for r in range(args.rounds):
        for name, make in runs.items():
            wall, cpu, _, outs = _replay(make(), chunks)
            if ref is None:
                ref = outs
            else:
                for k, (a, b) in enumerate(zip(ref, outs, strict=True)):
                    for x in a:
                        if not np.array_equal(a[x], b[x]):
                            c = int(np.argmax(a[x] != b[x]))
                            raise SystemExit(f"{name}: {x} differs from the whole "
                                             f"system's in chunk {k}, cycle {c}")
            w, c = best.get(name, (1e99, 1e99))
            best[name] = (min(w, wall), min(c, cpu))
        print(f"round {r + 1} done", file=sys.stderr)
    base = best["whole system, 1 thread"][0]
    print(f"{cycles} cycles replayed ({args.stim}), every run's outputs identical to the whole "
          f"system's, cycle by cycle; best of {args.rounds}, load {os.getloadavg()[0]:.1f}")
    print(f"{'run':<36} {'cycles/s (wall)':>16} {'ns/cycle':>9} {'CPU/wall':>9} {'vs whole':>9}")
    for name, (wall, cpu) in best.items():
        print(f"{name:<36} {cycles / wall:>16,.0f} {1e9 * wall / cycles:>9,.0f} "
              f"{cpu / wall:>9.2f} {base / wall:>8.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
