# amaranth: UnusedElaboratable=no
"""VDC unit: regressor table, program == bit-exact reference == RTL, error budget vs float."""

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mrm_cosim.hdl.node.engine_ref import EngineModel
from mrm_cosim.protocol.isa import IO_BASE
from mrm_cosim.protocol.fixed import (
    ACC, FORCE, GAIN, RHOT, THETA, VEL, WORD_MAX, WORD_MIN, theta_group,
)
from mrm_cosim.protocol.vdc_program import (
    Y_TABLE, VdcParams, theta_words, vdc_microcode, vdc_param_words,
)
from mrm_cosim.hdl.node.vdc import VdcUnit
from mrm_cosim.hdl.node.vdc_ref import VdcInputs, VdcModel, vdc_input_words, vdc_state_words
from mrm_cosim.master.quintic import QuinticProfile
from mrm_cosim.hdl.node.vdc_float_ref import ModuleGains, ModuleVDC
from mrm_cosim.models.robot import load_robot
from mrm_cosim.models.spatial import regressor

from .test_node_engine import run_engine

G0 = 9.81


def test_regressor_table_is_the_closed_form():
    rng = np.random.default_rng(0)
    for _ in range(20):
        w, V_r, dV_r, g = rng.normal(size=3), rng.normal(size=6), rng.normal(size=6), \
            rng.normal(size=3)
        a = dV_r[:3] + np.cross(w, V_r[:3]) + g
        P = np.outer(w, V_r[3:])
        vals = {"a": a, "P": {10 * m + n: P[m, n] for m in range(3) for n in range(3)},
                "dw": dV_r[3:]}
        Y = np.zeros((6, 13))
        for (row, col), parts in Y_TABLE.items():
            Y[row, col] = sum(s * vals[kind][idx] for s, kind, idx in parts)
        np.testing.assert_allclose(Y, regressor(w, V_r, dV_r, g), atol=1e-12)


def _model(rng, theta=None):
    if theta is None:
        theta = load_robot("mrm3").nominal_theta[1]
    K = rng.uniform(5.0, 200.0, (2, 6))
    rho = rng.uniform(0.0, 1.0, (2, 13)) * np.array([50.0] + [2.0] * 3 + [0.05] * 9)
    lower = theta - np.abs(theta) * 0.3 - 1e-4
    upper = theta + np.abs(theta) * 0.3 + 1e-4
    params = VdcParams.from_float(K, rho, lower, upper, 1e-3)
    return VdcModel(params, theta_words(theta)), (K, rho, lower, upper)


def _random_inputs(rng, scale=1.0):
    g = rng.normal(size=3)
    g *= G0 / np.linalg.norm(g)
    return VdcInputs.from_float(rng.normal() * scale, rng.normal(size=6) * scale,
                                rng.normal(size=6) * scale, rng.normal() * scale,
                                rng.uniform(-np.pi, np.pi), g)


def _engine_step(engine: EngineModel, mc, x: VdcInputs, first: bool):
    for name, v in vdc_input_words(x).items():
        engine.write(mc.addr(name), v)
    marks = engine.run("first" if first else "main")
    assert len(marks) == 1
    F_a = [engine.outputs[mc.addr(f"FA{k}") - IO_BASE] for k in range(6)]
    F_b = [engine.outputs[mc.addr(f"FB{k}") - IO_BASE] for k in range(6)]
    return F_a, F_b


def _engine_for(model: VdcModel) -> EngineModel:
    mc = vdc_microcode()
    engine = EngineModel(mc)
    for name, v in {**vdc_param_words(model.params), **vdc_state_words(model)}.items():
        engine.write(mc.addr(name), v)
    return engine


def _check_state(engine, model):
    mc = vdc_microcode()
    for name, v in vdc_state_words(model).items():
        assert engine.read(mc.addr(name)) == v, name


@pytest.mark.parametrize("seed", range(4))
def test_program_equals_reference(seed):
    rng = np.random.default_rng(seed)
    model, _ = _model(rng)
    engine = _engine_for(model)
    mc = vdc_microcode()
    for period in range(6):
        x = _random_inputs(rng, scale=2.0 if seed % 2 else 0.3)
        first = period == 0 or (seed == 3 and period == 3)
        if first:
            model.primed = False
        F_ref = model.step(x)
        assert _engine_step(engine, mc, x, first) == F_ref
        _check_state(engine, model)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(words=st.lists(st.integers(WORD_MIN, WORD_MAX), min_size=22, max_size=22),
       extreme=st.lists(st.sampled_from([WORD_MIN, WORD_MAX, 0, 1, -1]), min_size=22,
                        max_size=22),
       mix=st.lists(st.booleans(), min_size=22, max_size=22), seed=st.integers(0, 2**16))
