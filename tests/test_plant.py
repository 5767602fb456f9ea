"""The plant against independent references: pinocchio, closed forms, exact arithmetic."""

import dataclasses
import math

import numpy as np
import pinocchio as pin
import pytest
from scipy.integrate import solve_ivp

from mrm_cosim.models.actuators import ACTUATORS
from mrm_cosim.models.drive import solve_stick_slip_bruteforce
from mrm_cosim.models.encoder import decode_quadrature
from mrm_cosim.models.plant import Perturbation, Plant, PlantConfig, true_parameters
from mrm_cosim.models.robot import load_robot
from mrm_cosim.errors import InputError

ROBOTS = ["mrm3", "mrm6"]
NOMINAL = dict(perturbation=0.0)


@pytest.fixture(scope="module", params=ROBOTS)
def robot(request):
    return load_robot(request.param)


def reference_model(robot):
    """Nominal rigid bodies + datasheet rotor inertia, built here, not by the plant."""
    model = robot.pinocchio_model()
    model.armature = np.array([ACTUATORS[m.type.actuator].output_inertia for m in robot.modules])
    return model


def springs(robot):
    amp = np.array([0.0 if m.spring is None else m.spring.torque for m in robot.modules])
    phase = np.array([0.0 if m.spring is None else m.spring.phase for m in robot.modules])
    return amp, phase


class Holder:
    """Torque that balances gravity and springs at q (what stiction has to hold beyond)."""

    def __init__(self, robot):
        self.model = reference_model(robot)
        self.data = self.model.createData()
        self.amp, self.phase = springs(robot)

    def __call__(self, q):
        return (pin.computeGeneralizedGravity(self.model, self.data, q)
                - self.amp * np.cos(q + self.phase))


def static_friction(robot):
    return np.array([ACTUATORS[m.type.actuator].static_friction for m in robot.modules])


def energy(robot, model, data, q, v):
    amp, phase = springs(robot)
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    return (0.5 * v @ M @ v + pin.computePotentialEnergy(model, data, q)
            - np.sum(amp * np.sin(q + phase)))


# --- rigid bodies ----------------------------------------------------------------------------

def test_one_step_acceleration_is_pinocchio_aba(robot):
    model = reference_model(robot)
    data = model.createData()
    rng = np.random.default_rng(3)
    plant = Plant(robot, PlantConfig(friction=False, springs=False, current_loop=False,
                                     **NOMINAL))
    for _ in range(5):
        q = robot.home + rng.uniform(-1, 1, robot.n)
        v = rng.uniform(-2, 2, robot.n)
        tau = rng.uniform(-3, 3, robot.n)
        plant.reset(q, v)
        plant.step(tau)
        a_ref = pin.aba(model, data, q, v, tau)
        a = (plant.qd - v) / plant.dt
        np.testing.assert_allclose(a, a_ref, rtol=1e-3, atol=1e-3 * np.abs(a_ref).max())


@pytest.mark.parametrize("name", ROBOTS)
def test_free_motion_matches_high_order_integration(name):
    """Friction off: the 10 µs plant against scipy DOP853 on pinocchio's ABA, 50 ms."""
    robot = load_robot(name)
    model = reference_model(robot)
    data = model.createData()
    amp, phase = springs(robot)
    q0 = robot.home + 0.3
    v0 = np.linspace(1.0, -1.5, robot.n)

    def rhs(t, y):
        q, v = y[:robot.n], y[robot.n:]
        return np.concatenate([v, pin.aba(model, data, q, v, amp * np.cos(q + phase))])

    T = 0.05
    ref = solve_ivp(rhs, (0.0, T), np.concatenate([q0, v0]), method="DOP853", rtol=1e-12,
                    atol=1e-13).y[:, -1]
    errors = []
    for dt in (1e-5, 2e-5):
        plant = Plant(robot, PlantConfig(dt=dt, friction=False, current_loop=False, **NOMINAL))
        plant.reset(q0, v0)
        zero = np.zeros(robot.n)
        for _ in range(round(T / dt)):
            plant.step(zero)
        assert plant.t == pytest.approx(T, rel=1e-12)
        errors.append(np.abs(plant.q - ref[:robot.n]).max())
    assert errors[0] < 1e-9                                 # rad, far below one count (7.9e-6)
    assert 3.0 < errors[1] / errors[0] < 5.0                # second order


