"""The safe stop in the closed loop: line 1 of the mrm3 cut for good at the quintic's peak
speed (configs/table2.toml, rigid plant, model backend, ``on_trip = "end"``); per run each
joint's brake time after the cut, its motion from the cut to its brake and from its brake to
the end of the run (docs/faults.md "Safe stop in the closed loop")::

    python benchmarks/safe_stop_cut.py --png docs/img/safe_stop.png

Runs: every controller with the default safe stop (the hold follows the joint to rest, the
brake at standstill) and the brakes of ``[plant.brake]`` (1.5 × the motor's peak) and of
1.2 ×; the first version's fixed 50 ms timer (the hold's reference the trip position) for
comparison; ``--amplitude -0.1571`` runs the quintic downwards (joints moving with gravity);
``--trail 0 1 2`` runs the default stop once per STOP_TRAIL (mrad; default: the
:class:`SafeStopParams` default).
About a minute and a half of CPU per run, two at a time.
"""

from __future__ import annotations

import argparse
import dataclasses
from concurrent.futures import ProcessPoolExecutor

import numpy as np

T_FAST = 0.5
TAIL = 0.35


def _brake(cfg, factor):
    from mrm_cosim.models.actuators import ACTUATORS
    from mrm_cosim.models.brake import BrakeConfig
    from mrm_cosim.models.robot import load_robot

    plant = dataclasses.replace(cfg.plant, joints="rigid")
    if factor is None:
        return plant
    act = ACTUATORS[load_robot(cfg.robot).modules[0].type.actuator]
    return dataclasses.replace(plant, brake=BrakeConfig(
        holding_torque=factor * act.peak_torque / act.gear_ratio))


def one(job):
    from mrm_cosim.cosim.closed_loop import LineFault
    from mrm_cosim.cosim.experiment_config import load
    from mrm_cosim.cosim.preview import paper_test_profile
    from mrm_cosim.cosim.track import run_track
    from mrm_cosim.models.robot import load_robot
    from mrm_cosim.protocol.safe_stop import SafeStopParams

    controller, stop, factor, amplitude, trail = job
    cfg = load(None)
    safe = (SafeStopParams(stop_trail=trail) if stop == "default"
            else SafeStopParams(stop_s=0.05, standstill=0.0, stop_trail=0.0))
    limit = safe.stop_s
    profile = paper_test_profile(load_robot(cfg.robot), amplitude, cfg.trajectory.duration)
    res, _ = run_track(cfg.robot, controller, "model", T_FAST + limit + TAIL, cfg.seed,
                       gains=cfg.gains, timing=cfg.timing, plant_config=_brake(cfg, factor),
                       faults=[LineFault.parse(f"cut:down:1@{T_FAST}s+inf")], on_trip="end",
                       safe_stop=safe, profile=profile)
    i_cut = int(np.searchsorted(res.t, T_FAST))
    rows = []
    for j in range(res.q.shape[1]):
        e = int(np.argmax(res.brake[:, j]))
        rows.append((res.t[e] - T_FAST, res.q[e, j] - res.q[i_cut, j],
                     np.abs(res.q[e:, j] - res.q[e, j]).max()))
    return job, rows, res.t, res.q, res.brake


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--png")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--amplitude", type=float, default=0.1571)
    ap.add_argument("--quick", action="store_true", help="only the default stop, 1.5 ×")
    ap.add_argument("--trail", type=float, nargs="+", help="STOP_TRAIL values, mrad")
    ap.add_argument("--controllers", nargs="+", default=["vdc", "pid-fpga", "pid-1khz"])
    ap.add_argument("--no-fixed", action="store_true", help="without the fixed-timer runs")
    args = ap.parse_args(argv)
    from mrm_cosim.protocol.safe_stop import SafeStopParams

    trails = args.trail or [SafeStopParams().stop_trail]
    jobs = [(c, "default", None, args.amplitude, e) for e in trails for c in args.controllers]
    if not args.quick:
        jobs += [(c, "default", 1.2, args.amplitude, e) for e in trails
                 for c in args.controllers]
        if not args.no_fixed:
            jobs += [("vdc", "fixed", f, args.amplitude, 0.0) for f in (None, 1.2)]
    with ProcessPoolExecutor(args.workers) as pool:
        done = list(pool.map(one, jobs))
    print("| controller | safe stop | brake holds | brakes after the cut (ms) "
          "| cut → brake (mrad) | after the brake (µrad) |")
    print("|---|---|---|---|---|---|")
    for (controller, stop, factor, _, trail), rows, *_ in done:
        name = (f"standstill rule, trail {trail:g} mrad" if stop == "default"
                else "fixed 50 ms timer, hold at the trip position")
        print(f"| {controller} | {name} | {'1.5' if factor is None else factor} × peak | "
              + ", ".join(f"{1e3 * r[0]:.1f}" for r in rows) + " | "
              + ", ".join(f"{1e3 * r[1]:.3f}" for r in rows) + " | "
              + ", ".join(f"{1e6 * r[2]:.2f}" for r in rows) + " |")
    if args.png:
        from mrm_cosim.cosim.plots import plot_safe_stop

        picked = [d for d in done if d[0][2] is None and d[0][0] in ("vdc", "pid-fpga")]
        t = picked[0][2]
        n = min(len(d[2]) for d in picked)
        runs = {f"{d[0][0]}, " + (f"stop with a {d[0][4]:g} mrad trail" if d[0][1] == "default"
                                  else "fixed timer")
                : (d[3][:n], d[4][:n]) for d in picked}
        keep = t[:n] >= T_FAST - 0.05
        plot_safe_stop(args.png, t[:n][keep], {k: (q[keep], b[keep]) for k, (q, b)
                                               in runs.items()}, T_FAST,
                       "mrm3, Table 2's quintic, line 1 cut at 0.5 s (peak speed): "
                       "stop, hold, brake, STO", bound=1e-3)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
