"""Speed of Verilator build variants of the 3-node system, side by side, on a recorded loop.

Run on purpose (each build takes 2-3 minutes on this machine), not in CI::

    MRM_CACHE_DIR=/tmp/s-cache python benchmarks/compiled_variants.py record
    MRM_CACHE_DIR=/tmp/s-cache python benchmarks/compiled_variants.py compare tied tied-o3-xfast
    git show fadb99e:cosim/compiled.py > /tmp/compiled_v1.py
    python benchmarks/compiled_variants.py bench --legacy /tmp/compiled_v1.py
    MRM_CACHE_DIR=/tmp/s-cache python benchmarks/compiled_variants.py pgo

``record`` runs the 3-module VDC closed loop (start-up, uploads, then ``--cycles`` of the
A/B/C/D cycle) on the ``compiled`` backend and stores every chunk's per-cycle inputs. ``compare``
builds each named variant (cached), replays the recorded inputs chunk by chunk through
:meth:`cosim.compiled.CompiledModel.run` (the calls the closed loop makes, without plant and
master), checks that every variant returns the same outputs bit for bit as the first, and prints
the replay's cycles per second, best of ``--rounds`` rounds taken in turn (the machine is shared
and noisy: only ratios within one run mean anything). ``bench`` runs ``mrm bench``'s compiled
window alternately with an older engine (``--legacy``) and the current one. ``pgo`` measures GCC
profile-guided optimisation of the default build: an instrumented build replays the tape once
(in a child process: the profile is written at its exit), the model is rebuilt with that
profile, and the two builds are replayed in turn as ``compare`` does.
"""

from __future__ import annotations

import argparse
import hashlib
import pickle
import sys
import time
from pathlib import Path

import numpy as np

_XFAST = ["--x-assign", "fast", "--x-initial", "fast", "--noassert"]

#: name -> CompiledModel keyword arguments (everything spelled out: defaults may change)
VARIANTS = {
    # the engine before this work, from a copy of its source given with --legacy
    "legacy": {"legacy": True},
    # reset as an input port, as before (the harness steps it with two eval() per cycle)
    "rst-port": {"reset_port": True, "opt": "-O2", "verilator_args": []},
    # reset tied low in a harness module: Verilator folds the reset logic away
    "tied": {"opt": "-O2", "verilator_args": []},
    "tied-o3": {"opt": "-O3", "verilator_args": []},
    "tied-xfast": {"opt": "-O2", "verilator_args": _XFAST},
    "tied-o3-xfast": {"opt": "-O3", "verilator_args": _XFAST},
    "tied-o3-xfast-native": {"opt": "-O3", "verilator_args": _XFAST,
                             "cflags": "-march=native"},
    "tied-o3-xfast-threads2": {"opt": "-O3", "verilator_args": [*_XFAST, "--threads", "2"]},
    "tied-o3-xfast-inline": {"opt": "-O3", "verilator_args": [*_XFAST, "--inline-mult", "-1"]},
    # the shared library without semantic interposition (calls inside it need not go through
    # the PLT, and may be inlined across Verilator's functions), and bound symbolically
    "tied-o3-xfast-nosi": {"opt": "-O3", "verilator_args": _XFAST,
                           "cflags": "-fno-semantic-interposition"},
    "tied-o3-xfast-nosi-symbolic": {"opt": "-O3",
                                    "verilator_args": [*_XFAST, "-LDFLAGS", "-Wl,-Bsymbolic"],
                                    "cflags": "-fno-semantic-interposition"},
    # smaller code (the 3-node model's code is most of the 1 MiB L2), and Verilator's own
    # optimisations off one at a time: lookup tables for small blocks, the data-flow graph
    "tied-os-xfast": {"opt": "-Os", "verilator_args": _XFAST},
    "tied-o2-xfast": {"opt": "-O2", "verilator_args": _XFAST},
    "tied-o3-xfast-notable": {"opt": "-O3", "verilator_args": [*_XFAST, "-fno-table"]},
    "tied-o3-xfast-nodfg": {"opt": "-O3", "verilator_args": [*_XFAST, "-fno-dfg"]},
    # Verilator's functions split at N statements (the default build's cycle is a few very
    # large straight-line functions), or never
    "tied-o3-xfast-cfuncs200": {"opt": "-O3",
                                "verilator_args": [*_XFAST, "--output-split-cfuncs", "200"]},
    "tied-o3-xfast-cfuncs2000": {"opt": "-O3",
                                 "verilator_args": [*_XFAST, "--output-split-cfuncs", "2000"]},
    "tied-o3-xfast-nosplit": {"opt": "-O3", "verilator_args": [*_XFAST, "--output-split", "0",
                                                               "--output-split-cfuncs", "0"]},
    # a --trace build (what a VCD window needs), tracing off
    "tied-o3-xfast-trace": {"opt": "-O3", "verilator_args": _XFAST, "trace": True},
    "prof": {"reset_port": True, "opt": "-O2", "verilator_args": ["--prof-cfuncs"],
             "cflags": "-g"},
    "tied-prof": {"opt": "-O2", "verilator_args": ["--prof-cfuncs"], "cflags": "-g"},
    # the default build of a netlist Yosys flattened and optimised first (opt -full, dead
    # logic purged, $pmux as $mux trees); needs a `yosys` on PATH
    "yosys-opt": {"opt": "-O3", "verilator_args": _XFAST, "yosys_opt": True},
}