def test_energy_is_conserved_without_friction(robot):
    model = reference_model(robot)
    data = model.createData()
    plant = Plant(robot, PlantConfig(friction=False, current_loop=False, **NOMINAL))
    q0 = robot.home + 0.2
    v0 = np.linspace(-1.0, 1.0, robot.n)
    plant.reset(q0, v0)
    e0 = energy(robot, model, data, q0, v0)
    zero = np.zeros(robot.n)
    drift = 0.0
    for k in range(10_000):
        plant.step(zero)
        if k % 1000 == 999:
            drift = max(drift, abs(energy(robot, model, data, plant.q, plant.qd) - e0))
    assert drift < 1e-10 * abs(e0)          # measured: 5e-11 J of 27 J (mrm3), 6e-10 of 101 J


# --- friction --------------------------------------------------------------------------------

def test_stiction_holds_bit_for_bit_below_static_friction(robot):
    hold = Holder(robot)
    rng = np.random.default_rng(7)
    q0 = robot.home + rng.uniform(-0.5, 0.5, robot.n)
    fs = static_friction(robot)
    cmd = hold(q0) + 0.98 * fs * rng.choice([-1, 1], robot.n)
    plant = Plant(robot, PlantConfig(**NOMINAL))
    plant.reset(q0, tau_motor0=cmd)
    before = plant.q
    for _ in range(3000):
        plant.step(cmd)
    assert plant.q.tobytes() == before.tobytes()
    assert plant.qd.tobytes() == np.zeros(robot.n).tobytes()
    assert np.array_equal(plant.encoder_counts(), np.floor(before * 800_000 / (2 * math.pi)))


def test_breakaway_above_static_friction(robot):
    hold = Holder(robot)
    q0 = robot.home.copy()
    fs = static_friction(robot)
    base = hold(q0)
    for j in range(robot.n):
        for sign in (1.0, -1.0):
            for factor, moves in ((0.999, False), (1.02, True)):
                cmd = base.copy()
                cmd[j] += sign * factor * fs[j]
                plant = Plant(robot, PlantConfig(current_loop=False, **NOMINAL))
                plant.reset(q0)
                for _ in range(200):
                    plant.step(cmd)
                dq = plant.q[j] - q0[j]
                if moves:
                    assert dq * sign > 0.0, (j, sign)
                else:
                    assert plant.q.tobytes() == q0.tobytes(), (j, sign)


def test_friction_step_matches_exhaustive_reference(robot):
    """One step from states mixing joints at rest, creeping and sliding, against the friction
    law solved by exhaustive search on pinocchio's M and bias, computed here."""
    hold = Holder(robot)
    model, data = hold.model, hold.data
    specs = [ACTUATORS[m.type.actuator] for m in robot.modules]
    fc = np.array([s.coulomb_friction for s in specs])
    fs = np.array([s.static_friction for s in specs])
    vs = np.array([s.stribeck_velocity for s in specs])
    b = np.array([s.viscous_friction for s in specs])
    rng = np.random.default_rng(17)
    plant = Plant(robot, PlantConfig(current_loop=False, **NOMINAL))
    h = plant.dt
    outcomes = set()
    for _ in range(60):
        q = robot.home + rng.uniform(-0.3, 0.3, robot.n)
        v = rng.choice([0.0, 0.0, 2e-5, -2e-5, 0.4, -0.4], robot.n)
        cmd = hold(q) + rng.uniform(-2.0, 2.0, robot.n) * fs
        plant.reset(q, v)
        plant.step(cmd)
        qm = q + 0.5 * h * v
        rho = cmd + hold.amp * np.cos(qm + hold.phase) - b * v
        level = fc + (fs - fc) * np.exp(-((v / vs) ** 2))
        force = rho - pin.nonLinearEffects(model, data, qm, v)
        M = pin.crba(model, data, qm)
        M = np.triu(M) + np.triu(M, 1).T
        w = solve_stick_slip_bruteforce(M, h * force, v, h * level)
        np.testing.assert_allclose(plant.qd, w, rtol=1e-9, atol=1e-15)
        assert np.array_equal(plant.qd == 0.0, w == 0.0)
        np.testing.assert_allclose(plant.q, qm + 0.5 * h * w, rtol=0, atol=1e-15)
        outcomes.add((bool(np.any(v == 0.0)), bool(np.any(w == 0.0)),
                      bool(np.any((v != 0.0) & (w == 0.0)))))
    assert len(outcomes) >= 3                     # rest, sticking and sliding cases all seen


