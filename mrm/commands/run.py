"""``mrm run``: closed-loop experiments: ``table2``, ``track`` (gateware in the loop) and
``preview`` (the plant alone).

``table2`` and ``track`` take their experiment from a configuration file (default
``configs/table2.toml``): robot, backend, seed, duration, trajectory, plant, gains, timing;
their flags override the first four. So ``mrm run track --controller vdc`` is the ``vdc`` row
of ``mrm run table2``, bit for bit. Each writes its resolved configuration (``config.toml``)
into its result folder. A run that is not clean ends with exit code 3 and says why.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import logging
import os
import sys
from dataclasses import replace
from pathlib import Path

from mrm_cosim import __version__
from mrm_cosim.errors import InputError
from mrm_cosim.mrm.flags import (RUN_DMP_TABLE2, RUN_LINE, RUN_PREVIEW, RUN_TABLE2, RUN_TRACK,
                                 named_by_flags)

EXIT_NOT_CLEAN = 3

_log = logging.getLogger("mrm_cosim.mrm")


def _int_flag(minimum: int, kind: str, doc: str):
    """An argparse type: an integer ≥ ``minimum`` (``kind``: "non-negative", "positive"),
    refused before anything runs (argparse names the flag and exits with code 2)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a {kind} integer, not {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be a {kind} integer, not {value}")
        return value

    parse.__doc__ = doc
    return parse


_seed = _int_flag(0, "non-negative", "``--seed``: a non-negative integer.")
_threads = _int_flag(1, "positive", "``--threads``: a positive integer.")


#: ``--threads``'s help (every command that can run the compiled backend)
THREADS_HELP = ("compiled backend: simulate the gateware as one model per node on this many "
                "threads (at most one a node; same results bit for bit; default "
                "$MRM_COMPILED_THREADS, else 1: the whole system's model). Faster on wall "
                "time where cores are free; not with a waveform or clocks of their own")


_CONFIG_HELP = "experiment TOML: robot, backend, seed, duration, trajectory, plant, gains, " \
               "timing (default: the package's configs/table2.toml)"


def register(subparsers) -> None:
    p = subparsers.add_parser("run", help="run a closed-loop experiment",
                              epilog="example:\n  mrm run table2 --duration 0.05 --out "
                              "results/t2")
    sub = p.add_subparsers(dest="run_command", required=True)
    pp = sub.add_parser("preview", help="the paper's quintic test on the plant with a float "
                        "feedforward + PID controller at 1 kHz (no link, no gateware yet)",
                        epilog="example:\n  mrm run preview --robot mrm6 --duration 0.5 "
                        "--out results/preview")
    pp.add_argument("--robot", default="mrm3", help="built-in name or assembly .toml")
    pp.add_argument("--duration", type=float, default=1.5, help="simulated seconds")
    pp.add_argument("--seed", type=_seed, default=0, help="plant perturbation seed")
    pp.add_argument("--uncertainty", type=float, default=None,
                    help="relative perturbation of the plant's parameters (default: the plant's)")
    pp.add_argument("--out", default="results/preview", help="result folder (replaced)")
    pp.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    pp.set_defaults(func=_preview)
    pt = sub.add_parser("track", help="the paper's quintic test in closed loop with the gateware "
                        "(master, link, nodes, plant)",
                        epilog="example:\n  mrm run track --controller vdc --backend model "
                        "--duration 0.05 --out results/track\n  mrm run track --backend "
                        "compiled --duration 0.003 --vcd 1ms:1.1ms --signals 'torque*'\n"
                        "  mrm run track --backend pysim --duration 0.001 --fst 0:20us")
    pt.add_argument("--controller", default="vdc", choices=["vdc", "pid-fpga", "pid-1khz"],
                    help="the controller to run")
    pt.add_argument("--config", default=None, metavar="FILE", help=_CONFIG_HELP)
    pt.add_argument("--backend", default=None, choices=["compiled", "pysim", "model"],
                    help="override the config's backend")
    pt.add_argument("--robot", default=None,
                    help="override the config's robot: built-in name or assembly .toml")
    pt.add_argument("--duration", type=float, default=None,
                    help="override the config's simulated seconds")
    pt.add_argument("--seed", type=_seed, default=None, help="override the plant seed")
    pt.add_argument("--out", default="results/track", help="result folder (replaced)")
    pt.add_argument("--vcd", default=None, metavar="T0:T1",
                    help="write OUT/waves.vcd of this window only (times from period 0, e.g. "
                    "0.5ms:0.6ms; pysim and compiled backends)")
    pt.add_argument("--fst", default=None, metavar="T0:T1",
                    help="as --vcd, as FST: OUT/waves.fst (compiled: Verilator writes it; "
                    "needs pip install 'mrm-cosim[fst]'). Either waveform comes with "
                    "OUT/waves.gtkw: gtkwave OUT/waves.fst OUT/waves.gtkw")
    pt.add_argument("--signals", default=None, metavar="PATTERN",
                    help="comma-separated globs of the signals in the VCD or FST, dotted "
                    "below the top (e.g. 'torque*,node1.core.*'; default: all)")
    pt.add_argument("--line-fault", action="append", default=[],
                    metavar="KIND:DIR:NODE@T[+LEN]",
                    help="inject a fault on the line above NODE, DIR down (towards it) or up, "
                    "at T from period 0 for LEN (default one cycle); KIND cut, bit or stuck-d; "
                    "e.g. bit:up:2@2.006ms, cut:down:3@10ms+2us (repeatable; pysim and "
                    "compiled). summary.json says where each fault was counted")
    pt.add_argument("--threads", type=_threads, default=None, metavar="N", help=THREADS_HELP)
    pt.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    pt.set_defaults(func=_track)
    pl = sub.add_parser("line", help="a planned Cartesian line (trigonometric or Ruckig) "
                        "through IK into the closed loop on a six-joint arm; tool errors, "
                        "joint trajectories, torques, the tool's path in 3-D",
                        epilog="example:\n  mrm run line examples/line.toml --robot mrm6 "
                        "--controller vdc --out results/line\n  mrm run line "
                        "examples/line.toml --profile both --duration 0.5")
    pl.add_argument("file", metavar="FILE", help="the line: start and end poses and limits "
                    "(as for mrm plan line)")
    pl.add_argument("--robot", default=None,
                    help="six-joint robot: built-in name or assembly .toml (default: the "
                    "config's robot, mrm6 in the package's configs/line.toml)")
    pl.add_argument("--controller", default="vdc", choices=["vdc", "pid-fpga", "pid-1khz"],
                    help="the controller to run")
    pl.add_argument("--profile", default="trig", choices=["trig", "ruckig", "both"],
                    help="the trigonometric jerk-continuous profile, Ruckig's time-optimal "
                    "one, or both side by side (line.md)")
    pl.add_argument("--config", default=None, metavar="FILE",
                    help="experiment TOML for the robot, gains, timing, plant, seed and backend "
                    "(default: the package's configs/line.toml; its trajectory and duration "
                    "are not used)")
    pl.add_argument("--backend", default=None, choices=["compiled", "pysim", "model"],
                    help="override the config's backend")
    pl.add_argument("--duration", type=float, default=None,
                    help="simulated seconds (default: the move plus a 0.2 s hold)")
    pl.add_argument("--seed", type=_seed, default=None, help="override the plant seed")
    pl.add_argument("--out", default="results/line", help="result folder (replaced)")
    pl.add_argument("--threads", type=_threads, default=None, metavar="N", help=THREADS_HELP)
    pl.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    pl.set_defaults(func=_line)
    p2 = sub.add_parser("table2", help="the paper's Table 2: pid-1khz, pid-fpga and vdc on the "
                        "quintic test, same plant and seed; table, plots, timelines",
                        epilog="example:\n  mrm run table2 --backend model --duration 0.05 "
                        "--out results/t2\n  mrm run table2 --config my.toml --seed 3 --jobs 1")
    p2.add_argument("--config", default=None, metavar="FILE", help=_CONFIG_HELP)
    p2.add_argument("--backend", default=None,
                    help="override the config's backend: compiled, pysim or model")
    p2.add_argument("--out", default="results/table2", help="result folder (replaced)")
    p2.add_argument("--seed", type=_seed, default=None, help="override the plant seed")
    p2.add_argument("--duration", type=float, default=None,
                    help="override the simulated seconds per controller")
    p2.add_argument("--jobs", type=int, default=None,
                    help="controllers run side by side (default: one per controller on a "
                    "machine with two cores or more — three runs on two cores end sooner "
                    "together than two and then one — else 1); the results do not depend "
                    "on it")
    p2.add_argument("--threads", type=_threads, default=None, metavar="N", help=THREADS_HELP)
    p2.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    p2.set_defaults(func=_table2)
    pd = sub.add_parser("dmp-table2", help="the motion-primitive paper's Table 2: four tool "
                        "paths on a six-joint arm, traditional (the joint holds the master's "
                        "position) vs modularized (a DMP generator in every node) at the same "
                        "slow master period, and the 1 ms master; RMSE by the paper's eq. (10) "
                        "and by log(T_d^-1 T_g); plots of the paths and errors",
                        epilog="example:\n  mrm run dmp-table2 --out results/dmp\n  mrm run "
                        "dmp-table2 --path line --backend compiled")
    pd.add_argument("--config", default=None, metavar="FILE",
                    help="comparison TOML: robot, periods, DMP, plane, paths, plant, gains "
                    "(default: the package's configs/dmp_table2.toml)")
    pd.add_argument("--robot", default=None,
                    help="six-joint robot: built-in name or assembly .toml (default: the "
                    "config's, mrm6)")
    pd.add_argument("--backend", default=None, choices=["compiled", "pysim", "model"],
                    help="override the config's backend")
    pd.add_argument("--seed", type=_seed, default=None, help="override the plant seed")
    pd.add_argument("--path", action="append", default=None, metavar="NAME",
                    help="run only this path of the config (repeatable)")
    pd.add_argument("--jobs", type=int, default=None,
                    help="runs side by side (default: as many as there are CPU cores); the "
                    "results do not depend on it")
    pd.add_argument("--out", default="results/dmp-table2", help="result folder (replaced)")
    pd.add_argument("--threads", type=_threads, default=None, metavar="N", help=THREADS_HELP)
    pd.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    pd.set_defaults(func=_dmp_table2)


def _print_json(summary: dict) -> None:
    print(json.dumps(summary, indent=2))


def _not_clean(command: str, reasons: list[str]) -> int:
    """Say why a run is not clean (stderr, even with -q) and give its exit code."""
    for reason in reasons:
        sys.stderr.write(f"mrm run {command}: NOT A CLEAN RUN: {reason}\n")
    return EXIT_NOT_CLEAN if reasons else 0


# --- preview -------------------------------------------------------------------------------
@named_by_flags(RUN_PREVIEW)
def _preview(args) -> int:
    from mrm_cosim.cosim.plots import plot_tracking
    from mrm_cosim.cosim.preview import run_preview
    from mrm_cosim.models.plant import PlantConfig
    from mrm_cosim.models.robot import load_robot
    from mrm_cosim.results import atomic_output_dir, check_output_dir, write_json

    check_output_dir(args.out)
    robot = load_robot(args.robot)
    config = PlantConfig() if args.uncertainty is None else _plant_config(args.uncertainty)
    with atomic_output_dir(args.out, made_by="mrm run preview") as tmp:
        result = run_preview(robot, duration=args.duration, seed=args.seed, plant_config=config)
        summary = dict(result.summary, version=__version__)
        write_json(tmp / "summary.json", summary)
        write_json(tmp / "config.json", {
            "command": "mrm run preview", "robot": robot.describe(), "seed": args.seed,
            "duration_s": args.duration, "plant": _config_dict(config), "version": __version__})
        with open(tmp / "trace.csv", "w", newline="") as f:
            w = csv.writer(f)
            n = robot.n
            w.writerow(["t_s"] + [f"q_d{k + 1}_rad" for k in range(n)]
                       + [f"q{k + 1}_rad" for k in range(n)]
                       + [f"tau{k + 1}_Nm" for k in range(n)]
                       + [f"counts{k + 1}" for k in range(n)])
            for i in range(len(result.t)):
                w.writerow([repr(float(result.t[i]))] + [repr(float(x)) for x in result.q_d[i]]
                           + [repr(float(x)) for x in result.q[i]]
                           + [repr(float(x)) for x in result.tau[i]]
                           + [int(c) for c in result.counts[i]])
        plot_tracking(tmp / "tracking.png", result.t, result.q_d, result.q, result.tau,
                      f"{robot.name}: quintic test, float feedforward + PID at 1 kHz (preview)")
    if args.json:
        _print_json(summary)
    elif not args.quiet:
        s = result.summary
        print(f"preview on {robot.name} (plant only, no gateware): "
              f"max tip speed {s['max_tip_speed_m_s']:.4f} m/s, "
              f"max tip error {1e3 * s['max_tip_error_m']:.4f} mm, rho {s['rho_s']:.6f} s, "
              f"max joint error {s['max_joint_error_rad']:.3e} rad")
        print(f"results in {Path(args.out)}/ (summary.json, config.json, trace.csv, "
              "tracking.png)")
    return 0


# --- track ---------------------------------------------------------------------------------
def track_config(config_path=None, *, controller: str = "vdc", robot=None,
                 backend: str | None = None, seed: int | None = None,
                 duration: float | None = None):
    """The resolved experiment of one ``mrm run track``: the configuration file's (default
    ``configs/table2.toml``) with the given overrides, running ``controller`` alone.
    Errors name the argument (``backend``, ``robot``, …) or the file's field."""
    from mrm_cosim.cosim.experiment_config import load

    config = load(config_path).with_overrides(backend=backend, seed=seed, duration=duration,
                                              field_prefix="")
    if robot is not None:
        config = replace(config, robot=_robot_spec(robot))
    return replace(config, controllers=(controller,))


def _robot_spec(robot: str) -> str:
    """A robot given on the command line as the configuration holds it: a built-in name, or
    an assembly file's absolute path (checked here: it must load and fit the gateware)."""
    from mrm_cosim.cosim.track import check_robot_fits
    from mrm_cosim.models.robot import load_robot

    check_robot_fits(load_robot(robot), "robot")
    return str(Path(robot).resolve()) if str(robot).endswith(".toml") else robot


@named_by_flags(RUN_TRACK)
def _track(args) -> int:
    from mrm_cosim.cosim.closed_loop import LineFault
    from mrm_cosim.cosim.preview import paper_test_profile
    from mrm_cosim.cosim.table2 import Progress
    from mrm_cosim.cosim.track import check_robot_fits, run_faults, run_track
    from mrm_cosim.models.robot import load_robot
    from mrm_cosim.results import atomic_output_dir, check_output_dir

    check_output_dir(args.out)
    config = track_config(args.config, controller=args.controller, robot=args.robot,
                          backend=args.backend, seed=args.seed, duration=args.duration)
    _log.debug("experiment: %s", json.dumps(config.to_dict()))
    robot = load_robot(config.robot)
    check_robot_fits(robot, "robot")
    wave = _waveform(args)
    if args.signals is not None and wave is None:
        raise InputError("signals", "selects the signals of a --vcd or --fst window; give "
                         "one of them too")
    faults = [LineFault.parse(spec) for spec in args.line_fault]
    for where, given in (("faults", faults), ("safety.line_faults", config.faults.parsed)):
        for f in given:
            if config.backend == "model" and f.kind != "cut":
                raise InputError(where, "the model backend's link has no bits: it takes "
                                 "'cut' faults only; inject the others on compiled or pysim")
            if f.node > robot.n:
                raise InputError(where, f"the robot has {robot.n} nodes, not {f.node}")
    faults += list(config.faults.parsed)
    if wave is not None:            # refused before anything runs or prints
        from mrm_cosim.cosim.backends import VcdWindow

        if config.backend == "model":
            raise InputError(wave[0], "the model backend has no signals; use pysim or "
                             "compiled")
        if wave[0] == "fst" and config.backend == "compiled":
            from mrm_cosim.cosim.compiled import fst_headers_missing

            missing = fst_headers_missing()
            if missing:
                raise InputError("fst", f"Verilator's FST writer needs {', '.join(missing)} "
                                 "(Debian: apt-get install liblz4-dev zlib1g-dev); or use "
                                 "--vcd, or --backend pysim")

        with _wave_field(wave):
            VcdWindow.parse(wave[1], Path(args.out) / f"waves.{wave[0]}", signals=args.signals)
    tr = config.trajectory
    profile = paper_test_profile(robot, tr.amplitude, tr.duration)
    progress = None if args.quiet else Progress([args.controller], config.duration)
    with atomic_output_dir(args.out, made_by="mrm run track") as tmp:
        if progress is not None:
            progress.begin(args.controller)
        vcd_path = tmp / f"waves.{wave[0]}" if wave is not None else None
        with _wave_field(wave):
            result, summary = run_track(robot, args.controller, config.backend,
                                        config.duration, config.seed, gains=config.gains,
                                        timing=config.timing, plant_config=config.plant,
                                        progress=progress, profile=profile,
                                        vcd=wave and wave[1], signals=args.signals,
                                        vcd_path=vcd_path, faults=faults,
                                        on_trip=config.faults.on_trip,
                                        rearm_blend=config.faults.rearm_blend,
                                        safe_stop=config.faults.safe_stop,
                                        clocks=config.clocks)
        summary["version"] = __version__
        _write_track(tmp, args, config, robot, result, summary, profile)
    if args.json:
        _print_json(summary)
    elif not args.quiet:
        _print_track(args, config, summary)
    return _not_clean("track", run_faults(summary))


def _waveform(args) -> tuple[str, str] | None:
    """``("vcd" | "fst", "T0:T1")`` of a waveform request, ``None`` without one; FST needs
    its optional dependency (refused naming --fst, before anything runs)."""
    if args.vcd is not None and args.fst is not None:
        raise InputError("fst", "give one of --vcd and --fst (the same window as VCD or FST)")
    if args.fst is not None:
        from mrm_cosim.cosim.waves import require_fst

        require_fst("fst")
        return "fst", args.fst
    return None if args.vcd is None else ("vcd", args.vcd)


@contextlib.contextmanager
def _wave_field(wave):
    """The library names a bad window ``vcd`` whatever the format: name --fst for FST."""
    try:
        yield
    except InputError as exc:
        if wave is not None and wave[0] == "fst" and exc.field == "vcd":
            raise InputError("fst", exc.message) from None
        raise


def _write_track(tmp: Path, args, config, robot, result, summary, profile) -> None:
    from mrm_cosim.cosim.plots import pick_period, plot_timeline, plot_tracking
    from mrm_cosim.cosim.table2 import skew_figure, timeline_json
    from mrm_cosim.results import usual_mode, write_json

    wave = _waveform(args)
    if wave is not None:
        path = tmp / f"waves.{wave[0]}"
        if not path.exists() or path.stat().st_size == 0:
            raise InputError(wave[0], "the window is not inside the run (nothing recorded)")
        usual_mode(path)
        usual_mode(path.with_suffix(".gtkw"))
    q_d = profile.evaluate(result.t)[0]
    write_json(tmp / "summary.json", summary)
    (tmp / "config.toml").write_text(config.to_toml())
    write_json(tmp / "config.json", {
        "command": "mrm run track", "controller": args.controller,
        "backend": config.backend, "robot": robot.describe(), "seed": config.seed,
        "duration_s": config.duration, "vcd": args.vcd, "fst": args.fst,
        "signals": args.signals,
        "line_faults": list(args.line_fault), "experiment": config.to_dict(),
        "version": __version__})
    write_json(tmp / "timeline.json", timeline_json(result.master.records))
    records = result.master.records
    if any(r.complete for r in records):
        record = pick_period(records, when=0.5)
        plot_timeline(tmp / "timeline.png", record, robot.n,
                      result.master.timing.period_cycles,
                      f"{args.controller}: period {record.index} exchange",
                      skew=summary.get("period_skew"))
    plot_tracking(tmp / "tracking.png", result.t, q_d, result.q, result.tau,
                  f"{robot.name}: quintic test, {args.controller} on {config.backend}")
    skew_figure(tmp / "skew.png", result, robot.n, config, args.controller)


def _print_track(args, config, summary) -> None:
    from mrm_cosim.cosim.track import link_fault_places

    print(f"{args.controller} on {config.backend}: max tip error "
          f"{1e3 * summary['max_tip_error_m']:.4f} mm, rho {summary['rho_s']:.6f} s, "
          f"overruns {summary['overruns']}, link errors {summary['link_errors']}, "
          f"upload errors {summary.get('upload_errors', 0)}, "
          f"late replies {summary.get('late_replies', 0)}, "
          f"A/B/C/D done at " + _phases_text(summary["phases_us"])
          + f"; RTF {summary['rtf']:.0f}")
    if summary["link_errors"]:
        print("link faults counted at: " + link_fault_places(summary["link_error_detail"]))
    for event in summary.get("recovery", []):
        print(f"safety, {event['t_s']:.4f} s: {event['event']}")
    skew = not config.clocks.common or config.clocks.discipline
    print(f"results in {args.out}/ (summary.json, config.toml, timeline.json, tracking.png"
          + (", skew.png" if skew else "")
          + (", waves.vcd: the --vcd window" if args.vcd else "")
          + (", waves.fst: the --fst window" if args.fst else "")
          + ("; waves.gtkw opens it in GTKWave)" if args.vcd or args.fst else ")"))


def _phases_text(phases: dict) -> str:
    """``A 10.34, B 30.34, …, node_compute 5.64/5.64/5.64 µs`` (no value: ``–``; per-node
    lists joined by ``/``)."""
    def fmt(v):
        if isinstance(v, (list, tuple)):
            return "/".join(fmt(x) for x in v)
        return "–" if v is None else f"{v:.2f}"

    return ", ".join(f"{k} {fmt(v)}" for k, v in phases.items()) + " µs"


# --- line ----------------------------------------------------------------------------------
@named_by_flags(RUN_LINE)
def _line(args) -> int:
    from mrm_cosim.cosim.experiment_config import LINE_CONFIG, load
    from mrm_cosim.errors import InputError
    from mrm_cosim.cosim.line import PROFILES, line_reference, run_line
    from mrm_cosim.cosim.table2 import Progress
    from mrm_cosim.cosim.track import check_robot_fits, run_faults
    from mrm_cosim.master.trig_planner import plan_line
    from mrm_cosim.models.robot import load_robot
    from mrm_cosim.master.line_file import load_line_file
    from mrm_cosim.results import atomic_output_dir, check_output_dir

    check_output_dir(args.out)
    config = load(args.config or LINE_CONFIG).with_overrides(backend=args.backend,
                                                             seed=args.seed, field_prefix="")
    if args.duration is not None:
        from mrm_cosim.errors import require_positive

        require_positive(args.duration, "duration")
    robot = load_robot(args.robot or config.robot)
    check_robot_fits(robot, "robot")
    start, end, limits = load_line_file(args.file)
    plan = plan_line(start, end, limits)
    profiles = PROFILES if args.profile == "both" else (args.profile,)
    # every reference is computed and checked (workspace, singularity, limits) before any run
    try:
        references = {name: line_reference(robot, plan, name) for name in profiles}
    except InputError as exc:
        if exc.field == "robot" and args.robot is None:     # the config's robot, not a flag
            raise InputError("experiment.robot", exc.message) from None
        raise
    progress = None if args.quiet else Progress(list(profiles), args.duration or max(
        r.duration for r in references.values()) + 0.2)
    runs = {}
    with atomic_output_dir(args.out, made_by="mrm run line") as tmp:
        for name in profiles:
            if progress is not None:
                progress.begin(name)
            runs[name] = run_line(robot, plan, profile=name, controller=args.controller,
                                  backend=config.backend, seed=config.seed, gains=config.gains,
                                  timing=config.timing, plant_config=config.plant,
                                  duration=args.duration, progress=progress,
                                  reference=references[name], clocks=config.clocks)
        summary = {"command": "mrm run line", "file": str(Path(args.file).resolve()),
                   "robot": robot.name, "controller": args.controller,
                   "backend": config.backend, "seed": config.seed, "version": __version__,
                   "plan": plan.summary(),
                   "runs": {name: run.summary for name, run in runs.items()}}
        _write_line(tmp, args, config, robot, runs, summary)
    if args.json:
        _print_json(summary)
    elif not args.quiet:
        print((Path(args.out) / "line.md").read_text(), end="")
        print(f"results in {args.out}/ (summary.json, line.md, config.toml, tool_errors.png, "
              "tool_path.png, tracking_<profile>.png)")
    reasons = [f"{name}: {r}" for name, run in runs.items() for r in run_faults(run.summary)]
    return _not_clean("line", reasons)


def _write_line(tmp: Path, args, config, robot, runs, summary) -> None:
    from mrm_cosim.cosim.line import line_table
    from mrm_cosim.cosim.plots import plot_tool_errors, plot_tool_path, plot_tracking
    from mrm_cosim.results import write_json

    write_json(tmp / "summary.json", summary)
    (tmp / "config.toml").write_text(config.to_toml())
    (tmp / "line.md").write_text(
        f"# {robot.name}: Cartesian line ({Path(args.file).name}), {args.controller} on "
        f"{config.backend}, seed {config.seed}\n\n" + line_table(runs))
    first = next(iter(runs.values()))
    title = f"{robot.name}: line, {args.controller} on {config.backend}"
    plot_tool_errors(tmp / "tool_errors.png", {n: (r.result.t, r.errors) for n, r in runs.items()},
                     title)
    plot_tool_path(tmp / "tool_path.png", first.errors.tool_desired,
                   {n: r.errors.tool_actual for n, r in runs.items()}, title)
    for name, run in runs.items():
        plot_tracking(tmp / f"tracking_{name}.png", run.result.t, run.q_desired, run.result.q,
                      run.result.tau, f"{title}, {name} profile")


# --- table2 --------------------------------------------------------------------------------
@named_by_flags(RUN_TABLE2)
def _table2(args) -> int:
    from mrm_cosim.cosim.experiment_config import load
    from mrm_cosim.cosim.table2 import Progress, run_table2
    from mrm_cosim.cosim.track import run_faults
    from mrm_cosim.results import check_output_dir

    check_output_dir(args.out)
    config = load(args.config).with_overrides(backend=args.backend, seed=args.seed,
                                              duration=args.duration, field_prefix="")
    _log.debug("experiment: %s", json.dumps(config.to_dict()))
    jobs = table2_jobs(len(config.controllers)) if args.jobs is None else args.jobs
    if isinstance(jobs, bool) or jobs < 1:
        raise InputError("jobs", f"must be a whole number ≥ 1, not {args.jobs!r}")
    progress = None if args.quiet else Progress(config.controllers, config.duration)
    summary = run_table2(config, args.out, progress=progress, jobs=jobs)
    if args.json:
        _print_json(summary)
    elif not args.quiet:
        print((Path(args.out) / "table2.md").read_text(), end="")
        print(f"results in {args.out}/ (summary.json, table2.md, config.toml, "
              "fig4_tracking.png, fig5_errors.png, torques.png, <controller>/timeline.png)")
    reasons = [f"{c}: {r}" for c, s in summary["controllers"].items() for r in run_faults(s)]
    return _not_clean("table2", reasons)


# --- dmp-table2 ----------------------------------------------------------------------------
@named_by_flags(RUN_DMP_TABLE2)
def _dmp_table2(args) -> int:
    from mrm_cosim.cosim.dmp_table2 import (DMP_CONFIG, load_dmp_config, run_dmp_table2,
                                            summary_dict, table_markdown)
    from mrm_cosim.cosim.experiment_config import _robot
    from mrm_cosim.cosim.plots import plot_dmp_errors, plot_dmp_paths
    from mrm_cosim.cosim.track import check_robot_fits, run_faults
    from mrm_cosim.models.robot import load_robot
    from mrm_cosim.results import atomic_output_dir, check_output_dir, write_json

    check_output_dir(args.out)
    config_path = Path(args.config) if args.config else DMP_CONFIG
    config = load_dmp_config(config_path)
    overrides = {k: v for k, v in (("backend", args.backend), ("seed", args.seed)) if v is not None}
    if args.robot is not None:
        try:
            overrides["robot"] = _robot(args.robot, Path.cwd())
        except InputError as exc:
            raise InputError("robot", exc.message) from None
    config = replace(config, **overrides)
    robot = load_robot(config.robot)
    check_robot_fits(robot, "robot")

    def progress(text):
        if not args.quiet:
            sys.stderr.write(f"mrm run dmp-table2: {text}\n")

    jobs = default_jobs() if args.jobs is None else args.jobs
    if isinstance(jobs, bool) or jobs < 1:
        raise InputError("jobs", f"must be a whole number ≥ 1, not {args.jobs!r}")
    results = run_dmp_table2(config, paths=args.path, progress=progress, jobs=jobs)
    summary = {"command": "mrm run dmp-table2", "config": str(config_path.resolve()),
               "overrides": {k: str(v) for k, v in overrides.items()},
               "robot": robot.name, "backend": config.backend, "seed": config.seed,
               "periods_ms": list(config.periods_ms), "version": __version__,
               "paths": summary_dict(results)}
    table = table_markdown(results, config)
    with atomic_output_dir(args.out, made_by="mrm run dmp-table2") as tmp:
        write_json(tmp / "summary.json", summary)
        (tmp / "config.toml").write_text(config_path.read_text())
        (tmp / "dmp_table2.md").write_text(
            f"# {robot.name}: motion primitives on the joints vs the traditional master "
            f"({config.backend}, seed {config.seed})\n\n{table}\n")
        title = f"{robot.name}, {config.backend}, seed {config.seed}"
        for period in config.periods_ms:
            plot_dmp_paths(tmp / f"paths_{period}ms.png", results, period, title)
        plot_dmp_errors(tmp / "errors.png", results, title)
    if args.json:
        _print_json(summary)
    elif not args.quiet:
        print((Path(args.out) / "dmp_table2.md").read_text(), end="")
        print(f"results in {args.out}/ (summary.json, dmp_table2.md, config.toml, "
              "paths_<period>ms.png, errors.png)")
    reasons = [f"{name} {arch} {period} ms: {r}" for name, res in results.items()
               for (arch, period), run in res.runs.items() for r in run_faults(run.summary)]
    return _not_clean("dmp-table2", reasons)


def table2_jobs(runs: int, cores: int | None = None) -> int:
    """``mrm run table2``'s processes by default: one per run (controller) where the machine
    has two cores or more, else 1. Equal runs on fewer cores than runs finish together in
    ``runs / cores`` run times side by side, but in ``⌈runs / cores⌉`` when each core takes
    whole runs (three on two cores: 1.5 against 2; measured 26 Nov on this 2-core machine,
    quiet: the runs' part of the table 4.7 s against 6.0 s)."""
    cores = default_jobs() if cores is None else cores
    return max(1, runs) if cores >= 2 else 1


def default_jobs() -> int:
    """The CPU cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:                      # not on Linux
        return max(1, os.cpu_count() or 1)


def _plant_config(uncertainty: float):
    from mrm_cosim.models.plant import PlantConfig

    try:
        return PlantConfig(perturbation=uncertainty)
    except InputError as exc:
        raise InputError("uncertainty", exc.message) from None
    except ValueError as exc:
        raise InputError("uncertainty", str(exc)) from None


def _config_dict(config) -> dict:
    from dataclasses import asdict, is_dataclass

    return json.loads(json.dumps(asdict(config) if is_dataclass(config) else vars(config),
                                 default=str))
