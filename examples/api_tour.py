"""The Python API in one script: robot, plant, trajectory, master dynamics, a closed-loop run.

Run it:  python examples/api_tour.py [--out tour.png]

What a notebook does with mrm-cosim, step by step, each on public names:

1. load the paper's three-module robot and look at it (``models.robot.load_robot``);
2. step the physical plant by hand: the arm released under gravity for 50 ms
   (``models.plant.Plant``);
3. plan the paper's quintic test (``cosim.preview.paper_test_profile``) and compute the torques
   it needs with the master's Newton–Euler recursion (``master.vdc.inverse_dynamics``),
   checked against pinocchio's RNEA;
4. run it in closed loop with the VDC controller in the nodes' bit-exact models
   (``cosim.track.run_track``, the ``model`` backend) and get the trace as numpy arrays;
5. draw the joint tracking errors — docs/experiments.md's Fig. 5, for one controller and a
   shorter run.
"""

import argparse

import numpy as np
import pinocchio as pin

from mrm_cosim.cosim.preview import paper_test_profile
from mrm_cosim.cosim.track import run_track
from mrm_cosim.master.vdc import inverse_dynamics
from mrm_cosim.models.plant import Plant, PlantConfig
from mrm_cosim.models.robot import load_robot


def main(out=None, duration: float = 0.2) -> dict:
    # 1. The robot: three modules, their types and the tool at home.
    robot = load_robot("mrm3")
    report = {"modules": [m.type.name for m in robot.modules],
              "tool_at_home_m": robot.tip_pose(robot.home)[:3, 3].tolist()}

    # 2. The plant, stepped by hand: zero torque, brakes released, 50 ms at its 10 µs step.
    plant = Plant(robot, PlantConfig(), seed=0)
    plant.reset(robot.home)
    for _ in range(5000):
        plant.step(np.zeros(robot.n))
    report["sag_after_50ms_rad"] = (plant.q - robot.home).tolist()

    # 3. The paper's test trajectory and the torques it needs (the master's recursion).
    profile = paper_test_profile(robot)
    t = np.linspace(0.0, 1.0, 11)
    q, qd, qdd = profile.evaluate(t)[:3]
    model = robot.pinocchio_model()
    data = model.createData()
    worst = 0.0
    for k in range(len(t)):
        tau = inverse_dynamics(robot, q[k], qd[k], qdd[k])
        worst = max(worst, float(np.abs(tau - pin.rnea(model, data, q[k], qd[k], qdd[k])).max()))
    report["newton_euler_vs_pinocchio_Nm"] = worst

    # 4. Closed loop: VDC in the nodes' bit-exact models, gateware timing, the plant.
    result, summary = run_track(robot, "vdc", "model", duration=duration, seed=0)
    q_d = profile.evaluate(result.t)[0]
    errors = q_d - result.q                          # (steps, joints), rad, numpy
    report.update(max_tip_error_m=summary["max_tip_error_m"],
                  trace_sha256=summary["trace_sha256"], steps=len(result.t))

    # 5. One figure.
    if out is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 3))
        for j in range(robot.n):
            ax.plot(result.t, 1e3 * errors[:, j], lw=0.8, label=f"joint {j + 1}")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("tracking error (mrad)")
        ax.set_title("VDC on mrm3, model backend (as docs/experiments.md Fig. 5)")
        ax.legend(fontsize=7)
        ax.grid(True, lw=0.3)
        fig.tight_layout()
        fig.savefig(out, dpi=110)
        plt.close(fig)
    return report


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=None, help="write the figure here (PNG)")
    ap.add_argument("--duration", type=float, default=0.2, help="closed-loop seconds")
    args = ap.parse_args()
    r = main(args.out, args.duration)
    assert r["newton_euler_vs_pinocchio_Nm"] < 1e-9
    for key, value in r.items():
        print(f"{key}: {value}")