def _pi_velocity_run(robot, plant, hold, j, v_target, integ, steps=6000, window=2000):
    """Hold joint j at v_target with a PI loop on top of gravity/spring compensation."""
    n = robot.n
    J = hold.model.armature[j] + 0.02
    kp = 2000.0 * J                      # N·m·s/rad: loop bandwidth ≈ 600 rad/s
    ki = 200.0 * kp
    total = 0.0
    v_mean = 0.0
    cmd = np.zeros(n)
    for k in range(steps):
        q, v = plant.q, plant.qd
        cmd[:] = hold(q)
        e = v_target - v[j]
        integ += ki * e * plant.dt
        cmd[j] += kp * e + integ
        plant.step(cmd)
        if k >= steps - window:
            total += kp * e + integ
            v_mean += plant.qd[j]
    return total / window, v_mean / window


@pytest.mark.parametrize("name", ["mrm3"])
def test_steady_state_friction_follows_stribeck_curve(name):
    robot = load_robot(name)
    hold = Holder(robot)
    j = robot.n - 1                       # the last joint: its inertia does not depend on q
    spec = ACTUATORS[robot.modules[j].type.actuator]
    speeds = [0.004, 0.008, 0.015, 0.03, 0.3, 1.0]
    measured = []
    for v_target in speeds:
        plant = Plant(robot, PlantConfig(current_loop=False, **NOMINAL))
        # start at speed, the integrator at a rough guess (Coulomb level): it converges from there
        plant.reset(robot.home, qd0=np.eye(robot.n)[j] * v_target,
                    tau_motor0=hold(robot.home))
        friction, v_mean = _pi_velocity_run(robot, plant, hold, j, v_target,
                                            spec.coulomb_friction)
        assert v_mean == pytest.approx(v_target, rel=1e-4)
        others = np.delete(plant.qd, j)
        assert np.all(others == 0.0)                        # the other joints stayed stuck
        measured.append(friction)
        expected = (spec.coulomb_friction + (spec.static_friction - spec.coulomb_friction)
                    * math.exp(-(v_target / spec.stribeck_velocity) ** 2)
                    + spec.viscous_friction * v_target)
        assert friction == pytest.approx(expected, rel=2e-3), v_target
    # shape: falls with speed through the Stribeck region, rises again with viscous friction
    assert measured[0] > measured[1] > measured[2] > measured[3]
    assert measured[3] < measured[4] < measured[5]


def test_viscous_steady_state_speed_matches_closed_form(robot):
    hold = Holder(robot)
    j = robot.n - 1
    config = PlantConfig(current_loop=False, **NOMINAL)
    truth = true_parameters(robot, config, 0)
    b = truth.friction.viscous.copy()
    b[j] = 5.0                                           # N·m·s/rad: time constant ≈ 17 ms
    truth = truth.with_friction(viscous=b)
    fc = truth.friction.coulomb[j]
    extra = 1.0                                          # N·m above Coulomb friction
    plant = Plant(robot, config, truth=truth)
    plant.reset(robot.home)
    tau_c = (truth.rotor_inertia[j] + 0.0166) / b[j]
    for _ in range(round(13 * tau_c / plant.dt)):        # 13 time constants: e^-13 = 2e-6
        cmd = hold(plant.q)
        cmd[j] += fc + extra
        plant.step(cmd)
    assert plant.qd[j] == pytest.approx(extra / b[j], rel=1e-5)


