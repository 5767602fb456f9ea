"""Gain sweeps for the Table 2 experiment: one controller, one gain varied, the rest from a config.

Each point is a full closed-loop run through ``cosim.track.run_track`` (gateware in the loop)
on the chosen backend, with the plant, seed, timing and other gains of the experiment config.
It prints one line per point (ρ, max tip and joint error, max |τ|, overruns) and can save
them as JSON. This is how the gains in ``configs/table2.toml`` were chosen
(``docs/experiments.md``, "Tuning"); it runs for minutes to hours, never in CI.

Examples::

    python benchmarks/table2_sweep.py --controller pid-1khz --gain pid_1khz_hz 5 10 20 40
    python benchmarks/table2_sweep.py --controller vdc --gain k_j 30 60 120 --duration 0.4 \\
        --backend model --json results/sweep_kj.json
    python benchmarks/table2_sweep.py --controller vdc --gain lam 50 100 --set k_j=80
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from mrm_cosim.cosim.experiment_config import from_dict, load
from mrm_cosim.cosim.track import run_track
from mrm_cosim.master.cycle import CONTROLLERS
from mrm_cosim.results import atomic_write_text


def _point(config, controller: str) -> dict:
    t0 = time.perf_counter()
    result, s = run_track(config.robot, controller, config.backend, config.duration,
                          config.seed, gains=config.gains, timing=config.timing,
                          plant_config=config.plant)
    late = [r for r in result.master.records if not r.complete]
    return {"rho_s": s["rho_s"], "max_tip_error_m": s["max_tip_error_m"],
            "max_joint_error_rad": s["max_joint_error_rad"],
            "final_joint_error_rad": float(np.abs(_final_error(config, result)).max()),
            "max_abs_torque_Nm": np.abs(result.tau).max(axis=0).tolist(),
            "overruns": s["overruns"], "incomplete_periods": len(late),
            "link_errors": s["link_errors"], "wall_s": time.perf_counter() - t0}


def _final_error(config, result) -> np.ndarray:
    from mrm_cosim.cosim.preview import paper_test_profile
    from mrm_cosim.models.robot import load_robot

    profile = paper_test_profile(load_robot(config.robot), config.trajectory.amplitude,
                                 config.trajectory.duration)
    return profile.evaluate(result.t[-1:])[0][0] - result.q[-1]


def sampled_pid_radius(hz: float, period: float = 1e-3, delay: float = 25e-6,
                       current_bandwidth: float = 1000.0) -> float:
    """Spectral radius of the master's sampled PID loop on a rigid joint (no friction).

    Plant J q̈ = τ_m, amplifier T τ̇_m = u − τ_m (T = 1/(2π·current_bandwidth)); the master
    samples q, q̇ at the period start, applies u = −k_p q − k_d q̇ − k_i I after ``delay`` and
    holds it for the rest of the period (and the previous u before). Gains as
    ``cosim.closed_loop.pid_gains`` (triple pole at 2π·hz; the result does not depend on J).
    Stable when the radius is below 1.
    """
    from scipy.linalg import expm

    w = 2 * np.pi * hz
    kp, ki, kd = 3 * w * w, w**3, 3 * w
    tau_i = 1 / (2 * np.pi * current_bandwidth)
    A = np.array([[0, 1, 0], [0, 0, 1], [0, 0, -1 / tau_i]])
    B = np.array([0, 0, 1 / tau_i])

    def flow(h):
        M = np.zeros((4, 4))
        M[:3, :3], M[:3, 3] = A * h, B * h
        E = expm(M)
        return E[:3, :3], E[:3, 3]

    (A1, B1), (A2, B2) = flow(delay), flow(period - delay)
    phi = np.zeros((5, 5))                      # state: q, q̇, τ_m, previous u, integral
    for j in range(5):
        z = np.zeros(5)
        z[j] = 1.0
        x, u_prev, integral = z[:3], z[3], z[4]
        integral = integral + period * x[0]
        u = -kp * x[0] - kd * x[1] - ki * integral
        x = A2 @ (A1 @ x + B1 * u_prev) + B2 * u
        phi[:, j] = np.r_[x, u, integral]
    return float(np.abs(np.linalg.eigvals(phi)).max())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default=None, help="experiment TOML (default configs/table2.toml)")
    p.add_argument("--controller", choices=CONTROLLERS)
    p.add_argument("--gain", nargs="+", metavar=("NAME", "VALUE"),
                   help="a Gains field and the values to try")
    p.add_argument("--pid-stability", action="store_true",
                   help="print the sampled 1 kHz PID loop's stability limit and exit")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="fix another Gains field for every point")
    p.add_argument("--backend", default=None)
    p.add_argument("--duration", type=float, default=None)
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--json", default=None, help="write the points here as JSON")
    p.add_argument("--friction-comp", type=float, default=None, metavar="FRACTION",
                   help="VDC joint friction estimates as FRACTION x the nominal friction "
                   "(shorthand for --set friction_comp=FRACTION)")
    args = p.parse_args(argv)
    if args.pid_stability:
        for hz in (5, 15, 40, 80):
            print(f"pid_1khz_hz {hz:5g}: spectral radius {sampled_pid_radius(hz):.4f}")
        hz = next(h for h in np.arange(1.0, 1000.0, 0.5) if sampled_pid_radius(h) >= 1.0)
        print(f"unstable from {hz:g} Hz")
        return 0
    if not args.controller or not args.gain:
        p.error("--controller and --gain are required (or --pid-stability)")
    base = load(args.config).with_overrides(backend=args.backend, seed=args.seed,
                                            duration=args.duration)
    name, values = args.gain[0], [float(v) for v in args.gain[1:]]
    fixed = {}
    for item in args.set:
        key, _, value = item.partition("=")
        fixed[key] = float(value)
    if args.friction_comp is not None:
        fixed["friction_comp"] = args.friction_comp
    points = []
    print(f"# {args.controller} on {base.backend}, seed {base.seed}, {base.duration:g} s, "
          f"fixed {fixed or 'nothing'}; varying {name}; friction estimates "
          f"{fixed.get('friction_comp', base.gains.friction_comp):g} x nominal", flush=True)
    print(f"# {name:>10} {'rho_s':>10} {'tip_mm':>9} {'joint_mrad':>10} {'final_mrad':>10} "
          f"{'max|tau| N m':>22} overruns wall_s", flush=True)
    for v in values:
        data = base.to_dict()
        data["gains"].update(fixed)
        data["gains"][name] = v
        config = replace(from_dict(data), controllers=(args.controller,))
        r = _point(config, args.controller)
        points.append({"controller": args.controller, name: v, **fixed,
                       "friction_comp": data["gains"]["friction_comp"], **r})
        tau = " ".join(f"{x:6.2f}" for x in r["max_abs_torque_Nm"])
        print(f"  {v:10g} {r['rho_s']:10.3g} {1e3 * r['max_tip_error_m']:9.4f} "
              f"{1e3 * r['max_joint_error_rad']:10.4f} {1e3 * r['final_joint_error_rad']:10.4f} "
              f"{tau:>22} {r['overruns']:8d} {r['wall_s']:6.0f}", flush=True)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.json, json.dumps({"config": base.to_dict(), "points": points},
                                                indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
