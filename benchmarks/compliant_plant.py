"""The compliant plant's figures in docs/plant.md ("Compliant joints"), from one command.

Run on purpose (not a test)::

    python benchmarks/compliant_plant.py [--modes] [--effects] [--encoder] [--hold S]
                                         [--speed] [--config FILE]

* ``--modes``: the gear modes of mrm3 and mrm6 at home (generalised eigenvalues of the
  linear two-inertia system on K1 and on K3, nominal parameters) and the step bound;
* ``--effects``: Table 2's ρ per controller (model backend, the config's seed and gains) on
  the rigid plant, the compliant plant, and the compliant plant with one effect removed;
* ``--encoder``: the same compliant runs with the tip computed from the motor angles (what the
  encoders see) beside the link's, and the largest gear-deflection change per joint;
* ``--hold S``: each controller on the compliant plant for S seconds (the quintic, then the
  hold): the largest joint error per 0.5 s;
* ``--speed``: CPU time per plant step, rigid and compliant, Python path and numba kernel,
  side by side (best of 3 × 20,000 steps).

``--config`` is an experiment TOML (default: configs/table2.toml); the compliant runs set
``plant.joints = "compliant"`` on it.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
import pinocchio as pin
import scipy.linalg as sl

from mrm_cosim.cosim import experiment_config as ec
from mrm_cosim.cosim.preview import paper_test_profile
from mrm_cosim.cosim.track import START_CYCLE, _trajectory, run_loop, run_track
from mrm_cosim.master.cycle import Master
from mrm_cosim.master.kinematics import jacobian
from mrm_cosim.master.uploads import node_uploads, pid_gains
from mrm_cosim.models.compliant import CompliantPlant
from mrm_cosim.models.gear import GearConfig
from mrm_cosim.models.plant import Plant, PlantConfig, make_plant
from mrm_cosim.models.robot import load_robot
from mrm_cosim.units import CLOCK_HZ

CONTROLLERS = ("pid-1khz", "pid-fpga", "vdc")


def modes() -> None:
    for name in ("mrm3", "mrm6"):
        r = load_robot(name)
        p = CompliantPlant(r, PlantConfig(joints="compliant", perturbation=0.0,
                                          gear=GearConfig(stiffness_spread=0.0)))
        n = p.n
        M = pin.crba(p._model, p._model.createData(), np.asarray(r.home, float))
        M = np.triu(M) + np.triu(M, 1).T
        B = p.gears.motor_inertia
        print(f"{name}: actuators {[a.name for a in p._truth.actuators]}")
        for seg in ("k1", "k3"):
            K = getattr(p.gears, seg)
            Mb = np.block([[np.diag(B), np.zeros((n, n))], [np.zeros((n, n)), M]])
            Kb = np.block([[np.diag(K), -np.diag(K)], [-np.diag(K), np.diag(K)]])
            f = np.sqrt(np.clip(sl.eigh(Kb, Mb, eigvals_only=True), 0, None)) / (2 * np.pi)
            print(f"  {seg}: modes {np.round(f[f > 1e-3], 1)} Hz; motor against a locked link "
                  f"{np.round(np.sqrt(K / B) / (2 * np.pi), 1)} Hz")
        print(f"  step bound h_max {p.step_bound * 1e3:.2f} ms")


def effects(cfg) -> None:
    base = replace(cfg.plant, joints="compliant")
    g = base.gear
    variants = {
        "rigid": replace(cfg.plant, joints="rigid"),
        "compliant": base,
        "no noise, no ripple": replace(base, gear=replace(g, ripple=0.0, current_noise=0.0)),
        "no hysteresis": replace(base, gear=replace(g, hysteresis=False)),
        "gear only": replace(base, gear=replace(g, ripple=0.0, current_noise=0.0,
                                                 hysteresis=False)),
        "gears 10x stiffer": replace(base, gear=replace(g, stiffness_scale=10.0)),
    }
    for name, pc in variants.items():
        row = []
        for c in CONTROLLERS:
            _, s = run_track(cfg.robot, c, "model", cfg.duration, seed=cfg.seed,
                             gains=cfg.gains, timing=cfg.timing, plant_config=pc)
            row.append(f"{c} {s['rho_s']:.6f} s")
        print(f"{name}: " + " | ".join(row), flush=True)


def _compliant_run(cfg, controller, duration):
    robot = load_robot(cfg.robot)
    profile = paper_test_profile(robot)
    uploads = node_uploads(robot, controller, cfg.gains,
                           period_cycles=cfg.timing.period_cycles)
    master = Master(robot, controller, _trajectory(robot, profile), robot.counts_per_rev,
                    cfg.timing, lam=cfg.gains.lam,
                    pid=pid_gains(robot, cfg.gains.pid_1khz_hz, cfg.gains.pid_1khz_base_hz),
                    base_fb=cfg.gains.vdc_base_fb,
                    uploads=uploads)
    plant = make_plant(robot, replace(cfg.plant, joints="compliant"), cfg.seed)
    plant.reset(robot.home)
    theta = []
    step = plant.step

    def recording_step(tau):
        step(tau)
        theta.append(plant.theta)

    plant.step = recording_step
    start = -(-START_CYCLE // cfg.timing.period_cycles) * cfg.timing.period_cycles
    res, _ = run_loop(robot, "model", master, plant, start, uploads,
                      int(round(duration * CLOCK_HZ)))
    theta = np.array(theta)[-len(res.t):]
    return robot, profile, res, theta


def encoder(cfg) -> None:
    for c in CONTROLLERS:
        robot, profile, res, theta = _compliant_run(cfg, c, cfg.duration)
        q_d, qd_d, _, _ = profile.evaluate(res.t)
        tip_d = np.array([robot.tip_pose(q)[:3, 3] for q in q_d[::10]])
        link = np.linalg.norm(tip_d - [robot.tip_pose(q)[:3, 3] for q in res.q[::10]], axis=1)
        enc = np.linalg.norm(tip_d - [robot.tip_pose(q)[:3, 3] for q in theta[::10]], axis=1)
        speed = max(np.linalg.norm(jacobian(robot, q)[:3] @ v)
                    for q, v in zip(q_d[::10], qd_d[::10], strict=True))
        d = np.abs(theta - res.q).max(axis=0)
        print(f"{c}: rho link {link.max() / speed:.6f} s, as the encoders see it "
              f"{enc.max() / speed:.6f} s; max |theta - q| {np.round(d * 1e3, 2)} mrad",
              flush=True)


def hold(cfg, duration) -> None:
    for c in CONTROLLERS:
        _, profile, res, _ = _compliant_run(cfg, c, duration)
        q_d = profile.evaluate(res.t)[0]
        print(f"{c}, largest joint error (link) per 0.5 s, mrad:")
        for a in np.arange(0.0, duration, 0.5):
            m = (res.t >= a) & (res.t < a + 0.5)
            print(f"  t {a:.1f}-{a + 0.5:.1f} s: "
                  f"{np.round(np.abs(q_d[m] - res.q[m]).max(axis=0) * 1e3, 3)}", flush=True)


def speed() -> None:
    from mrm_cosim.cosim.model_kernel import load, load_plant

    load()
    r = load_robot("mrm3")
    n = 20000
    tau = [3.0 * np.sin(np.array([1.0, 2.0, 3.0]) * s * 1e-3) for s in range(n)]
    best = {}
    for _ in range(3):
        for kind in ("rigid", "compliant"):
            for compiled in (False, True):
                p = Plant(r, PlantConfig(), 0) if kind == "rigid" else \
                    CompliantPlant(r, PlantConfig(joints="compliant"), 0)
                if compiled:
                    p.use_kernel(load_plant())
                p.reset(r.home)
                t0 = time.process_time()
                for s in range(n):
                    p.step(tau[s])
                t = (time.process_time() - t0) / n
                key = (kind, "numba" if compiled else "python")
                best[key] = min(best.get(key, t), t)
    for (kind, path), t in best.items():
        print(f"{kind:9s} {path:6s} {t * 1e6:6.2f} µs/step")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=None)
    ap.add_argument("--modes", action="store_true")
    ap.add_argument("--effects", action="store_true")
    ap.add_argument("--encoder", action="store_true")
    ap.add_argument("--hold", type=float, default=None)
    ap.add_argument("--speed", action="store_true")
    a = ap.parse_args(argv)
    cfg = ec.load(a.config)
    if a.modes:
        modes()
    if a.effects:
        effects(cfg)
    if a.encoder:
        encoder(cfg)
    if a.hold:
        hold(cfg, a.hold)
    if a.speed:
        speed()


if __name__ == "__main__":
    main()