# --- amplifier, spring -----------------------------------------------------------------------

def test_current_loop_step_response_in_plant(robot):
    plant = Plant(robot, PlantConfig(**NOMINAL))
    T = 1.0 / (2.0 * math.pi * ACTUATORS[robot.modules[0].type.actuator].current_bandwidth)
    cmd = np.full(robot.n, 2.0)
    plant.reset(robot.home)
    history = []
    for _ in range(40):
        plant.step(cmd)
        history.append(plant.tau_motor)
    history = np.array(history)
    t = np.arange(1, 41) * plant.dt
    np.testing.assert_allclose(history[:, 0], 2.0 * (1.0 - np.exp(-t / T)), rtol=1e-12)
    k = int(np.searchsorted(history[:, 0], 2.0 * (1.0 - math.exp(-1.0))))
    assert t[k - 1] <= T <= t[k]                         # 63 % is crossed at t = T


def test_bandwidth_override_gives_exact_time_constant(robot):
    plant = Plant(robot, PlantConfig(current_bandwidth=1.0 / (2.0 * math.pi * 1e-4),
                                     **NOMINAL))
    plant.reset(robot.home)
    for _ in range(10):
        plant.step(np.full(robot.n, 1.0))
    np.testing.assert_allclose(plant.tau_motor, 1.0 - math.exp(-1.0), rtol=1e-12)


def test_torque_saturates_at_peak(robot):
    peak = np.array([ACTUATORS[m.type.actuator].peak_torque for m in robot.modules])
    plant = Plant(robot, PlantConfig(**NOMINAL))
    plant.reset(robot.home)
    cmd = np.where(np.arange(robot.n) % 2 == 0, 1e4, -1e4)
    for _ in range(300):
        plant.step(cmd)
        assert np.all(np.abs(plant.tau_motor) <= peak)
    np.testing.assert_allclose(plant.tau_motor, np.sign(cmd) * peak, rtol=1e-6)
    # and the joints accelerate as that torque dictates (friction is small against it)
    assert np.all(np.sign(plant.qd) == np.sign(cmd))


def test_spring_torque_enters_the_dynamics(robot):
    model = reference_model(robot)
    data = model.createData()
    amp, phase = springs(robot)
    if not np.any(amp):
        pytest.skip("no spring")
    q = robot.home + 0.3
    results = {}
    for on in (True, False):
        plant = Plant(robot, PlantConfig(friction=False, current_loop=False, springs=on,
                                         **NOMINAL))
        plant.reset(q)
        plant.step(np.zeros(robot.n))
        results[on] = plant.qd
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    tau_s = np.array([0.0 if m.spring is None else m.spring.torque_at(q[k])
                      for k, m in enumerate(robot.modules)])
    np.testing.assert_allclose((results[True] - results[False]) / plant.dt,
                               np.linalg.solve(M, tau_s), rtol=1e-9, atol=1e-12)


# --- encoder ---------------------------------------------------------------------------------