YOSYS_OPT = "proc; flatten; opt -full; opt_clean -purge; pmuxtree; opt_clean"


def _yosys_opt(verilog_text: str, top: str) -> str:
    """``verilog_text`` through ``yosys`` (:data:`YOSYS_OPT`); the same ports, same behaviour."""
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "in.v", Path(tmp) / "out.v"
        src.write_text(verilog_text)
        subprocess.run(["yosys", "-q", "-p", f"read_verilog {src}; hierarchy -top {top}; "
                        f"{YOSYS_OPT}; write_verilog -noattr {dst}"], check=True)
        return dst.read_text()

STIM = Path("/tmp/mrm-compiled-stimulus.pkl")


def record(cycles: int, path: Path, robot_name: str = "mrm3") -> None:
    from mrm_cosim.cosim.backends import CompiledBackend
    from mrm_cosim.cosim.closed_loop import ClosedLoop
    from mrm_cosim.master.uploads import Gains, node_uploads
    from mrm_cosim.cosim.track import loop_system, loop_system_key
    from mrm_cosim.models.robot import load_robot

    robot = load_robot(robot_name)
    from mrm_cosim.cosim.bench import bench_master_and_plant

    master, plant = bench_master_and_plant(robot)
    class Taping(CompiledBackend):
        """The compiled backend, keeping every chunk's inputs and output names."""

        chunks = []

        async def run(self, n, inputs, outputs):
            self.chunks.append((n, {k: np.array(np.broadcast_to(v, (n,))) for k, v in
                                    inputs.items()}, list(outputs)))
            return await super().run(n, inputs, outputs)

    be = Taping(lambda: loop_system(robot), loop_system_key(robot), quiet=False)
    model = be.model
    text, signed = model.verilog, {p.name: p.signed for p in model.ports.values()}
    loop = ClosedLoop(robot, be, master, plant, 50_000, node_uploads(robot, "vdc", Gains()))
    loop.run(cycles)
    with open(path, "wb") as f:
        # the Verilog goes with the stimulus: the gateware may change before the replay
        pickle.dump({"verilog": text, "signed": signed, "chunks": be.chunks,
                     "robot": robot_name}, f)
    print(f"recorded {sum(c[0] for c in be.chunks)} cycles in {len(be.chunks)} chunks "
          f"to {path}; {len(master.records)} periods")


LEGACY = None


def _model(tape, kwargs):
    from mrm_cosim.cosim.compiled import CompiledModel

    if kwargs.get("legacy"):
        import importlib.util

        if LEGACY is None:
            raise SystemExit("the 'legacy' variant needs --legacy PATH (an older compiled.py)")
        spec = importlib.util.spec_from_file_location("compiled_legacy", LEGACY)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod
        spec.loader.exec_module(mod)
        return mod.CompiledModel(None, "system", verilog_text=tape["verilog"],
                                 signed_ports=tape["signed"], quiet=False)
    kwargs = dict(kwargs)
    text = tape["verilog"]
    if kwargs.pop("yosys_opt", False):
        text = tape.setdefault("_yosys_opt", _yosys_opt(text, "system"))
    return CompiledModel(None, "system", verilog_text=text, signed_ports=tape["signed"],
                         quiet=False, **kwargs)


