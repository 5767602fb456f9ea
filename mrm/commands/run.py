"""``mrm run``: closed-loop experiments. Today: ``preview`` (float controller on the plant)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from mrm import __version__
from mrm.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser("run", help="run a closed-loop experiment")
    sub = p.add_subparsers(dest="run_command", required=True)
    pp = sub.add_parser("preview", help="the paper's quintic test on the plant with a float "
                        "feedforward + PID controller at 1 kHz (no link, no gateware yet)")
    pp.add_argument("--robot", default="mrm3", help="built-in name or assembly .toml")
    pp.add_argument("--duration", type=float, default=1.5, help="simulated seconds")
    pp.add_argument("--seed", type=int, default=0, help="plant perturbation seed")
    pp.add_argument("--uncertainty", type=float, default=None,
                    help="relative perturbation of the plant's parameters (default: the plant's)")
    pp.add_argument("--out", default="results/preview", help="result folder (replaced)")
    pp.add_argument("--quiet", action="store_true", help="print nothing but errors")
    pp.set_defaults(func=_preview)


def _preview(args) -> int:
    from cosim.plots import plot_tracking
    from cosim.preview import run_preview
    from models.plant import PlantConfig
    from models.robot import load_robot
    from mrm.output import atomic_output_dir, write_json

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


def _plant_config(uncertainty: float):
    from models.plant import PlantConfig

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