def test_encoder_lines_follow_the_motion_both_ways(robot):
    """Each joint in turn is thrown one way against a torque that brings it back: the A/B
    lines of every FPGA cycle decode (legal Gray code) to the plant's exact count."""
    hold = Holder(robot)
    M = pin.crba(hold.model, hold.data, robot.home)
    peak = np.array([ACTUATORS[m.type.actuator].peak_torque for m in robot.modules])
    k_rad = 800_000 / (2.0 * math.pi)
    for j in range(robot.n):
        torque = 0.7 * peak[j]
        v0 = 3e-3 * torque / M[j, j]                 # stops after ≈ 3 ms, then comes back
        plant = Plant(robot, PlantConfig(**NOMINAL))
        base = hold(robot.home)
        plant.reset(robot.home, qd0=np.eye(robot.n)[j] * v0, tau_motor0=base)
        count = plant.encoder_counts()
        directions = set()
        for _ in range(700):
            cmd = hold(plant.q)
            cmd[j] -= torque
            plant.step(cmd)
            cyc = plant.encoder_cycles()
            assert cyc.counts.shape == (plant.cycles_per_step, robot.n)
            changes = plant.encoder_changes()       # the same counts as change events
            prev = np.vstack([count[None, :], cyc.counts[:-1]])
            for i in range(robot.n):
                rows = np.flatnonzero(cyc.counts[:, i] != prev[:, i])
                assert changes[i] == list(zip(rows.tolist(), cyc.counts[rows, i].tolist(),
                                                  strict=True))
            decoded = decode_quadrature(cyc.a, cyc.b, count)   # raises on illegal Gray code
            np.testing.assert_array_equal(decoded, cyc.counts)
            np.testing.assert_array_equal(cyc.counts[-1], plant.encoder_counts())
            directions.update(np.sign(np.diff(cyc.counts[:, j])).tolist())
            count = plant.encoder_counts()
        assert {-1, 1} <= directions, j
        np.testing.assert_array_equal(plant.encoder_counts(), np.floor(plant.q * k_rad))


def test_encoder_cycles_needs_a_step(robot):
    plant = Plant(robot, PlantConfig(**NOMINAL))
    with pytest.raises(RuntimeError):
        plant.encoder_cycles()
    with pytest.raises(RuntimeError):
        plant.encoder_changes()


# --- true versus nominal ---------------------------------------------------------------------

def _trajectory(robot, config, seed, steps=400):
    plant = Plant(robot, config, seed)
    rng = np.random.default_rng(11)
    out = []
    for _ in range(steps):
        plant.step(rng.uniform(-3.0, 3.0, robot.n))
        out.append(np.concatenate([plant.q, plant.qd, plant.tau_motor]))
    return np.array(out)


def test_same_seed_same_plant_bit_for_bit(robot):
    config = PlantConfig(perturbation=0.2)
    a, b = true_parameters(robot, config, 42), true_parameters(robot, config, 42)
    for j in range(1, a.model.njoints):
        assert np.array_equal(a.model.inertias[j].toDynamicParameters(),
                              b.model.inertias[j].toDynamicParameters())
    for field in ("rotor_inertia", "spring_torque", "spring_phase"):
        assert np.array_equal(getattr(a, field), getattr(b, field))
    for field in ("coulomb", "static", "stribeck_velocity", "viscous"):
        assert np.array_equal(getattr(a.friction, field), getattr(b.friction, field))
    assert _trajectory(robot, config, 42).tobytes() == _trajectory(robot, config, 42).tobytes()


def test_different_seed_different_plant(robot):
    config = PlantConfig(perturbation=0.2)
    a, b = true_parameters(robot, config, 1), true_parameters(robot, config, 2)
    assert not np.array_equal(a.friction.coulomb, b.friction.coulomb)
    assert not np.array_equal(a.rotor_inertia, b.rotor_inertia)
    assert not np.array_equal(a.model.inertias[1].toDynamicParameters(),
                              b.model.inertias[1].toDynamicParameters())
    assert not np.array_equal(_trajectory(robot, config, 1), _trajectory(robot, config, 2))