def _replay(model, chunks):
    """Replay the tape; returns the CPU time it took (the replay is one thread, and on the
    shared machine the wall time is up to 4x the CPU time) and a digest of the outputs."""
    digest = hashlib.sha256()
    t0 = time.process_time()
    for n, inputs, outputs in chunks:
        out = model.run(n, inputs, outputs)
        for v in out.values():
            digest.update(v.tobytes())
    return time.process_time() - t0, digest.hexdigest()


def compare(names, path: Path, rounds: int) -> int:
    with open(path, "rb") as f:
        tape = pickle.load(f)
    chunks = tape["chunks"]
    cycles = sum(c[0] for c in chunks)
    # build one at a time (each build uses both cores), then measure in turns
    models = {}
    for name in names:
        t0 = time.perf_counter()
        models[name] = _model(tape, VARIANTS[name])
        print(f"{name}: ready in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    best = {name: float("inf") for name in names}
    digests = {}
    for _ in range(rounds):
        for name in names:
            fresh = _model(tape, VARIANTS[name])      # cached build, state from reset
            wall, digest = _replay(fresh, chunks)
            fresh.close()
            best[name] = min(best[name], wall)
            digests.setdefault(name, digest)
            if digests[name] != digest:
                print(f"{name}: replay not deterministic", file=sys.stderr)
                return 1
    ref = digests[names[0]]
    print(f"{cycles} cycles replayed, best of {rounds} rounds")
    for name in names:
        same = "identical" if digests[name] == ref else "DIFFERENT OUTPUTS"
        print(f"{name:18s} {cycles / best[name]:12,.0f} cycles/s  "
              f"x{best[names[0]] / best[name]:5.2f}  {same}")
    return 0 if all(d == ref for d in digests.values()) else 1


def bench(legacy: Path, rounds: int) -> int:
    """``mrm bench``'s compiled window, alternating the legacy engine and the current one."""
    import importlib.util

    import mrm_cosim.cosim.compiled as cc
    from mrm_cosim.cosim.bench import bench_backend

    spec = importlib.util.spec_from_file_location("compiled_legacy", legacy)
    old = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = old
    spec.loader.exec_module(old)

    class Legacy(old.CompiledModel):
        def __init__(self, *args, trace=False, **kwargs):     # no trace option back then
            super().__init__(*args, **kwargs)

    current = cc.CompiledModel
    results = {"before": [], "after": []}
    try:
        for _ in range(rounds):
            for name, cls in (("before", Legacy), ("after", current)):
                cc.CompiledModel = cls
                r = bench_backend("compiled", "mrm3")
                results[name].append(r["cycles_per_s"])
                print(f"{name:6s} {r['cycles_per_s']:10,.0f} cycles/s  RTF {r['rtf']:6.0f}",
                      flush=True)
    finally:
        cc.CompiledModel = current
    med = {k: float(np.median(v)) for k, v in results.items()}
    print(f"median {med['before']:,.0f} -> {med['after']:,.0f} cycles/s "
          f"(x{med['after'] / med['before']:.2f})")
    return 0


PGO_WORK = Path("/tmp/mrm-pgo-build")   # a fixed build directory: the profile files are
PGO_DATA = Path("/tmp/mrm-pgo-data")    # named after the object files' absolute paths


def _pgo_model(tape, stage: str):
    """The default build (``stage`` "base"), instrumented ("gen") or optimised with the
    recorded profile ("use"); the instrumented and the optimised builds run in
    :data:`PGO_WORK`, so their object files, and the profile's names, are the same."""
    import shutil

    import mrm_cosim.cosim.compiled as cc

    def fixed_mkdtemp(prefix="", dir=None):
        shutil.rmtree(PGO_WORK, ignore_errors=True)
        PGO_WORK.mkdir(parents=True)
        return str(PGO_WORK)

    kwargs = dict(VARIANTS["tied-o3-xfast"])
    if stage == "gen":
        kwargs["verilator_args"] = [*_XFAST, "-LDFLAGS", "-fprofile-generate"]
        kwargs["cflags"] = f"-fprofile-generate={PGO_DATA} -fprofile-update=single"
    elif stage == "use":
        # the profile's digest goes into the flags, hence into the build cache's key
        digest = hashlib.sha256(b"".join(f.read_bytes() for f in sorted(PGO_DATA.iterdir())))
        kwargs["cflags"] = (f"-fprofile-use={PGO_DATA} -fprofile-partial-training "
                            f"-Wno-missing-profile -DMRM_PGO={digest.hexdigest()[:16]}")
    saved = cc.tempfile.mkdtemp
    cc.tempfile.mkdtemp = fixed_mkdtemp if stage != "base" else saved
    try:
        return _model(tape, kwargs)
    finally:
        cc.tempfile.mkdtemp = saved


def pgo(path: Path, rounds: int) -> int:
    import shutil
    import subprocess

    with open(path, "rb") as f:
        tape = pickle.load(f)
    chunks = tape["chunks"]
    cycles = sum(c[0] for c in chunks)
    shutil.rmtree(PGO_DATA, ignore_errors=True)
    subprocess.run([sys.executable, __file__, "_pgo-train", "--stim", str(path)], check=True)
    best, digests = {"base": float("inf"), "use": float("inf")}, {}
    for stage in best:
        _pgo_model(tape, stage).close()           # build once, before measuring
    for _ in range(rounds):
        for stage in best:
            model = _pgo_model(tape, stage)
            wall, digest = _replay(model, chunks)
            model.close()
            best[stage] = min(best[stage], wall)
            digests.setdefault(stage, set()).add(digest)
    print(f"{cycles} cycles replayed, best of {rounds} rounds")
    for stage in best:
        print(f"{stage:5s} {cycles / best[stage]:12,.0f} cycles/s  "
              f"x{best['base'] / best[stage]:5.2f}  outputs {sorted(digests[stage])[0][:16]}")
    same = len(digests["base"] | digests["use"]) == 1
    print("outputs identical" if same else "DIFFERENT OUTPUTS")
    return 0 if same else 1


def _pgo_train(path: Path) -> int:
    with open(path, "rb") as f:
        tape = pickle.load(f)
    model = _pgo_model(tape, "gen")
    wall, _ = _replay(model, tape["chunks"])
    model.close()
    print(f"training replay (instrumented build): {wall:.1f} s", file=sys.stderr)
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("--cycles", type=int, default=250_000)
    r.add_argument("--stim", type=Path, default=STIM)
    r.add_argument("--robot", default="mrm3", help="the robot (compiled_split.py replays "
                   "any; compare and pgo take mrm3's tape)")
    c = sub.add_parser("compare")
    c.add_argument("variants", nargs="+", choices=sorted(VARIANTS))
    c.add_argument("--stim", type=Path, default=STIM)
    c.add_argument("--rounds", type=int, default=3)
    c.add_argument("--legacy", type=Path, help="an older cosim/compiled.py, for 'legacy'")
    b = sub.add_parser("bench")
    b.add_argument("--legacy", type=Path, required=True,
                   help="an older cosim/compiled.py (git show fadb99e:cosim/compiled.py)")
    b.add_argument("--rounds", type=int, default=3)
    g = sub.add_parser("pgo")
    g.add_argument("--stim", type=Path, default=STIM)
    g.add_argument("--rounds", type=int, default=3)
    t = sub.add_parser("_pgo-train")
    t.add_argument("--stim", type=Path, default=STIM)
    args = p.parse_args(argv)
    if args.cmd == "pgo":
        return pgo(args.stim, args.rounds)
    if args.cmd == "_pgo-train":
        return _pgo_train(args.stim)
    if args.cmd == "bench":
        return bench(args.legacy, args.rounds)
    global LEGACY
    LEGACY = getattr(args, "legacy", None)
    if args.cmd == "record":
        record(args.cycles, args.stim, args.robot)
        return 0
    return compare(args.variants, args.stim, args.rounds)


if __name__ == "__main__":
    sys.exit(main())
