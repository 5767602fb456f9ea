"""``mrm run``: closed-loop experiments: ``track`` (gateware in the loop) and ``preview``."""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path

from mrm_cosim import __version__
from mrm_cosim.errors import InputError


def _seed(text: str) -> int:
    """``--seed``: a non-negative integer, refused before anything runs (argparse names the
    flag and exits with code 2)."""
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, not {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, not {value}")
    return value


def register(subparsers) -> None:
    p = subparsers.add_parser("run", help="run a closed-loop experiment")
    sub = p.add_subparsers(dest="run_command", required=True)
    pp = sub.add_parser("preview", help="the paper's quintic test on the plant with a float "
                        "feedforward + PID controller at 1 kHz (no link, no gateware yet)")
    pp.add_argument("--robot", default="mrm3", help="built-in name or assembly .toml")
    pp.add_argument("--duration", type=float, default=1.5, help="simulated seconds")
    pp.add_argument("--seed", type=_seed, default=0, help="plant perturbation seed")
    pp.add_argument("--uncertainty", type=float, default=None,
                    help="relative perturbation of the plant's parameters (default: the plant's)")
    pp.add_argument("--out", default="results/preview", help="result folder (replaced)")
    pp.add_argument("--quiet", action="store_true", help="print nothing but errors")
    pp.set_defaults(func=_preview)
    pt = sub.add_parser("track", help="the paper's quintic test in closed loop with the gateware "
                        "(master, link, nodes, plant)")
    pt.add_argument("--controller", default="vdc", choices=["vdc", "pid-fpga", "pid-1khz"])
    pt.add_argument("--backend", default="compiled", choices=["compiled", "pysim", "model"])
    pt.add_argument("--robot", default="mrm3", help="built-in name or assembly .toml")
    pt.add_argument("--duration", type=float, default=1.5, help="simulated seconds")
    pt.add_argument("--seed", type=_seed, default=0, help="plant perturbation seed")
    pt.add_argument("--out", default="results/track", help="result folder (replaced)")
    pt.add_argument("--vcd", default=None, metavar="T0:T1",
                    help="write OUT/waves.vcd of this window only (times from period 0, e.g. "
                    "0.5ms:0.6ms; pysim and compiled backends)")
    pt.add_argument("--signals", default=None, metavar="PATTERN",
                    help="comma-separated globs of the signals in the VCD, dotted below the "
                    "top (e.g. 'torque*,node1.core.*'; default: all)")
    pt.add_argument("--line-fault", action="append", default=[],
                    metavar="KIND:DIR:NODE@T[+LEN]",
                    help="inject a fault on the line above NODE, DIR down (towards it) or up, "
                    "at T from period 0 for LEN (default one cycle); KIND cut, bit or stuck-d; "
                    "e.g. bit:up:2@2.006ms, cut:down:3@10ms+2us (repeatable; pysim and "
                    "compiled). summary.json says where each fault was counted")
    pt.add_argument("--quiet", action="store_true", help="print nothing but errors")
    pt.set_defaults(func=_track)
    p2 = sub.add_parser("table2", help="the paper's Table 2: pid-1khz, pid-fpga and vdc on the "
                        "quintic test, same plant and seed; table, plots, timelines")
    p2.add_argument("--config", default=None,
                    help="experiment TOML (default: configs/table2.toml)")
    p2.add_argument("--backend", default=None,
                    help="override the config's backend (any name run_track accepts)")
    p2.add_argument("--out", default="results/table2", help="result folder (replaced)")
    p2.add_argument("--seed", type=_seed, default=None, help="override the plant seed")
    p2.add_argument("--duration", type=float, default=None,
                    help="override the simulated seconds per controller")
    p2.add_argument("--jobs", type=int, default=None,
                    help="controllers run side by side (default: as many as there are CPU "
                    "cores, at most one per controller); the results do not depend on it")
    p2.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p2.set_defaults(func=_table2)


def _preview(args) -> int:
    from mrm_cosim.cosim.plots import plot_tracking
    from mrm_cosim.cosim.preview import run_preview
    from mrm_cosim.models.plant import PlantConfig
    from mrm_cosim.models.robot import load_robot
    from mrm_cosim.results import atomic_output_dir, check_output_dir, write_json

    check_output_dir(args.out)
    robot = load_robot(args.robot)
    config = PlantConfig() if args.uncertainty is None else _plant_config(args.uncertainty)
    result = run_preview(robot, duration=args.duration, seed=args.seed, plant_config=config)
    with atomic_output_dir(args.out) as tmp:
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
    if not args.quiet:
        s = result.summary
        print(f"preview on {robot.name} (plant only, no gateware): "
              f"max tip speed {s['max_tip_speed_m_s']:.4f} m/s, "
              f"max tip error {1e3 * s['max_tip_error_m']:.4f} mm, rho {s['rho_s']:.6f} s, "
              f"max joint error {s['max_joint_error_rad']:.3e} rad")
        print(f"results in {Path(args.out)}/ (summary.json, trace.csv, tracking.png)")
    return 0


def _track(args) -> int:
    from mrm_cosim.cosim.table2 import Progress
    from mrm_cosim.cosim.track import check_robot_fits, run_track
    from mrm_cosim.models.robot import load_robot
    from mrm_cosim.errors import require_positive
    from mrm_cosim.results import check_output_dir

    check_output_dir(args.out)
    robot = load_robot(args.robot)
    check_robot_fits(robot, "--robot")
    duration = require_positive(args.duration, "--duration")
    if args.signals is not None and args.vcd is None:
        raise InputError("--signals", "selects the signals of a --vcd window; give --vcd too")
    from mrm_cosim.cosim.closed_loop import LineFault

    faults = [LineFault.parse(spec) for spec in args.line_fault]
    if faults and args.backend == "model":
        raise InputError("--line-fault", "the model backend's link is ideal: inject line "
                         "faults on compiled or pysim")
    for f in faults:
        if f.node > robot.n:
            raise InputError("--line-fault", f"the robot has {robot.n} nodes, not {f.node}")
    progress = None if args.quiet else Progress([args.controller], duration)
    if progress is not None:
        progress.begin(args.controller)
    vcd_tmp = None
    if args.vcd is not None:
        import tempfile

        fd, name = tempfile.mkstemp(prefix=".waves.", suffix=".vcd")
        os.close(fd)
        vcd_tmp = Path(name)
    try:
        result, summary = run_track(robot, args.controller, args.backend, duration, args.seed,
                                    progress=progress, vcd=args.vcd, signals=args.signals,
                                    vcd_path=vcd_tmp, faults=faults)
        summary["version"] = __version__
        _write_track(args, robot, result, summary, duration, vcd_tmp)
    finally:
        if vcd_tmp is not None:
            vcd_tmp.unlink(missing_ok=True)
    return 0


def _write_track(args, robot, result, summary, duration, vcd_tmp) -> None:
    import shutil

    from mrm_cosim.cosim.plots import pick_period, plot_timeline, plot_tracking
    from mrm_cosim.cosim.preview import paper_test_profile
    from mrm_cosim.cosim.table2 import timeline_json
    from mrm_cosim.results import atomic_output_dir, write_json

    q_d = paper_test_profile(robot).evaluate(result.t)[0]
    with atomic_output_dir(args.out) as tmp:
        write_json(tmp / "summary.json", summary)
        write_json(tmp / "config.json", {
            "command": "mrm run track", "controller": args.controller,
            "backend": args.backend, "robot": robot.describe(), "seed": args.seed,
            "duration_s": duration, "vcd": args.vcd, "signals": args.signals,
            "line_faults": list(args.line_fault),
            "version": __version__})
        if vcd_tmp is not None:
            if vcd_tmp.stat().st_size == 0:
                raise InputError("--vcd", "the window is not inside the run (nothing recorded)")
            shutil.copyfile(vcd_tmp, tmp / "waves.vcd")
        write_json(tmp / "timeline.json", timeline_json(result.master.records))
        records = result.master.records
        if any(r.complete for r in records):
            record = pick_period(records, when=0.5)
            plot_timeline(tmp / "timeline.png", record, robot.n,
                          result.master.timing.period_cycles,
                          f"{args.controller}: period {record.index} exchange")
        plot_tracking(tmp / "tracking.png", result.t, q_d, result.q, result.tau,
                      f"{robot.name}: quintic test, {args.controller} on {args.backend}")
    if not args.quiet:
        print(f"{args.controller} on {args.backend}: max tip error "
              f"{1e3 * summary['max_tip_error_m']:.4f} mm, rho {summary['rho_s']:.6f} s, "
              f"overruns {summary['overruns']}, link errors {summary['link_errors']}, "
              f"upload errors {summary.get('upload_errors', 0)}, "
              f"late replies {summary.get('late_replies', 0)}, "
              f"A/B/C/D done at " + _phases_text(summary["phases_us"])
              + f"; RTF {summary['rtf']:.0f}")
        from mrm_cosim.cosim.track import link_fault_places, run_faults

        faults = run_faults(summary)
        if faults:
            print("NOT A CLEAN RUN: " + "; ".join(faults))
        if summary["link_errors"]:
            print("link faults counted at: " + link_fault_places(summary["link_error_detail"]))
        print(f"results in {args.out}/" + (" (waves.vcd: the --vcd window)" if vcd_tmp else ""))


def _phases_text(phases: dict) -> str:
    """``A 10.34, B 30.34, …, node_compute 5.64/5.64/5.64 µs`` (no value: ``–``; per-node
    lists joined by ``/``)."""
    def fmt(v):
        if isinstance(v, (list, tuple)):
            return "/".join(fmt(x) for x in v)
        return "–" if v is None else f"{v:.2f}"

    return ", ".join(f"{k} {fmt(v)}" for k, v in phases.items()) + " µs"


def _table2(args) -> int:
    from mrm_cosim.cosim.experiment_config import load
    from mrm_cosim.cosim.table2 import Progress, run_table2
    from mrm_cosim.results import check_output_dir

    check_output_dir(args.out)
    config = load(args.config).with_overrides(backend=args.backend, seed=args.seed,
                                              duration=args.duration)
    jobs = default_jobs() if args.jobs is None else args.jobs
    if isinstance(jobs, bool) or jobs < 1:
        raise InputError("--jobs", f"must be a whole number ≥ 1, not {args.jobs!r}")
    progress = None if args.quiet else Progress(config.controllers, config.duration)
    summary = run_table2(config, args.out, progress=progress, jobs=jobs)
    if not args.quiet:
        print((Path(args.out) / "table2.md").read_text(), end="")
        print(f"results in {args.out}/ (summary.json, table2.md, config.toml, "
              "fig4_tracking.png, fig5_errors.png, torques.png, <controller>/timeline.png)")
    return 0 if summary["controllers"] else 1


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
        raise InputError("--uncertainty", exc.message) from None
    except ValueError as exc:
        raise InputError("--uncertainty", str(exc)) from None


def _config_dict(config) -> dict:
    from dataclasses import asdict, is_dataclass

    return json.loads(json.dumps(asdict(config) if is_dataclass(config) else vars(config),
                                 default=str))