def test_zero_perturbation_is_nominal_exactly(robot):
    truth = true_parameters(robot, PlantConfig(perturbation=0.0), seed=123)
    ref = reference_model(robot)
    for j in range(1, ref.njoints):
        assert np.array_equal(truth.model.inertias[j].toDynamicParameters(),
                              ref.inertias[j].toDynamicParameters())
    assert np.array_equal(truth.model.armature, ref.armature)
    specs = [ACTUATORS[m.type.actuator] for m in robot.modules]
    assert np.array_equal(truth.friction.coulomb, [s.coulomb_friction for s in specs])
    assert np.array_equal(truth.friction.static, [s.static_friction for s in specs])
    assert np.array_equal(truth.friction.viscous, [s.viscous_friction for s in specs])
    assert np.array_equal(truth.friction.stribeck_velocity, [s.stribeck_velocity for s in specs])
    amp, phase = springs(robot)
    assert np.array_equal(truth.spring_torque, amp) and np.array_equal(truth.spring_phase, phase)
    # and the seed no longer matters
    config = PlantConfig(perturbation=0.0)
    assert _trajectory(robot, config, 1).tobytes() == _trajectory(robot, config, 99).tobytes()


def test_perturbed_inertias_stay_physical_and_bounded(robot):
    nominal = reference_model(robot)
    p = 0.5
    config = PlantConfig(perturbation=Perturbation(links=p, rotor_inertia=p, friction=p,
                                                   spring=p))
    for seed in range(20):
        truth = true_parameters(robot, config, seed)
        for j in range(1, nominal.njoints):
            body, ref = truth.model.inertias[j], nominal.inertias[j]
            assert (1 - p) * ref.mass <= body.mass <= (1 + p) * ref.mass
            ev = np.linalg.eigvalsh(body.inertia)
            assert ev[0] > 0.0
            assert ev[0] + ev[1] >= ev[2] * (1.0 - 1e-9)          # triangle inequality
            # pseudo-inertia positive definite: a real mass distribution
            c = np.array(body.lever)
            sigma = 0.5 * np.trace(body.inertia) * np.eye(3) - body.inertia
            J = np.block([[sigma + body.mass * np.outer(c, c), body.mass * c[:, None]],
                          [body.mass * c[None, :], np.array([[body.mass]])]])
            assert np.linalg.eigvalsh(J)[0] > -1e-12 * np.trace(J)
        nominal_rotor = np.array([ACTUATORS[m.type.actuator].output_inertia
                                  for m in robot.modules])
        assert np.all(np.abs(truth.rotor_inertia / nominal_rotor - 1.0) <= p)
        assert np.all(truth.friction.static >= truth.friction.coulomb)


# --- interface -------------------------------------------------------------------------------

def test_rejects_bad_input(robot):
    plant = Plant(robot, PlantConfig(**NOMINAL))
    q = plant.q
    with pytest.raises(InputError, match="tau_cmd"):
        plant.step(np.full(robot.n, np.nan))
    with pytest.raises(InputError, match="tau_cmd"):
        plant.step(np.zeros(robot.n + 1))
    with pytest.raises(InputError, match="tau_cmd"):
        plant.step(np.zeros((robot.n, 1)))
    with pytest.raises(InputError, match="tau_cmd"):
        plant.step("torque")
    assert plant.q.tobytes() == q.tobytes() and plant.steps == 0
    with pytest.raises(InputError, match="q0"):
        plant.reset(np.zeros(robot.n - 1))
    with pytest.raises(InputError, match="tau_motor0"):
        plant.reset(q, tau_motor0=np.full(robot.n, 100.0))
    with pytest.raises(InputError, match="plant.dt"):
        PlantConfig(dt=1.5e-8)
    with pytest.raises(InputError, match="plant.perturbation.friction"):
        PlantConfig(perturbation=Perturbation(friction=0.9))
    with pytest.raises(InputError, match="plant.perturbation"):
        PlantConfig(perturbation=-0.1)
    with pytest.raises(InputError, match="seed"):
        Plant(robot, PlantConfig(), seed=-1)


def test_rejects_unknown_actuator(robot):
    module = dataclasses.replace(robot.modules[0],
                                 type=dataclasses.replace(robot.modules[0].type,
                                                          actuator="FHA-99X"))
    other = load_robot(robot.name)
    other.modules[0] = module
    with pytest.raises(InputError, match="actuator"):
        true_parameters(other, PlantConfig(), 0)


