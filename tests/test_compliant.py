"""The compliant plant (models.compliant, models.gear) against independent references: the
catalogue's worked torsion-angle example, the two-inertia natural frequency, energy balance,
pinocchio's gravity for the static deflection, the rigid plant in the stiff limit, the
hysteresis (Dahl: loop width, loop area, passivity; the play option), seeded noise, and the
step bound's refusals."""

import math
from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest

from mrm_cosim.errors import InputError
from mrm_cosim.models.compliant import CompliantPlant, gear_truth
from mrm_cosim.models.gear import (
    ARCMIN, DAHL_SIGMA, GEARS, GearConfig, GearSpec, dahl, dahl_loop_area, gear_torque, play,
)
from mrm_cosim.models.plant import Plant, PlantConfig, make_plant, true_parameters
from mrm_cosim.models.robot import load_robot, robot_from_dict

QUIET = GearConfig(hysteresis=False, ripple=0.0, current_noise=0.0, stiffness_spread=0.0)


def _one_joint():
    """One Type I module about a vertical axis: no gravity torque on it."""
    return robot_from_dict({"name": "one", "modules": [{"type": "I"}]})


def _linear(plant, k, d=0.0, half=0.0):
    """The plant's gears made linear (K1 = K2 = K3 = k), with damping d and half-play."""
    g = plant.gears
    n = plant.n
    return replace(g, k1=np.full(n, k), k2=np.full(n, k), k3=np.full(n, k),
                   damping=np.full(n, d), half_play=np.full(n, half))


def test_catalogue_worked_example_of_the_torsion_angle():
    """Harmonic Drive's §4.2 example: 60 N·m on K1 = 6.7e4, K2 = 1.1e5, K3 = 1.2e5 with
    T1 = 29, T2 = 108 N·m gives 7.15e-4 rad (2.5 arcmin); the curve inverts it."""
    g = GearSpec(t1=29.0, t2=108.0, k1=6.7e4, k2=1.1e5, k3=1.2e5, hysteresis=0.0)
    phi = g.deflection(60.0)
    assert phi == pytest.approx(7.15e-4, abs=0.005e-4)
    assert phi / ARCMIN == pytest.approx(2.5, abs=0.05)
    for t in (-20.0, -0.3, 0.0, 1.0, 28.9, 29.0, 60.0, 107.0, 200.0):
        assert gear_torque(g.deflection(t), g.t1, g.t2, g.k1, g.k2, g.k3) == \
            pytest.approx(t, rel=1e-12, abs=1e-12)


def test_catalogue_values_of_the_size_14_gear():
    g = GEARS["FHA-14C-100"]
    assert (g.t1, g.t2, g.k1, g.k2, g.k3) == (2.0, 6.9, 4.7e3, 6.1e3, 7.1e3)
    assert g.hysteresis == pytest.approx(ARCMIN)


def test_hysteresis_loop_width_is_the_catalogue_loss():
    """Quasi-static loop between ± 2 T2: the unloading and loading branches cross zero torque
    a hysteresis loss apart."""
    g = GEARS["FHA-14C-100"]
    a = 0.5 * g.hysteresis
    top = g.deflection(2 * g.t2) + a
    path = np.concatenate([np.linspace(0, top, 4001), np.linspace(top, -top, 8001),
                           np.linspace(-top, top, 8001)])
    y = 0.0
    zeros = []
    prev = None
    for k, delta in enumerate(path):
        y = play(y, float(delta), a)
        t = gear_torque(y, g.t1, g.t2, g.k1, g.k2, g.k3)
        if k > 4001 and prev is not None and (prev > 0) != (t > 0) and t != 0.0:
            zeros.append(float(delta))
        prev = t
    down, up = zeros[0], zeros[-1]
    assert up - down == pytest.approx(g.hysteresis, rel=1e-3)


