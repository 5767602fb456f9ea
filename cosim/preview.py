"""Float closed-loop preview: the paper's quintic test on the plant under the master-rate
feedforward + PID controller, without link or gateware.

Timing: the plant advances in fixed steps (default 10 µs); every period (1 ms) the controller
reads the encoder counts, computes a torque command and holds it for the period (zero-order
hold), as a 1 kHz master would. Desired motion: the MRM paper's test, q_i = i·q_d(t) (eq. 4),
then hold. Everything is deterministic for a given seed.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from mrm_cosim.master.feedforward_pid import FeedforwardPID
from mrm_cosim.master.kinematics import jacobian
from mrm_cosim.master.quintic import QuinticProfile
from mrm_cosim.models.plant import PlantConfig, make_plant
from mrm_cosim.models.robot import load_robot
from mrm_cosim.errors import InputError, require_positive

__all__ = ["PreviewResult", "run_preview", "paper_test_profile"]


def paper_test_profile(robot, pf: float = 0.1571, tf: float = 1.0) -> QuinticProfile:
    """q_i = i·q_d: joint i (1-based) moves from home by i·pf; joints beyond the third repeat
    the pattern (1, 2, 3, 1, 2, 3 …) so that six-module arms stay within their limits."""
    scale = np.array([(k % 3) + 1 for k in range(robot.n)], dtype=float)
    return QuinticProfile(robot.home, robot.home + scale * pf, tf)


@dataclass
class PreviewResult:
    """Recorded at the controller period. Shapes: (n_samples,) for ``t``, (n_samples, n) for
    joint arrays, (n_samples, 3) for tip positions."""

    t: np.ndarray
    q_d: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    counts: np.ndarray
    tip_d: np.ndarray
    tip: np.ndarray
    tip_speed_d: np.ndarray
    summary: dict


def run_preview(robot="mrm3", duration: float = 1.5, seed: int = 0, period: float = 1e-3,
                plant_config: PlantConfig | None = None,
                bandwidth_hz: float = 8.0) -> PreviewResult:
    """Run the preview and return its trace and summary.

    Parameters
    ----------
    robot : Robot or str
    duration : float, s
        Simulated time (the quintic lasts 1 s, then the goal is held).
    seed : int
        Seed of the plant's parameter perturbation.
    period : float, s
        Controller period.
    plant_config : PlantConfig, optional
    bandwidth_hz : float
        PID pole frequency, see :class:`master.feedforward_pid.FeedforwardPID`.
    """
    robot = load_robot(robot)
    duration = require_positive(duration, "duration")
    if duration > 60.0:
        raise InputError("duration", f"at most 60 s for a preview, not {duration!r}")
    config = PlantConfig() if plant_config is None else plant_config
    plant = make_plant(robot, config, seed=seed)
    steps = round(period / plant.dt)
    if steps < 1 or abs(steps * plant.dt - period) > 1e-12:
        raise InputError("period", f"must be a multiple of the plant step {plant.dt} s")
    profile = paper_test_profile(robot)
    ctrl = FeedforwardPID(robot, period, bandwidth_hz)
    plant.reset(robot.home)
    n_samples = int(round(duration / period))
    if n_samples < 2:       # one sample has no motion yet: rho would be 0/0
        raise InputError("duration", f"must cover at least 2 controller samples "
                         f"({2 * period:g} s at the {period:g} s period), not {duration!r}")
    t = np.arange(n_samples) * period
    q_d, qd_d, qdd_d, _ = profile.evaluate(t)
    rec_q = np.empty((n_samples, robot.n))
    rec_tau = np.empty((n_samples, robot.n))
    rec_counts = np.empty((n_samples, robot.n), dtype=np.int64)
    for i in range(n_samples):
        counts = plant.encoder_counts()
        rec_counts[i] = counts
        rec_q[i] = plant.q
        tau = ctrl(counts, q_d[i], qd_d[i], qdd_d[i])
        rec_tau[i] = tau
        for _ in range(steps):
            plant.step(tau)
    tip_d = np.array([robot.tip_pose(q)[:3, 3] for q in q_d])
    tip = np.array([robot.tip_pose(q)[:3, 3] for q in rec_q])
    speed_d = np.array([np.linalg.norm(jacobian(robot, q)[:3] @ v)
                        for q, v in zip(q_d, qd_d, strict=True)])
    tip_err = np.linalg.norm(tip_d - tip, axis=1)
    digest = hashlib.sha256()
    digest.update(rec_counts.tobytes())
    digest.update(rec_tau.tobytes())
    max_speed = float(speed_d.max())
    summary = {
        "controller": "feedforward-pid (float, master at 1 kHz)",
        "backend": "preview (no link, no gateware)",
        "robot": robot.name,
        "seed": seed,
        "duration_s": duration,
        "period_s": period,
        "plant_dt_s": plant.dt,
        "rho_s": float(tip_err.max() / max_speed),
        "max_tip_error_m": float(tip_err.max()),
        "max_tip_speed_m_s": max_speed,
        "max_joint_error_rad": float(np.abs(q_d - rec_q).max()),
        "max_torque_Nm": np.abs(rec_tau).max(axis=0).tolist(),
        "trace_sha256": digest.hexdigest(),
    }
    return PreviewResult(t, q_d, rec_q, rec_tau, rec_counts, tip_d, tip, speed_d, summary)