def test_unknown_actuator_of_a_user_type_names_the_type(robot):
    mtype = dataclasses.replace(robot.modules[1].type, actuator="FHA-99X",
                                source="module_types.III")
    other = load_robot(robot.name)
    other.modules[1] = dataclasses.replace(robot.modules[1], type=mtype)
    with pytest.raises(InputError) as info:
        true_parameters(other, PlantConfig(), 0)
    assert info.value.field == "module_types.III.actuator"


def test_time_counts_steps(robot):
    plant = Plant(robot, PlantConfig())
    for _ in range(1000):
        plant.step(np.zeros(robot.n))
    assert plant.steps == 1000 and plant.t == 1000 * 1e-5
    plant.reset(robot.home)
    assert plant.t == 0.0


@pytest.mark.parametrize("robot_name", ["mrm3", "mrm6"])
@pytest.mark.parametrize("friction", [True, False])
def test_compiled_step_equals_the_python_step(robot_name, friction):
    """:meth:`Plant.use_kernel`: the compiled step gives the Python step's state and count
    changes bit for bit — joints at rest, held, breaking away, sliding, reversing (random
    torques around the holding torque, some of them beyond the peak)."""
    from mrm_cosim.cosim.model_kernel import load_plant

    kern = load_plant()
    if kern is None:
        pytest.skip("numba cannot run here")
    robot = load_robot(robot_name)
    config = PlantConfig(friction=friction)
    ref, fast = Plant(robot, config, seed=3), Plant(robot, config, seed=3)
    fast.use_kernel(kern)
    rng = np.random.default_rng(0)
    for p in (ref, fast):
        p.reset(robot.home)
    for i in range(1500):
        scale = (0.0, 1.0, 30.0, 300.0)[(i // 100) % 4]
        tau = rng.normal(0.0, scale, robot.n) + (0.0 if i % 300 < 150 else 5.0)
        ref.step(tau)
        fast.step(tau)
        assert ref.q.tobytes() == fast.q.tobytes(), i
        assert ref.qd.tobytes() == fast.qd.tobytes(), i
        assert ref.tau_motor.tobytes() == fast.tau_motor.tobytes(), i
        assert ref.encoder_changes() == fast.encoder_changes(), i
    with pytest.raises(InputError):
        fast.step([float("nan")] * robot.n)
    fast.reset(robot.home)
    ref.reset(robot.home)
    ref.step(np.ones(robot.n))
    fast.step(np.ones(robot.n))
    assert ref.q.tobytes() == fast.q.tobytes()


@pytest.mark.parametrize("friction", [1.0, 0.0])
def test_pre_free_is_pre_then_free_force(friction):
    """:func:`models.plant_kernel_src.pre_free` (the model backend's fast path) leaves the
    state :func:`pre` and :func:`free_force` leave, bit for bit, and says which step follows:
    joints at rest, sliding both ways, commands beyond the peak, a command that is not
    finite."""
    from mrm_cosim.cosim.model_kernel import load_plant

    kern = load_plant()
    if kern is None:
        pytest.skip("numba cannot run here")
    rng = np.random.default_rng(5)
    n = 4
    for i in range(300):
        S = rng.normal(0.0, 1.0, (kern.S_ROWS, n))
        if i % 3 == 0:
            S[kern.V, rng.integers(n)] = 0.0            # a joint at rest
        C = np.abs(rng.normal(1.0, 0.5, (kern.C_ROWS, n)))
        C[kern.HAS_SPRING] = rng.integers(0, 2, n)
        cmd = rng.normal(0.0, 2.0, n)
        if i == 7:
            cmd[1] = float("inf")
        a, b = S.copy(), S.copy()
        code = kern.pre_free(a, C, cmd, 5e-6, friction)
        sliding = kern.pre(b, C, cmd, 5e-6)
        if sliding < 0:
            assert code == -1 and a.tobytes() == S.tobytes()
            continue
        if friction == 0.0 or sliding:
            kern.free_force(b, friction)
            assert code == 1
        else:
            assert code == 0
        assert a.tobytes() == b.tobytes(), i
