# amaranth: UnusedElaboratable=no
"""Joint controller: program == bit-exact reference == RTL; reference vs float equations."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mrm_cosim.hdl.node.engine_ref import EngineModel
from mrm_cosim.protocol.fixed import ACC, FORCE, POS, VEL, WORD_MAX, WORD_MIN
from mrm_cosim.protocol.isa import IO_BASE
from mrm_cosim.protocol.joint_program import (MODES, PID_SHIFT_MAX, JointParams, joint_microcode,
                                              joint_param_words, pid_formats)
from mrm_cosim.hdl.node.joint_ref import (JointInputs, JointModel, joint_input_words,
                                          joint_state_words)

from .test_node_engine import run_engine

CPR = 800_000
RAD = 2 * math.pi / CPR
CLOCK = 50e6


def _params(**kw):
    base = dict(lam=60.0, k_j=2.0, inertia=0.067, viscous=0.08, coulomb=0.5, offset=0.01,
                v_smooth=2e-3, k_p=800.0, k_i=4000.0, k_d=20.0, i_max=2e-4)
    base.update(kw)
    return JointParams.from_float(**base)


def _inputs(rng, t_cycles, tick=50):
    q_d0 = rng.uniform(-2.0, 2.0)
    v_d0 = rng.uniform(-0.5, 0.5)
    a_d0 = rng.uniform(-2.0, 2.0)
    t = t_cycles / CLOCK
    q = q_d0 + v_d0 * t + 0.5 * a_d0 * t * t + rng.normal() * 2e-4
    return JointInputs(q=math.floor(q / RAD), qd=VEL.encode(v_d0 + rng.normal() * 1e-2),
                       tn=t_cycles + tick, tau_D=FORCE.encode(rng.uniform(-5, 5)),
                       qd0=POS.encode(q_d0 / RAD), vd0=VEL.encode(v_d0),
                       ad0=ACC.encode(a_d0))


def _engine(params, model):
    mc = joint_microcode(params.pid_shift)
    eng = EngineModel(mc)
    for n, v in {**joint_param_words(params), **joint_state_words(model)}.items():
        eng.write(mc.addr(n), v)
    return eng


def _outputs(eng):
    mc = joint_microcode()
    return tuple(eng.outputs[mc.addr(n) - IO_BASE] for n in ("tau", "qdr_o", "err_o"))


def test_tick_fits_one_microsecond():
    mc = joint_microcode()
    for mode in MODES:
        # Started in the tick's cycle t, done in t + cycles, idle again at t + cycles + 1:
        # the next tick at t + 50 finds it idle (1 MHz at 50 MHz).
        assert mc.cycles(mode) <= 49, mode


@pytest.mark.parametrize("shift", [0, 5, PID_SHIFT_MAX])
@pytest.mark.parametrize("mode", MODES)
def test_program_equals_reference(mode, shift):
    rng = np.random.default_rng(MODES.index(mode))
    params = _params(pid_shift=shift)
    model = JointModel(params)
    eng = _engine(params, model)
    for k in range(40):
        x = _inputs(rng, 50 * k)
        ref = model.tick(mode, x)
        eng.run(mode, joint_input_words(x))
        assert _outputs(eng) == ref
        mc = joint_microcode()
        for n, v in joint_state_words(model).items():
            assert eng.read(mc.addr(n)) == v, n


word = st.integers(WORD_MIN, WORD_MAX)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ins=st.lists(word, min_size=7, max_size=7),
       prm=st.lists(word, min_size=17, max_size=17),
       state=st.lists(word, min_size=4, max_size=4), mode=st.sampled_from(MODES),
       shift=st.integers(0, PID_SHIFT_MAX))
def test_program_equals_reference_on_any_words(ins, prm, state, mode, shift):
    params = JointParams(*prm, pid_shift=shift)
    model = JointModel(params, *state)
    eng = _engine(params, model)
    x = JointInputs(*ins)
    for _ in range(2):
        ref = model.tick(mode, x)
        eng.run(mode, joint_input_words(x))
        assert _outputs(eng) == ref


@pytest.mark.parametrize("shift", [0, 8])
def test_rtl_equals_reference(shift):
    rng = np.random.default_rng(9)
    params = _params(pid_shift=shift)
    model = JointModel(params)
    mc = joint_microcode(shift)
    image = list(mc.init)
    for n, v in joint_param_words(params).items():
        image[mc.addr(n)] = v
    for mode in MODES:
        x = _inputs(rng, 5000)
        before = dataclasses.replace(model)
        ref = model.tick(mode, x)
        ref2 = model.tick(mode, x)
        for n, v in joint_state_words(before).items():
            image[mc.addr(n)] = v
        mem, out, runs = run_engine(mc, [mode, mode], joint_input_words(x), mem=image,
                                    name=f"joint_{mode}_s{shift}")
        assert tuple(out[:3]) == ref2 and ref is not None
        for n, v in joint_state_words(model).items():
            assert mem[mc.addr(n)] == v, n
        assert [r[0] for r in runs] == [mc.cycles(mode)] * 2
        image = mem


def test_vdc_torque_matches_the_float_joint_equation():
    """τ = τ_Lr + I_m q̈_r + b q̇_r + F_c sgn_s(q̇_r) + τ_0 + k_j (q̇_r − q̇), with q_d, q̇_d
    interpolated from the period start. The interpolated position error is within 1/32 count
    (half a POS LSB) of the exact one; given that error, the torque agrees to 2e-4 N·m. (The
    smooth sign's slope F_c/v_s = 250 N·m·s/rad turns 1/32 count into up to 4e-3 N·m; the
    encoder's own 1-count resolution is 32 times coarser.)"""
    rng = np.random.default_rng(3)
    lam, kj, Im, b, Fc, t0, vs = 60.0, 2.0, 0.067, 0.08, 0.5, 0.01, 2e-3
    params = _params(lam=lam, k_j=kj, inertia=Im, viscous=b, coulomb=Fc, offset=t0, v_smooth=vs)
    worst = 0.0
    for _ in range(200):
        model = JointModel(params)
        t_cyc = int(rng.integers(0, 60_000))
        x = _inputs(rng, t_cyc - 50)
        model.tick("vdc", x)                      # prepares the reference for t_cyc
        x2 = dataclasses.replace(x, tn=t_cyc + 50)
        tau, _, e = model.tick("vdc", x2)
        t = t_cyc / CLOCK
        q_d0, v_d0, a_d0 = POS.decode(x.qd0) * RAD, VEL.decode(x.vd0), ACC.decode(x.ad0)
        q_d = q_d0 + v_d0 * t + 0.5 * a_d0 * t * t
        v_d = v_d0 + a_d0 * t
        q, qd = x.q * RAD, VEL.decode(x.qd)
        assert abs(POS.decode(e) - (q_d - q) / RAD) <= 1 / 32 + 2e-3
        qd_r = v_d + lam * POS.decode(e) * RAD
        qdd_r = a_d0 + lam * (v_d - qd)
        sgn = min(1.0, max(-1.0, qd_r / vs))
        expect = (FORCE.decode(x.tau_D) + Im * qdd_r + b * qd_r + Fc * sgn + t0
                  + kj * (qd_r - qd))
        worst = max(worst, abs(FORCE.decode(tau) - expect))
    assert worst < 2e-4


def test_pid_integral_is_clamped_and_torque_mode_passes_through():
    params = _params(k_p=0.0, k_d=0.0, k_i=1000.0, i_max=1e-5)
    model = JointModel(params)
    x = JointInputs(q=-1000, qd=0, tn=50, tau_D=FORCE.encode(1.5), qd0=0, vd0=0, ad0=0)
    for _ in range(5000):
        model.tick("pid", x)
    # 5000 ticks of a 1000-count error: 5e6 counts·ticks = 4883 coarse units, clamped.
    assert params.ihi < 4883
    assert model.i_hi == params.ihi
    tau, _, _ = JointModel(params).tick("torque", x)
    assert tau == FORCE.encode(1.5)


def test_rejects_gains_that_do_not_fit():
    from mrm_cosim.errors import InputError
    with pytest.raises(InputError, match="joint.kj"):
        JointParams.from_float(k_j=1e6)


def test_the_pid_gain_shift_moves_only_the_pid_statements():
    """A node's PID gain shift is a build parameter: the same registers at the same addresses,
    the same cycles per mode (the model backend and the node's timing rely on it), and only
    the PID torque's instructions differ (their product and output shifts)."""
    base = joint_microcode(0)
    for s in range(1, PID_SHIFT_MAX + 1):
        mc = joint_microcode(s)
        assert [mc.cycles(m) for m in MODES] == [base.cycles(m) for m in MODES]
        assert all(mc.addr(n) == base.addr(n) for n in joint_param_words(_params()))
        assert 0 < sum(a != b for a, b in zip(mc.words, base.words, strict=True)) <= 8
    with pytest.raises(ValueError, match="pid_shift"):
        pid_formats(PID_SHIFT_MAX + 1)


@pytest.mark.parametrize("shift", [0, 3, 8])
def test_shifted_gains_give_the_float_pid_torque(shift):
    """The scaled gain words against the float PID law they stand for: with the same SI gains,
    the torque of a node built with shift s equals k_p·e + k_i·I + k_d·ė (+ τ_D) to the
    rounding of the gain words (relative 2^-23 of each format's range) and of the torque
    word, and a gain 2^s times larger than shift 0 holds is refused at shift 0 only."""
    k_p, k_i, k_d = 9_000.0 * 2**shift, 60_000.0 * 2**shift, 250.0 * 2**shift
    params = _params(k_p=k_p, k_i=k_i, k_d=k_d, i_max=0.05, pid_shift=shift)
    model = JointModel(params)
    e_counts, qd = 37, 0.013
    x = JointInputs(q=-e_counts, qd=VEL.encode(qd), tn=100, tau_D=FORCE.encode(0.25), qd0=0,
                    vd0=0, ad0=0)
    model.tick("pid", dataclasses.replace(x, qd=0))      # a first tick: q_des = 0, integral e
    tau, _, _ = model.tick("pid", x)
    tick = 50 / CLOCK
    expected = 0.25 + k_p * e_counts * RAD + k_i * e_counts * RAD * tick - k_d * VEL.decode(x.qd)
    f = pid_formats(shift)
    slack = (FORCE.resolution + e_counts * f["kp"].resolution + e_counts * f["ki"].resolution
             + abs(VEL.decode(x.qd)) * f["kd"].resolution)
    assert abs(FORCE.decode(tau) - expected) <= slack
    if shift >= 3:
        from mrm_cosim.errors import InputError
        with pytest.raises(InputError, match="joint.kp"):
            _params(k_p=k_p, k_i=k_i, k_d=k_d, i_max=0.05, pid_shift=0)
