"""``mrm hdl``: export gateware tops as Verilog.

``mrm hdl verilog --top spw_codec --out DIR [--param slots=1 ...]`` writes ``DIR/<top>.v`` and
beside it what a hardware engineer needs with it (:mod:`hdl.export`): ``<top>.vlt`` (the
Verilator lint waivers, each with its reason), ``<top>.sdc`` / ``.lpf`` / ``.ucf`` (the 50 MHz
clock) and ``<top>.ports.md`` (every port, its direction, width and meaning). Each file is
written atomically (a temporary file renamed into place) and a failed run removes what it
wrote, so it leaves no partial set.
``mrm hdl tops`` lists the tops and their parameters. ``mrm hdl synth --top node --family xc2v
--json`` reports LUTs, flip-flops, multipliers and block RAMs (:mod:`hdl.synth`).
"""

from __future__ import annotations

from pathlib import Path

from mrm_cosim.errors import InputError
from mrm_cosim.mrm.flags import HDL, named_by_flags
from mrm_cosim.results import (
    atomic_write_text, check_output_file, check_writable_folder, make_folder, remove_empty,
)


def register(subparsers) -> None:
    p = subparsers.add_parser("hdl", help="export gateware tops as Verilog",
                              epilog="example:\n  mrm hdl verilog --top spw_codec --out build")
    sub = p.add_subparsers(dest="hdl_command", required=True)
    p_verilog = sub.add_parser("verilog", help="write DIR/<top>.v for a gateware top, with its "
                               "lint waivers (.vlt), clock constraints (.sdc, .lpf, .ucf) and "
                               "port list (.ports.md)",
                               epilog="example:\n  mrm hdl verilog --top node --out build "
                               "--param counts_per_rev=2000")
    p_verilog.add_argument("--top", required=True, help="top name (see `mrm hdl tops`)")
    p_verilog.add_argument("--out", required=True, type=Path, help="output folder")
    p_verilog.add_argument("--param", action="append", default=[], metavar="NAME=INT",
                           help="top parameter, e.g. slots=1 (repeatable)")
    p_verilog.set_defaults(func=_verilog)
    p_tops = sub.add_parser("tops", help="list the tops and their parameters",
                            epilog="example:\n  mrm hdl tops")
    p_tops.set_defaults(func=_tops)
    p_synth = sub.add_parser("synth", help="resource report of a top (Debian yosys)",
                             epilog="example:\n  mrm hdl synth --top node --family ecp5 --json")
    p_synth.add_argument("--top", required=True, help="top name (see `mrm hdl tops`)")
    p_synth.add_argument("--family", default="xc2v", help="xc2v (Virtex-II) or ecp5")
    p_synth.add_argument("--param", action="append", default=[], metavar="NAME=INT",
                         help="top parameter, e.g. slots=1 (repeatable)")
    p_synth.add_argument("--json", action="store_true", help="print the report as JSON")
    p_synth.set_defaults(func=_synth)


def parse_params(items: list[str]) -> dict[str, int]:
    """``["slots=1", "run_div=2"]`` -> ``{"slots": 1, "run_div": 2}``; InputError if malformed
    or if a name is given twice (``--param slots=1 --param slots=2`` used to keep the last)."""
    params = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise InputError("--param", f"must look like NAME=INT, not {item!r}")
        if name in params:
            raise InputError(f"--param {name}", "given more than once")
        try:
            params[name] = int(value, 0)
        except ValueError:
            raise InputError(f"--param {name}", f"must be an integer, not {value!r}") from None
    return params


#: The files ``mrm hdl verilog`` writes for a top, beside ``<top>.v``: suffix -> what it is.
COMPANIONS = {".vlt": "Verilator lint waivers", ".sdc": "clock constraint (SDC)",
              ".lpf": "clock constraint (Lattice LPF)", ".ucf": "clock constraint (Xilinx UCF)",
              ".ports.md": "port list"}


def write_verilog(top: str, out: Path, params: dict[str, int]) -> Path:
    """Generate ``top`` with ``params`` and write ``out/<top>.v`` and its
    :data:`COMPANIONS` atomically; return the ``.v`` file's path."""
    from mrm_cosim.hdl.export import clock_constraints, port_list, verilator_config
    from mrm_cosim.hdl.tops import TOPS, build_top, component_verilog, param_error

    if top not in TOPS:
        raise InputError("--top", f"unknown top {top!r}; known: {', '.join(sorted(TOPS))}")
    known = TOPS[top].parameters()
    for name in params:
        if name not in known:
            raise InputError(f"--param {name}",
                             f"top {top!r} has no such parameter; known: {', '.join(known)}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError("--out", f"{str(out)!r} exists and is not a folder")
    check_writable_folder(out, "--out")     # before the build: /proc/x, under a file
    path = out / f"{top}.v"
    files = [path, *(out / f"{top}{suffix}" for suffix in COMPANIONS)]
    if out.is_dir():
        for f in files:                     # DIR/<top>.v a link, a FIFO, a folder: refused
            check_output_file(f, "--out")
    try:
        component = build_top(top, **params)
    except ValueError as exc:
        raise param_error(exc, top) from None
    clocks = clock_constraints(top)
    texts = [component_verilog(component, top), verilator_config(top), clocks["sdc"],
             clocks["lpf"], clocks["ucf"], port_list(component, top)]
    made = make_folder(out, "--out")
    written = []
    try:
        for f, text in zip(files, texts, strict=True):
            atomic_write_text(f, text)
            written.append(f)
    except BaseException as exc:
        for f in written:
            f.unlink(missing_ok=True)
        remove_empty(made)
        if isinstance(exc, InputError):
            raise InputError("--out", exc.message) from None
        if isinstance(exc, OSError):
            raise InputError("--out", f"cannot write into {str(out)!r} "
                             f"({exc.strerror or exc})") from None
        raise
    return path


@named_by_flags(HDL)
def _verilog(args) -> int:
    path = write_verilog(args.top, args.out, parse_params(args.param))
    print(path)
    for suffix, what in COMPANIONS.items():
        print(f"{path.with_name(path.stem + suffix)}  ({what})")
    vlt = path.with_suffix(".vlt")
    print(f"lint (clean with the shipped waivers): verilator --lint-only -Wall {vlt} {path}")
    return 0


def _tops(args) -> int:
    from mrm_cosim.hdl.tops import TOPS

    for name, top in sorted(TOPS.items()):
        params = ", ".join(f"{k}={v}" for k, v in top.parameters().items())
        print(f"{name}: {top.help}\n    parameters: {params}")
    return 0


@named_by_flags(HDL)
def _synth(args) -> int:
    from mrm_cosim.hdl.synth import cli_report

    return cli_report(args.top, args.family, parse_params(args.param), args.json)
