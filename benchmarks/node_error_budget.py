"""Error budget of the node's fixed-point VDC and joint controller against their float models.

Prints the figures quoted in docs/node.md "Error budget":

1. VDC forces, fixed (bit-exact reference) vs float (hdl.node.vdc_float_ref) on the *same decoded
   inputs*, along the MRM paper's quintic test on mrm3 (every module, 1 s at 1 kHz), with and
   without adaptation; and the parameter estimates' divergence in LSBs.
2. What the node's information costs even in float: required accelerations by backward
   difference (one period of lag) and gravity from the previous period, against the exact
   accelerations and the current gravity.
3. Joint torque, fixed vs float equation, on random states.

Run: ``.venv/bin/python benchmarks/node_error_budget.py [--periods 1000]``.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import pinocchio as pin

from mrm_cosim.protocol.fixed import ACC, FORCE, GAIN, POS, RHOT, THETA, VEL, theta_group
from mrm_cosim.hdl.node.joint_ref import JointInputs, JointModel
from mrm_cosim.hdl.node.vdc_ref import VdcInputs, VdcModel
from mrm_cosim.protocol.joint_program import JointParams
from mrm_cosim.protocol.vdc_program import VdcParams, theta_words
from mrm_cosim.master.quintic import QuinticProfile
from mrm_cosim.hdl.node.vdc_float_ref import (
    ModuleGains, ModuleVDC, link_a_acceleration, link_a_velocity, required_net_force, rz,
)
from mrm_cosim.models.robot import load_robot
from mrm_cosim.units import CLOCK_HZ

G0 = 9.81


def quintic_states(robot, k, n, lam=50.0, error=2e-5, quantize=1.0, seed=0):
    """Per period: the Comm B inputs of module k as the master computes them, plus the exact
    (not backward-differenced) accelerations for comparison.

    The joints track the quintic with a smooth error ``error · sin(2π·3 Hz·t + φ)`` (rad); the
    master sees ``q`` quantized to ``quantize`` counts (0: exact) and an exact ``q̇``.
    """
    model = robot.pinocchio_model()
    data = model.createData()
    fid = model.getFrameId(f"link{k + 1}b")
    scale = np.array([(j % 3) + 1 for j in range(robot.n)], dtype=float)
    prof = QuinticProfile(robot.home, robot.home + scale * 0.1571, 1.0)
    K = robot.counts_per_rev / (2 * math.pi)
    phase = np.random.default_rng(seed).uniform(0, 2 * math.pi, robot.n)
    w = 2 * math.pi * 3.0
    out = []
    for i in range(n):
        t = i * 1e-3
        q_d, qd_d, qdd_d = (np.asarray(v).reshape(-1) for v in prof.evaluate(t)[:3])
        q = q_d + error * np.sin(w * t + phase)
        qd = qd_d + error * w * np.cos(w * t + phase)
        q_meas = np.floor(q * K / quantize) * quantize / K if quantize else q
        qd_r = qd_d + lam * (q_d - q_meas)
        qdd_r = qdd_d + lam * (qd_d - qd)
        pin.forwardKinematics(model, data, q_meas, qd)
        pin.updateFramePlacements(model, data)
        V_C = pin.getFrameVelocity(model, data, fid, pin.LOCAL).vector.copy()
        g_C = data.oMf[fid].rotation.T @ np.array([0.0, 0.0, G0])
        pin.forwardKinematics(model, data, q_meas, qd_r, qdd_r)
        pin.updateFramePlacements(model, data)
        V_rC = pin.getFrameVelocity(model, data, fid, pin.LOCAL).vector.copy()
        dV_rC = pin.getFrameAcceleration(model, data, fid, pin.LOCAL).vector.copy()
        out.append(dict(q=q_meas[k], qd=qd[k], qd_r=qd_r[k], qdd_r=qdd_r[k], V_C=V_C,
                        V_rC=V_rC, dV_rC=dV_rC, g_C=g_C))
    return out


def make_model(theta, rho_scale):
    K = np.full((2, 6), 40.0)
    rho = rho_scale * np.array([50.0] + [2.0] * 3 + [0.05] * 9)[None, :].repeat(2, 0)
    lo = np.minimum(theta * 0.7, theta * 1.3) - 1e-4
    hi = np.maximum(theta * 0.7, theta * 1.3) + 1e-4
    return VdcModel(VdcParams.from_float(K, rho, lo, hi, 1e-3), theta_words(theta))


def float_twin(model):
    p = model.params
    dec = np.vectorize(lambda w, g: THETA[g].decode(int(w)))
    groups = np.array([theta_group(j) for j in range(13)])
    theta = dec(np.array(model.theta), groups[None, :])
    lo, hi = dec(np.array(p.lower), groups[None, :]), dec(np.array(p.upper), groups[None, :])
    rho = np.array([[RHOT[theta_group(j)].decode(p.rho_T[i][j]) / 1e-3 for j in range(13)]
                    for i in range(2)])
    K = np.array([[GAIN.decode(w) for w in p.K[i]] for i in range(2)])
    return ModuleVDC(theta, ModuleGains(K=K, rho=rho, lower=lo, upper=hi), 1e-3)


def vdc_budget(periods):
    robot = load_robot("mrm3")
    print("1. VDC forces, fixed vs float on the same decoded inputs (mrm3 quintic, "
          f"{periods} periods)")
    print("   module  adaptation  max|ΔF| (N, N·m)  mean      max|Δθ| (LSB)")
    for k in range(robot.n):
        states = quintic_states(robot, k, periods, seed=k)
        for rho_scale in (0.0, 1.0):
            model = make_model(robot.nominal_theta[k], rho_scale)
            twin = float_twin(model)
            errs, g_prev = [], None
            for s in states:
                g = s["g_C"] if g_prev is None else g_prev
                g_prev = s["g_C"]
                x = VdcInputs.from_float(s["qd_r"], s["V_C"], s["V_rC"], s["qd"], s["q"], g)
                F_a, F_b = model.step(x)
                fa, fb = twin.step(s["q"], VEL.decode(x.qd), VEL.decode(x.qd_r),
                                   np.array([VEL.decode(w) for w in x.V_C]),
                                   np.array([VEL.decode(w) for w in x.V_rC]),
                                   np.array([ACC.decode(w) for w in x.g_C]))
                F = np.array([FORCE.decode(w) for w in F_a + F_b])
                errs.append(np.abs(F - np.concatenate([fa, fb])).max())
            lsb = np.array([[THETA[theta_group(j)].resolution for j in range(13)]] * 2)
            th = np.array([[THETA[theta_group(j)].decode(model.theta[i][j]) for j in range(13)]
                           for i in range(2)])
            dth = (np.abs(th - twin.theta) / lsb).max()
            print(f"   {k + 1}       {'on ' if rho_scale else 'off'}         "
                  f"{max(errs):.2e}          {np.mean(errs):.2e}  {dth:.0f}")
    return robot


def information_cost(robot, periods):
    print("2. The node's information, in float: backward-difference accelerations and the "
          "previous period's gravity, against exact accelerations and current gravity")
    print("   module  q seen as  max|ΔF| (N, N·m)  rms       max|Δg| (m/s²)")
    for k in range(robot.n):
        theta = robot.nominal_theta[k]
        for quantize in (0.0, 1.0, 1 / 16):
            states = quintic_states(robot, k, periods, quantize=quantize, seed=k)
            errs, worst_g = [], 0.0
            vdc = ModuleVDC(theta, ModuleGains(K=np.zeros((2, 6))), 1e-3)
            g_prev = None
            for s in states:
                g = s["g_C"] if g_prev is None else g_prev
                worst_g = max(worst_g, np.abs(g - s["g_C"]).max())
                g_prev = s["g_C"]
                fa, fb = vdc.step(s["q"], s["qd"], s["qd_r"], s["V_C"], s["V_rC"], g,
                                  adapt=False)
                V_A = link_a_velocity(s["q"], s["qd"], s["V_C"])
                V_rA = link_a_velocity(s["q"], s["qd_r"], s["V_rC"])
                dV_rA = link_a_acceleration(s["q"], s["qd"], s["qdd_r"], s["V_rC"],
                                            s["dV_rC"])
                ea = required_net_force(theta[0], V_A, V_rA, dV_rA, rz(s["q"]).T @ s["g_C"],
                                        np.zeros(6))
                eb = required_net_force(theta[1], s["V_C"], s["V_rC"], s["dV_rC"], s["g_C"],
                                        np.zeros(6))
                errs.append(np.abs(np.concatenate([fa - ea, fb - eb])).max())
            errs = np.array(errs[1:])          # the first period has no history
            label = {0.0: "exact   ", 1.0: "1 count ", 1 / 16: "1/16 cnt"}[quantize]
            print(f"   {k + 1}       {label} "
                  f"{errs.max():.2e}          {np.sqrt(np.mean(errs**2)):.2e}  {worst_g:.2e}")


def joint_budget():
    rng = np.random.default_rng(3)
    rad = 2 * math.pi / 800_000
    lam, kj, Im, b, Fc, t0, vs = 60.0, 2.0, 0.067, 0.08, 0.5, 0.01, 2e-3
    params = JointParams.from_float(lam=lam, k_j=kj, inertia=Im, viscous=b, coulomb=Fc,
                                    offset=t0, v_smooth=vs)
    worst, worst_e = 0.0, 0.0
    for _ in range(2000):
        model = JointModel(params)
        t_cyc = int(rng.integers(0, 60_000))
        q_d0, v_d0, a_d0 = rng.uniform(-2, 2), rng.uniform(-0.5, 0.5), rng.uniform(-2, 2)
        t = t_cyc / CLOCK_HZ
        q_true = q_d0 + v_d0 * t + 0.5 * a_d0 * t * t + rng.normal() * 2e-4
        x = JointInputs(q=math.floor(q_true / rad), qd=VEL.encode(v_d0 + rng.normal() * 1e-2),
                        tn=t_cyc, tau_D=FORCE.encode(rng.uniform(-5, 5)),
                        qd0=POS.encode(q_d0 / rad), vd0=VEL.encode(v_d0), ad0=ACC.encode(a_d0))
        model.tick("vdc", x)
        tau, _, e = model.tick("vdc", JointInputs(**{**x.__dict__, "tn": t_cyc + 50}))
        qd0, vd0, ad0 = POS.decode(x.qd0) * rad, VEL.decode(x.vd0), ACC.decode(x.ad0)
        q_d, v_d = qd0 + vd0 * t + 0.5 * ad0 * t * t, vd0 + ad0 * t
        q, qd = x.q * rad, VEL.decode(x.qd)
        worst_e = max(worst_e, abs(POS.decode(e) - (q_d - q) / rad))
        qd_r = v_d + lam * POS.decode(e) * rad
        sgn = min(1.0, max(-1.0, qd_r / vs))
        expect = (FORCE.decode(x.tau_D) + Im * (a_d0 + lam * (v_d - qd)) + b * qd_r + Fc * sgn
                  + t0 + kj * (qd_r - qd))
        worst = max(worst, abs(FORCE.decode(tau) - expect))
    print("3. Joint controller (VDC mode), fixed vs float, 2000 random states")
    print(f"   interpolated position error vs exact: max {worst_e:.4f} counts")
    print(f"   torque given that position error: max {worst:.2e} N·m")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--periods", type=int, default=1000)
    args = parser.parse_args()
    robot = vdc_budget(args.periods)
    information_cost(robot, args.periods)
    joint_budget()


if __name__ == "__main__":
    main()
