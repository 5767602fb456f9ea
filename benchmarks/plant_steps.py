"""Plant speed (steps/s) for mrm3 and mrm6, and, with ``--accuracy``, the integrator's error.

Run on purpose (not a test)::

    python benchmarks/plant_steps.py [--steps N] [--repeat R] [--robots mrm3 mrm6]
                                     [--accuracy] [--json]

Speed is measured in three regimes, because the step takes different paths:

* ``sliding``: every joint moves (one ABA per step);
* ``rest``: every joint held by stiction (gravity/bias only, nothing moves);
* ``mixed``: the last joint moves, the others are held (likely-pattern check on M's blocks);

plus the cost of producing the per-FPGA-cycle encoder lines of a step (``encoder_cycles``)
while every joint moves at 0.3 rad/s (the paper's test speed) and at maximum speed. Each
figure is the best of ``--repeat`` runs, measured both per CPU second of this process (stable
on a shared machine) and per wall-clock second.

``--accuracy`` measures the error of the 10 µs step: friction-free motion against scipy's
DOP853 at rtol 1e-12 (and 20/40 µs to show the order), and a run with friction, stick-slip and
the current loop against the same plant at 1 µs.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time

import numpy as np
import pinocchio as pin

from mrm_cosim.models.plant import Plant, PlantConfig, true_parameters
from mrm_cosim.models.robot import load_robot


def _holding(plant_truth, q):
    model = plant_truth.model
    data = model.createData()
    return (pin.computeGeneralizedGravity(model, data, q)
            - plant_truth.spring_torque * np.cos(q + plant_truth.spring_phase))


def _best_rate(calls: int, repeat: int, reset, body) -> dict:
    """Calls per second of ``body``, best of ``repeat`` runs, by CPU time and by wall time."""
    cpu, wall = math.inf, math.inf
    for _ in range(repeat):
        reset()
        c0, w0 = time.process_time(), time.perf_counter()
        for _ in range(calls):
            body()
        cpu = min(cpu, time.process_time() - c0)
        wall = min(wall, time.perf_counter() - w0)
    return {"per_cpu_s": calls / cpu, "per_wall_s": calls / wall}


def _time_steps(plant: Plant, cmd: np.ndarray, steps: int, repeat: int, reset) -> dict:
    return _best_rate(steps, repeat, reset, lambda: plant.step(cmd))


def bench_speed(name: str, steps: int, repeat: int) -> dict:
    robot = load_robot(name)
    config = PlantConfig()
    truth = true_parameters(robot, config, seed=1)
    plant = Plant(robot, config, truth=truth)
    q0 = robot.home.copy()
    hold = _holding(truth, q0)
    n = robot.n
    out = {"robot": name, "n": n}

    # all joints slide: start moving, push along the motion (well above friction)
    push = hold + np.where(np.arange(n) % 2 == 0, 1.0, -1.0) * 0.3 * truth.peak_torque
    v0 = np.where(np.arange(n) % 2 == 0, 0.3, -0.3)
    out["sliding"] = _time_steps(plant, push, steps, repeat,
                                 lambda: plant.reset(q0, v0, tau_motor0=push))
    # all joints held by stiction
    out["rest"] = _time_steps(plant, hold, steps, repeat,
                              lambda: plant.reset(q0, tau_motor0=hold))
    # last joint moves, the others are held
    one = hold.copy()
    one[-1] += truth.friction.static[-1] + 1.0
    out["mixed"] = _time_steps(plant, one, steps, repeat,
                               lambda: plant.reset(q0, tau_motor0=one))
    out["mixed_moving_joints"] = int(np.count_nonzero(plant.qd))
    # encoder lines for every FPGA cycle of a step, all joints moving
    calls = max(steps // 10, 10)
    plant.reset(q0, v0, tau_motor0=push)
    plant.step(push)
    out["encoder_cycles"] = _best_rate(calls, repeat, lambda: None, plant.encoder_cycles)
    # and at the actuators' maximum speed (≈ 7.7 counts per step per joint)
    vmax = np.array([spec.max_speed for spec in truth.actuators])
    plant.reset(q0, np.sign(v0) * vmax, tau_motor0=push)
    plant.step(push)
    out["encoder_cycles_max_speed"] = _best_rate(calls, repeat, lambda: None,
                                                 plant.encoder_cycles)
    return out


def accuracy(name: str) -> dict:
    """Integrator error against independent references (see the module docstring)."""
    from scipy.integrate import solve_ivp

    robot = load_robot(name)
    n = robot.n
    counts_per_rad = 800_000 / (2.0 * math.pi)
    free = PlantConfig(friction=False, current_loop=False, perturbation=0.0)
    truth = true_parameters(robot, free, 0)
    model, data = truth.model, truth.model.createData()
    q0 = robot.home + 0.3
    v0 = np.linspace(1.0, -1.5, n)

    def rhs(t, y):
        q, v = y[:n], y[n:]
        tau = truth.spring_torque * np.cos(q + truth.spring_phase)
        return np.concatenate([v, pin.aba(model, data, q, v, tau)])

    T = 0.2
    ref = solve_ivp(rhs, (0.0, T), np.concatenate([q0, v0]), method="DOP853", rtol=1e-12,
                    atol=1e-13).y[:, -1]
    result = {"robot": name, "friction_free_T_s": T, "friction_free": {}}
    for dt in (1e-5, 2e-5, 4e-5):
        plant = Plant(robot, PlantConfig(dt=dt, friction=False, current_loop=False,
                                         perturbation=0.0))
        plant.reset(q0, v0)
        zero = np.zeros(n)
        for _ in range(round(T / dt)):
            plant.step(zero)
        result["friction_free"][f"{dt * 1e6:g}us"] = {
            "max_q_error_rad": float(np.abs(plant.q - ref[:n]).max()),
            "max_qd_error_rad_s": float(np.abs(plant.qd - ref[n:]).max()),
        }

    # friction on: a 10 µs run against a 1 µs run of the same plant, with a command that
    # drives every joint through stick-slip (sinusoid around the holding torque).
    T = 0.1
    config = {dt: PlantConfig(dt=dt, perturbation=0.0) for dt in (2e-5, 1e-5, 1e-6)}
    truth = true_parameters(robot, config[1e-5], 0)
    hold = _holding(truth, robot.home)
    amp = 0.3 * truth.peak_torque
    finals = {}
    for dt, cfg in config.items():
        plant = Plant(robot, cfg)
        plant.reset(robot.home, tau_motor0=hold)
        steps = round(T / dt)
        per_ms = round(1e-3 / dt)
        cmd = hold.copy()
        traj = []
        for k in range(steps):
            if k % per_ms == 0:                       # command held for 1 ms, like the master
                cmd = hold + amp * math.sin(2.0 * math.pi * k * dt / 0.05)
            plant.step(cmd)
            if (k + 1) % per_ms == 0:
                traj.append(plant.q)
        finals[dt] = np.array(traj)
    result["with_friction"] = {"T_s": T}
    for dt in (1e-5, 2e-5):
        err = np.abs(finals[dt] - finals[1e-6]).max()
        result["with_friction"][f"{dt * 1e6:g}us"] = {
            "max_q_error_vs_1us_rad": float(err), "in_counts": float(err * counts_per_rad)}
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=20_000, help="steps per timing run")
    parser.add_argument("--repeat", type=int, default=3, help="timing runs, best is kept")
    parser.add_argument("--robots", nargs="+", default=["mrm3", "mrm6"])
    parser.add_argument("--accuracy", action="store_true", help="also measure the error")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    if args.steps <= 0 or args.repeat <= 0:
        parser.error("--steps and --repeat must be positive")

    report = {"machine": {"python": sys.version.split()[0], "platform": platform.platform(),
                          "processor": platform.processor() or platform.machine(),
                          "pinocchio": pin.__version__},
              "dt_s": PlantConfig().dt, "speed": [], "accuracy": []}
    for name in args.robots:
        report["speed"].append(bench_speed(name, args.steps, args.repeat))
        if args.accuracy:
            report["accuracy"].append(accuracy(name))

    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    realtime = 1.0 / report["dt_s"]
    print(f"plant steps per CPU second (per wall second in brackets); dt = "
          f"{report['dt_s'] * 1e6:g} µs, real time = {realtime:,.0f} steps/s")
    for row in report["speed"]:
        print(f"  {row['robot']} (n={row['n']}), "
              f"{row['mixed_moving_joints']} joint(s) moving in 'mixed':")
        for key in ("sliding", "rest", "mixed", "encoder_cycles", "encoder_cycles_max_speed"):
            print(f"    {key:<26} {row[key]['per_cpu_s']:9,.0f}   "
                  f"({row[key]['per_wall_s']:,.0f})")
    for acc in report["accuracy"]:
        print(f"  {acc['robot']} accuracy, friction-free vs DOP853 over "
              f"{acc['friction_free_T_s']} s:")
        for dt, e in acc["friction_free"].items():
            print(f"    dt {dt:>5}: max |q error| {e['max_q_error_rad']:.2e} rad, "
                  f"max |qd error| {e['max_qd_error_rad_s']:.2e} rad/s")
        w = acc["with_friction"]
        for dt in ("10us", "20us"):
            print(f"    with friction, {dt} vs 1 µs over {w['T_s']} s: max |q error| "
                  f"{w[dt]['max_q_error_vs_1us_rad']:.2e} rad = {w[dt]['in_counts']:.3f} counts")
    return 0


if __name__ == "__main__":
    sys.exit(main())