def test_program_equals_reference_on_any_words(words, extreme, mix, seed):
    """Saturation everywhere, estimates pinned at their bounds, any gains."""
    w = [e if m else v for v, e, m in zip(words, extreme, mix, strict=True)]
    x = VdcInputs(w[0], w[1:7], w[7:13], w[13], w[14], w[15], w[16:19])
    rng = np.random.default_rng(seed)
    model, _ = _model(rng)
    model.params.K[0] = [w[19]] * 6
    model.params.rho_T[1] = [w[20]] * 13
    model.params.inv_T = w[21]
    model.theta[0] = list(model.params.upper[0])          # at the upper bounds
    model.theta[1] = list(model.params.lower[1])          # at the lower bounds
    engine = _engine_for(model)
    mc = vdc_microcode()
    for first in (True, False):
        F_ref = model.step(x)
        assert _engine_step(engine, mc, x, first) == F_ref
        _check_state(engine, model)


def test_rtl_equals_reference():
    rng = np.random.default_rng(7)
    model, _ = _model(rng)
    mc = vdc_microcode()
    xs = [_random_inputs(rng, 1.0), _random_inputs(rng, 1.0)]
    image = list(mc.init)
    for name, v in {**vdc_param_words(model.params), **vdc_state_words(model),
                    **vdc_input_words(xs[0])}.items():
        image[mc.addr(name)] = v
    writes = [(mc.addr(n), v) for n, v in vdc_input_words(xs[1]).items()]
    # Run "first" on xs[0]; the second run ("main", xs[1]) is loaded through the host port by
    # a second simulation, below, to keep this one short.
    mem, out, runs = run_engine(mc, ["first"], mem=image, name="vdc_first")
    F_ref = model.step(xs[0])
    assert out[:12] == F_ref[0] + F_ref[1]
    for name, v in vdc_state_words(model).items():
        assert mem[mc.addr(name)] == v, name
    assert runs[0][0] == mc.cycles("first")
    mem2, out2, runs2 = run_engine(mc, ["main"], mem=mem, host_writes=writes, name="vdc_main")
    F_ref = model.step(xs[1])
    assert out2[:12] == F_ref[0] + F_ref[1]
    for name, v in vdc_state_words(model).items():
        assert mem2[mc.addr(name)] == v, name
    cycles, marks = runs2[0]
    assert cycles == mc.cycles("main") < 600
    assert marks[0] < 300          # Comm C can be sent 6 µs after Comm B at 50 MHz


def test_vdc_unit_is_the_engine_with_the_vdc_program():
    assert VdcUnit().microcode is vdc_microcode()


# --- error budget against the float VDC ----------------------------------------------------

def _decode(words, fmt):
    return np.array([fmt.decode(w) for w in words])


def _float_twin(model: VdcModel):
    """A float VDC with exactly the quantized parameters and gains of ``model``."""
    theta = np.array([[THETA[theta_group(j)].decode(model.theta[i][j]) for j in range(13)]
                      for i in range(2)])
    prm = model.params
    Kq = np.array([[GAIN.decode(k) for k in prm.K[i]] for i in range(2)])
    rho_q = np.array([[RHOT[theta_group(j)].decode(prm.rho_T[i][j]) / 1e-3 for j in range(13)]
                      for i in range(2)])
    lo = np.array([[THETA[theta_group(j)].decode(prm.lower[i][j]) for j in range(13)]
                   for i in range(2)])
    hi = np.array([[THETA[theta_group(j)].decode(prm.upper[i][j]) for j in range(13)]
                   for i in range(2)])
    return ModuleVDC(theta, ModuleGains(K=Kq, rho=rho_q, lower=lo, upper=hi), period=1e-3)