def _dahl_loop(g, fh, sigma, top, points=8001):
    """δ from 0 to ``top``, down to ``−top`` and up again; (δ, z, total torque) per point."""
    path = np.concatenate([np.linspace(0, top, points // 2 + 1),
                           np.linspace(top, -top, points), np.linspace(-top, top, points)])
    z, prev = 0.0, 0.0
    out = []
    for delta in path.tolist():
        z = dahl(z, delta - prev, fh, sigma)
        prev = delta
        out.append((delta, z, gear_torque(delta, g.t1, g.t2, g.k1, g.k2, g.k3) + z))
    return out


def test_dahl_loop_width_at_zero_torque_is_the_catalogue_loss():
    """The Dahl hysteresis with F_h = T(a), a quasi-static loop between ± 2 T2: the unloading
    and loading branches cross zero torque one hysteresis loss (2a) apart, for both gears and
    for a sharper and a softer corner; the torque never jumps (no play: the link is never
    disconnected, the tangent stiffness stays ≥ K1)."""
    for name in GEARS:
        g = GEARS[name]
        a = 0.5 * g.hysteresis
        fh = gear_torque(a, g.t1, g.t2, g.k1, g.k2, g.k3)
        assert fh == pytest.approx(g.k1 * a, rel=1e-12)          # a lies on the K1 segment
        for c in (DAHL_SIGMA, 5.0):
            top = g.deflection(2 * g.t2)
            loop = _dahl_loop(g, fh, c * g.k1, top)
            zeros = [d0 + (d1 - d0) * t0 / (t0 - t1)
                     for (d0, _, t0), (d1, _, t1) in zip(loop[4001:], loop[4002:], strict=False)
                     if (t0 > 0) != (t1 > 0)]
            down, up = zeros[0], zeros[-1]     # unloading at +a, loading at −a (friction leads)
            assert down - up == pytest.approx(g.hysteresis, rel=1e-3), (name, c)
            slopes = [(t1 - t0) / (d1 - d0) for (d0, _, t0), (d1, _, t1)
                      in zip(loop, loop[1:], strict=False) if d1 != d0]
            assert min(slopes) >= g.k1 * (1 - 1e-9)
            assert max(abs(z) for _, z, _ in loop) <= fh


def test_dahl_off_is_the_one_valued_curve():
    """No hysteresis: the Dahl torque stays 0 whatever the path, so the gear torque is the
    catalogue curve of the deflection, the same bits as ``gear_torque``."""
    g = GEARS["FHA-14C-100"]
    loop = _dahl_loop(g, 0.0, DAHL_SIGMA * g.k1, g.deflection(2 * g.t2), 2001)
    for delta, z, t in loop:
        assert z == 0.0
        assert t == gear_torque(delta, g.t1, g.t2, g.k1, g.k2, g.k3)
    gt = gear_truth(true_parameters(load_robot("mrm3"), PlantConfig(), 0),
                    PlantConfig(joints="compliant", gear=GearConfig(hysteresis=False)), 0)
    assert not gt.hyst_torque.any() and not gt.half_play.any()


def test_dahl_energy_per_cycle_is_the_loop_area():
    """Cycled between ± A until periodic, the Dahl element's ∮ z dδ (the energy it dissipates
    per cycle, the area of the torque–deflection loop) equals the closed form
    ``models.gear.dahl_loop_area``, at amplitudes inside and well beyond the corner."""
    g = GEARS["FHA-14C-100"]
    fh, sigma = g.k1 * 0.5 * g.hysteresis, DAHL_SIGMA * g.k1
    for amp in (0.2 * g.hysteresis, g.hysteresis, 10 * g.hysteresis):
        z, prev = 0.0, 0.0
        t = np.linspace(0.0, 4.0, 40001)
        path = amp * np.sin(2 * np.pi * t)
        work = 0.0
        for k, delta in enumerate(path.tolist()):
            z_new = dahl(z, delta - prev, fh, sigma)
            if k >= 30000:                                   # the fourth cycle
                work += 0.5 * (z + z_new) * (delta - prev)
            z, prev = z_new, delta
        assert work == pytest.approx(dahl_loop_area(amp, fh, sigma), rel=1e-3), amp   # trapezoid
    # large amplitude: the loop is the two branches T ± F_h, area → 2 F_h · 2A
    assert dahl_loop_area(1.0, fh, sigma) == pytest.approx(4 * fh * 1.0, rel=1e-3)


def _elastic(t1, t2, k1, k2, k3):
    phi1 = t1 / k1
    phi2 = phi1 + (t2 - t1) / k2

    def energy(y):
        x = abs(y)
        if x <= phi1:
            return 0.5 * k1 * x * x
        e = 0.5 * k1 * phi1 * phi1
        if x <= phi2:
            return e + t1 * (x - phi1) + 0.5 * k2 * (x - phi1) ** 2
        e += t1 * (phi2 - phi1) + 0.5 * k2 * (phi2 - phi1) ** 2
        return e + t2 * (x - phi2) + 0.5 * k3 * (x - phi2) ** 2
    return energy


def test_dahl_gear_is_passive_and_dissipates_what_it_should():
    """One joint swinging on its gear, no friction, no damping, Dahl hysteresis on: the stored
    energy (both kinetic, the curve's elastic energy, the Dahl storage z²/2σ) never grows
    (passivity: no energy created) and what it loses is the dissipation ∫ z²/F_h |dδ| summed
    along the plant's own path (to 2 %): the swing decays through the hysteresis alone."""
    robot = _one_joint()
    gear = replace(QUIET, hysteresis="dahl")
    base = CompliantPlant(robot, PlantConfig(joints="compliant", friction=False, gear=gear))
    gears = replace(base.gears, damping=np.zeros(1))
    plant = CompliantPlant(robot, PlantConfig(joints="compliant", friction=False,
                                              current_loop=False, gear=gear), gears=gears)
    J = pin.crba(plant._model, plant._model.createData(), np.zeros(1))[0, 0]
    B = gears.motor_inertia[0]
    elastic = _elastic(gears.t1[0], gears.t2[0], gears.k1[0], gears.k2[0], gears.k3[0])
    fh, sigma = gears.hyst_torque[0], gears.hyst_sigma[0]
    assert fh > 0 and sigma > 0

    def energy():
        return 0.5 * B * plant.theta_d[0] ** 2 + 0.5 * J * plant.qd[0] ** 2 + \
            elastic(plant.theta[0] - plant.q[0]) + plant._z[0] ** 2 / (2 * sigma)

    plant.reset([0.0], theta0=[4.0 * plant.gears.half_play[0] + 6 * ARCMIN])
    e0 = energy()
    top = e0
    lost = 0.0
    y, z = plant._y[0], plant._z[0]
    for _ in range(20000):
        plant.step([0.0])
        e = energy()
        assert e <= top + 1e-6 * e0
        top = min(top, e)
        lost += 0.5 * (z * z + plant._z[0] ** 2) / fh * abs(plant._y[0] - y)
        y, z = plant._y[0], plant._z[0]
    assert e < 0.5 * e0                                   # it decays, through hysteresis only
    assert e0 - e == pytest.approx(lost, rel=0.02)


def test_natural_frequency_is_the_two_inertia_formula():
    robot = _one_joint()
    plant = CompliantPlant(robot, PlantConfig(joints="compliant", friction=False,
                                              gear=QUIET))
    k = 5000.0
    plant = CompliantPlant(robot, PlantConfig(joints="compliant", friction=False, gear=QUIET),
                           gears=_linear(plant, k))
    model = plant._model
    J = pin.crba(model, model.createData(), np.zeros(1))[0, 0]
    B = plant.gears.motor_inertia[0]
    f = math.sqrt(k * (1 / B + 1 / J)) / (2 * math.pi)
    plant.reset([0.0], theta0=[1e-4])
    crossings = []
    prev = 1e-4
    for s in range(20000):
        plant.step([0.0])
        d = plant.theta[0] - plant.q[0]
        if prev > 0 >= d or prev < 0 <= d:
            crossings.append((s - 1 + prev / (prev - d)) * plant.dt)   # interpolated
        prev = d
    period = 2 * (crossings[-1] - crossings[0]) / (len(crossings) - 1)
    assert 1 / period == pytest.approx(f, rel=1e-5)     # measured: 1.3e-6
    assert len(crossings) > 10


def test_energy_is_conserved_without_damping_or_friction():
    """The piecewise curve's elastic energy plus both kinetic energies, over 0.1 s of a swing
    across all three segments: drifts by less than 1e-4 of itself."""
    robot = _one_joint()
    base = CompliantPlant(robot, PlantConfig(joints="compliant", friction=False, gear=QUIET))
    gears = replace(base.gears, damping=np.zeros(1))
    plant = CompliantPlant(robot, PlantConfig(joints="compliant", friction=False,
                                              current_loop=False, gear=QUIET), gears=gears)
    g = GEARS[base._truth.actuators[0].name]
    J = pin.crba(plant._model, plant._model.createData(), np.zeros(1))[0, 0]
    B = gears.motor_inertia[0]
    elastic = _elastic(gears.t1[0], gears.t2[0], gears.k1[0], gears.k2[0], gears.k3[0])

    def energy():
        return 0.5 * B * plant.theta_d[0] ** 2 + 0.5 * J * plant.qd[0] ** 2 + \
            elastic(plant.theta[0] - plant.q[0])

    plant.reset([0.0], theta0=[2.0 * g.deflection(g.t2)])
    e0 = energy()
    worst = 0.0
    for _ in range(10000):
        plant.step([0.0])
        worst = max(worst, abs(energy() - e0))
    assert worst < 1e-4 * e0


def test_static_deflection_under_gravity_follows_the_curve():
    """mrm3 reset at a pose: the gears carry gravity's torque (pinocchio) at the catalogue
    formula's deflection, and held there by the motors nothing moves; with the motors a tenth
    of that deflection back, the links move."""
    robot = load_robot("mrm3")
    cfg = PlantConfig(joints="compliant", friction=False, springs=False, perturbation=0.0,
                      gear=QUIET)
    plant = CompliantPlant(robot, cfg)
    q0 = np.asarray(robot.home, dtype=float) + np.array([0.0, 0.4, -0.6])
    g = pin.computeGeneralizedGravity(plant._model, plant._model.createData(), q0)
    specs = [GEARS[a.name] for a in plant._truth.actuators]
    phi = np.array([s.deflection(t) for s, t in zip(specs, g, strict=True)])
    assert abs(g[1]) > GEARS["FHA-14C-100"].t2      # joint 2 in the K3 segment
    for back, still in ((0.0, True), (0.1, False)):
        plant.reset(q0, tau_motor0=g, theta0=q0 - back * phi)
        np.testing.assert_allclose(plant.preload, phi, rtol=1e-12)
        for _ in range(2000):
            plant.step(g)
        moved = np.abs(plant.q - q0).max()
        assert (moved < 1e-9) == still, moved


@pytest.mark.parametrize("hysteresis", ["off", "dahl"])
def test_stiff_gears_approach_the_rigid_plant(hysteresis):
    """Gears 30× stiffer, well damped: the link follows the rigid plant (pinocchio with
    the rotor as armature) to within a fraction of the motion; with the Dahl hysteresis too
    (its F_h = T(a) grows with the stiffness, the loop's width stays the catalogue's)."""
    robot = load_robot("mrm3")
    gear = replace(QUIET, stiffness_scale=30.0, damping_ratio=0.3, hysteresis=hysteresis)
    common = dict(friction=False, springs=True, perturbation=0.0)
    rigid = Plant(robot, PlantConfig(**common))
    soft = CompliantPlant(robot, PlantConfig(joints="compliant", gear=gear, **common))
    rigid.reset(robot.home)
    soft.reset(robot.home)
    tau = np.array([2.0, -1.0, 0.5])
    for _ in range(5000):
        rigid.step(tau)
        soft.step(tau)
    motion = np.abs(rigid.q - np.asarray(robot.home)).max()
    assert motion > 1e-2
    assert np.abs(soft.q - rigid.q).max() < 0.01 * motion


def test_encoder_counts_the_motor():
    robot = load_robot("mrm3")
    plant = make_plant(robot, PlantConfig(joints="compliant"), seed=1)
    assert isinstance(plant, CompliantPlant)
    for _ in range(300):
        plant.step([0.0, 0.0, 0.0])
    k = plant.counts_per_rad
    np.testing.assert_array_equal(plant.encoder_counts(), np.floor(plant.theta * k))
    assert not np.array_equal(plant.encoder_counts(), np.floor(plant.q * k))
    assert plant.encoder_cycles().counts[-1].tolist() == plant.encoder_counts().tolist()


def test_noise_and_ripple_are_seeded_and_reproducible():
    robot = load_robot("mrm3")
    cfg = PlantConfig(joints="compliant")

    def run(seed, reset_twice=False):
        p = CompliantPlant(robot, cfg, seed)
        p.reset(robot.home)
        if reset_twice:
            for _ in range(50):
                p.step([1.0, 2.0, 0.5])
            p.reset(robot.home)
        for _ in range(200):
            p.step([1.0, 2.0, 0.5])
        return np.concatenate([p.q, p.theta, p.tau_motor])

    a = run(4)
    assert run(4).tobytes() == a.tobytes()
    assert run(4, reset_twice=True).tobytes() == a.tobytes()
    assert run(5).tobytes() != a.tobytes()
    quiet = replace(cfg, gear=replace(cfg.gear, current_noise=0.0))
    p = CompliantPlant(robot, quiet, 4)
    p.reset(robot.home)
    for _ in range(200):
        p.step([1.0, 2.0, 0.5])
    assert not np.array_equal(p.tau_motor, a[6:])


def test_rigid_draws_do_not_move_when_the_gear_is_added():
    """The gear's draws are their own seed streams: the true rigid parameters are the same."""
    robot = load_robot("mrm3")
    a = true_parameters(robot, PlantConfig(), 7)
    b = CompliantPlant(robot, PlantConfig(joints="compliant"), 7)._truth
    np.testing.assert_array_equal(a.rotor_inertia, b.rotor_inertia)
    np.testing.assert_array_equal(a.friction.coulomb, b.friction.coulomb)
    t = gear_truth(a, PlantConfig(joints="compliant", gear=GearConfig(stiffness_scale=2.0)), 7)
    t1 = gear_truth(a, PlantConfig(joints="compliant"), 7)
    np.testing.assert_allclose(t.k1, 2.0 * t1.k1, rtol=1e-15)


@pytest.mark.parametrize("changes, field", [
    (dict(stiffness_scale=0.0), "plant.gear.stiffness_scale"),
    (dict(stiffness_scale=-1.0), "plant.gear.stiffness_scale"),
    (dict(damping_ratio=0.0), "plant.gear.damping_ratio"),
    (dict(damping_ratio=-0.1), "plant.gear.damping_ratio"),
    (dict(hysteresis_stiffness=0.0), "plant.gear.hysteresis_stiffness"),
    (dict(hysteresis_stiffness=-1.0), "plant.gear.hysteresis_stiffness"),
    (dict(hysteresis="backlash"), "plant.gear.hysteresis"),
    (dict(hysteresis=1), "plant.gear.hysteresis"),
])
def test_zero_or_negative_gear_is_refused(changes, field):
    with pytest.raises(InputError) as e:
        GearConfig(**changes)
    assert e.value.field == field


@pytest.mark.parametrize("changes, field", [
    (dict(stiffness_scale=1e7), "plant.gear.stiffness_scale"),
    (dict(damping_ratio=200.0), "plant.gear.damping_ratio"),
    (dict(hysteresis_stiffness=1e7), "plant.gear.hysteresis_stiffness"),
])
def test_gear_unstable_at_the_step_is_refused_with_the_largest_step(changes, field):
    robot = load_robot("mrm3")
    with pytest.raises(InputError) as e:
        CompliantPlant(robot, PlantConfig(joints="compliant", gear=GearConfig(**changes)))
    assert e.value.field == field
    assert "largest step it allows is" in e.value.message
    allowed = float(e.value.message.split("allows is ")[1].split(" s")[0])
    assert allowed < 1e-5
    # that step is accepted
    ok = CompliantPlant(robot, PlantConfig(joints="compliant", dt=2e-8 * max(1, int(
        allowed / 2e-8)), gear=GearConfig(**changes)))
    assert ok.dt <= allowed


def test_rigid_is_the_default_and_unknown_joints_are_refused():
    assert PlantConfig().joints == "rigid"
    assert type(make_plant(load_robot("mrm3"))) is Plant
    with pytest.raises(InputError) as e:
        PlantConfig(joints="soft")
    assert e.value.field == "plant.joints"


@pytest.mark.parametrize("hysteresis", ["dahl", "play", "off"])
def test_compiled_step_equals_the_python_step_bit_for_bit(hysteresis):
    """models.compliant_kernel_src against CompliantPlant.step: stiction, reversals, the
    hysteresis (Dahl, the play option, none), noise and ripple, a reset in between; every state
    row equal to the bit."""
    from mrm_cosim.cosim.model_kernel import load
    from mrm_cosim.models.compliant import compiled_kernel

    if load() is None or compiled_kernel() is None:
        pytest.skip("numba unavailable")
    robot = load_robot("mrm3")
    cfg = PlantConfig(joints="compliant", gear=GearConfig(hysteresis=hysteresis))
    py = CompliantPlant(robot, cfg, 2)
    nb = CompliantPlant(robot, cfg, 2)
    nb.use_kernel(None)
    assert nb._kern is not None
    rng = np.random.default_rng(0)
    for _rep in range(2):
        py.reset(robot.home)
        nb.reset(robot.home)
        for s in range(1500):
            tau = 3.0 * np.sin(np.array([1.0, 2.0, 3.0]) * s * 2e-3) + rng.normal(0, 0.3, 3)
            if s % 400 < 60:
                tau[:] = 0.0
            py.step(tau)
            nb.step(tau)
        for name in ("_q", "_v", "_a_prev", "_th", "_w", "_am_prev", "_y", "_z", "_tau", "_tau_j",
                     "_q_start", "_th_start"):
            assert np.asarray(getattr(py, name)).tobytes() == \
                np.asarray(getattr(nb, name)).tobytes(), name
        assert [np.asarray(x).tobytes() for x in py.motion()] == \
            [np.asarray(x).tobytes() for x in nb.motion()]
    with pytest.raises(InputError):
        nb.step([np.nan, 0.0, 0.0])