def _quintic_comm_b(robot, k, n_periods, lam=50.0, error=2e-5, seed=0):
    """Comm B inputs of module k along the paper's quintic test, as the master computes them
    (pinocchio frame velocities of {C_k} for q̇ and q̇_r), with a small tracking error."""
    model = robot.pinocchio_model()
    data = model.createData()
    fid = model.getFrameId(f"link{k + 1}b")
    scale = np.array([(j % 3) + 1 for j in range(robot.n)], dtype=float)
    prof = QuinticProfile(robot.home, robot.home + scale * 0.1571, 1.0)
    rng = np.random.default_rng(seed)
    out = []
    for n in range(n_periods):
        t = n * 1e-3
        q_d, qd_d = (np.asarray(v).reshape(-1) for v in prof.evaluate(t)[:2])
        q = q_d + rng.normal(size=robot.n) * error
        qd = qd_d + rng.normal(size=robot.n) * error * 20
        qd_r = qd_d + lam * (q_d - q)
        pin.forwardKinematics(model, data, q, qd)
        pin.updateFramePlacements(model, data)
        V_C = pin.getFrameVelocity(model, data, fid, pin.LOCAL).vector.copy()
        g_C = data.oMf[fid].rotation.T @ np.array([0.0, 0.0, G0])
        pin.forwardKinematics(model, data, q, qd_r)
        V_rC = pin.getFrameVelocity(model, data, fid, pin.LOCAL).vector.copy()
        out.append((q[k], qd[k], qd_r[k], V_C, V_rC, g_C))
    return out


def _theta_lsb():
    return np.array([[THETA[theta_group(j)].resolution for j in range(13)]] * 2)


def _budget_run(model, samples):
    """Run fixed and float side by side on decoded inputs; max |ΔF| (N or N·m), max |Δθ|."""
    twin = _float_twin(model)
    errs = []
    g_prev = None
    for q, qd, qd_r, V_C, V_rC, g_C in samples:
        g_use = g_C if g_prev is None else g_prev    # gravity from the previous Comm D
        g_prev = g_C
        x = VdcInputs.from_float(qd_r, V_C, V_rC, qd, q, g_use)
        F_a, F_b = model.step(x)
        # The float twin sees the decoded words (what the node received) and the exact angle.
        fa, fb = twin.step(q, VEL.decode(x.qd), VEL.decode(x.qd_r), _decode(x.V_C, VEL),
                           _decode(x.V_rC, VEL), _decode(x.g_C, ACC))
        errs.append(max(np.abs(_decode(F_a, FORCE) - fa).max(),
                        np.abs(_decode(F_b, FORCE) - fb).max()))
    theta = np.array([[THETA[theta_group(j)].decode(model.theta[i][j]) for j in range(13)]
                      for i in range(2)])
    return np.array(errs), np.abs(theta - twin.theta)


def test_error_budget_quintic_mrm3():
    """Realistic inputs: every module of mrm3 along the quintic, adaptation on (docs/node.md)."""
    robot = load_robot("mrm3")
    for k in range(robot.n):
        samples = _quintic_comm_b(robot, k, 300, seed=k)
        rng = np.random.default_rng(10 + k)
        model, _ = _model(rng, robot.nominal_theta[k])
        errs, dtheta = _budget_run(model, samples)
        assert errs.max() < 1e-3, (k, errs.max())
        assert (dtheta / _theta_lsb()).max() < 40


def test_error_budget_random_inputs():
    """Random smooth motions: every velocity a sum of random sinusoids (up to 2 m/s or rad/s,
    up to 3 Hz), required velocities within 0.02 of the actual ones (a velocity *error*: the
    adaptation signal saturates at ±8 beyond that, on purpose), random gains and estimates,
    adaptation on."""
    rng = np.random.default_rng(11)
    worst = 0.0
    for _ in range(4):
        theta = load_robot("mrm3").nominal_theta[rng.integers(3), rng.integers(2)]
        model, _ = _model(rng, np.array([theta, theta]) * rng.uniform(0.7, 1.3))
        amp = rng.uniform(0.0, 1.0, (14, 2))
        freq = rng.uniform(0.1, 3.0, (14, 2)) * 2 * np.pi
        phase = rng.uniform(0, 2 * np.pi, (14, 2))
        g = rng.normal(size=3)
        g *= G0 / np.linalg.norm(g)
        samples = []
        for n in range(100):
            t = n * 1e-3
            sig = (amp * np.sin(freq * t + phase)).sum(axis=1)
            samples.append((3.0 * sig[0], sig[1], sig[1] + 0.01 * sig[2], sig[2:8],
                            sig[2:8] + 0.01 * sig[8:14], g))
        errs, dtheta = _budget_run(model, samples)
        worst = max(worst, errs.max())
        assert (dtheta / _theta_lsb()).max() < 40
    assert worst < 2e-3, worst
