"""The joints' holding brakes (models.brake) in both plants: hold, slip, timing, kernel."""

import numpy as np
import pinocchio as pin
import pytest

from mrm_cosim.errors import InputError
from mrm_cosim.models.actuators import ACTUATORS
from mrm_cosim.models.brake import HOLDING_OVER_PEAK, BrakeConfig
from mrm_cosim.models.compliant import CompliantPlant
from mrm_cosim.models.plant import Plant, PlantConfig
from mrm_cosim.models.robot import load_robot

FAST = BrakeConfig(engage_time=1e-5, release_time=1e-5)


def gravity(plant, q) -> np.ndarray:
    """Gravity torque at ``q`` by pinocchio, on the plant's true bodies, less the springs."""
    tr = plant._truth
    g = pin.computeGeneralizedGravity(tr.model, tr.model.createData(), np.asarray(q, float))
    return g - tr.spring_torque * np.cos(q + tr.spring_phase)


def posture():
    """mrm3 stretched out horizontally: the largest gravity torque on joints 2 and 3."""
    return np.array([0.0, 0.0, 0.0])


@pytest.mark.parametrize("friction", [False, True])
def test_engaged_brake_holds_the_arm_under_gravity(friction):
    """No motor torque, brakes engaged: not one bit of motion over 0.2 s where pinocchio's
    gravity torque is below the holding torque (it is, at the default sizing)."""
    robot = load_robot("mrm3")
    plant = Plant(robot, PlantConfig(friction=friction, brake=FAST), seed=1)
    q0 = posture()
    plant.reset(q0)
    hold = np.array(plant._brake_hold)
    assert np.all(np.abs(gravity(plant, q0)) < hold)
    plant.set_brake([True] * 3)
    plant.step(np.zeros(3))                 # the command acts from the next step: one free
    plant.step(np.zeros(3))                 # step, then the brake stops the joints
    assert np.all(plant.qd == 0.0)
    q_held = plant.q
    assert np.abs(q_held - q0).max() < 1e-7
    for _ in range(20_000):
        plant.step(np.zeros(3))
    assert plant.q.tobytes() == q_held.tobytes()
    assert np.all(plant.qd == 0.0)


def test_released_arm_falls_and_the_brake_stops_it():
    """Without the brake the arm falls; engaged while it falls, the brake slips (kinetic
    torque) and stops it, then holds."""
    robot = load_robot("mrm3")
    plant = Plant(robot, PlantConfig(friction=False, brake=FAST), seed=1)
    plant.reset(posture())
    for _ in range(2_000):                  # 20 ms of free fall
        plant.step(np.zeros(3))
    moving = plant.qd
    assert np.abs(moving[1:]).max() > 0.05
    plant.set_brake([True] * 3)
    for _ in range(5_000):
        plant.step(np.zeros(3))
    q_held = plant.q
    for _ in range(5_000):
        plant.step(np.zeros(3))
    assert np.all(plant.qd == 0.0)
    assert plant.q.tobytes() == q_held.tobytes()


@pytest.mark.parametrize("compliant", [False, True])
def test_brake_slips_above_its_holding_torque(compliant):
    """A joint whose load exceeds the holding torque slips: a holding torque below the most
    loaded joint's gravity torque lets it fall, decelerated by the kinetic torque; the joints
    whose gravity torque is below it stay."""
    robot = load_robot("mrm3")
    cfg0 = PlantConfig(friction=False, joints="compliant" if compliant else "rigid")
    plant = (CompliantPlant if compliant else Plant)(robot, cfg0, seed=1)
    g = np.abs(gravity(plant, posture()))
    j = int(np.argmax(g))                   # the most loaded joint
    ratio = ACTUATORS[robot.modules[j].type.actuator].gear_ratio
    motor = 0.5 * g[j] / ratio              # half of its load, at the motor
    held = [i for i in range(3) if g[i] < 0.9 * motor * ratio]
    assert held
    cfg = PlantConfig(friction=False, brake=BrakeConfig(holding_torque=motor, slip_ratio=0.8,
                                                        engage_time=1e-5, release_time=1e-5),
                      joints=cfg0.joints)
    plant = (CompliantPlant if compliant else Plant)(robot, cfg, seed=1)
    plant.reset(posture())
    plant.set_brake([True] * 3)
    plant.step(np.zeros(3))
    free = (CompliantPlant if compliant else Plant)(robot, cfg, seed=1)
    free.reset(posture())
    free.step(np.zeros(3))
    for _ in range(3_000):
        plant.step(np.zeros(3))
        free.step(np.zeros(3))
    dq = plant.q - posture()
    dq_free = free.q - posture()
    assert abs(dq[j]) > 1e-3                               # the loaded joint slips …
    assert abs(dq[j]) < 0.8 * abs(dq_free[j])              # … slower than falling freely
    if not compliant:                                       # (compliant: the link still
        assert np.abs(dq[held]).max() < 1e-9                # swings on its gear)


def test_engage_and_release_times():
    """The torque acts exactly ``engage_time`` after the command (whole steps) and stops
    ``release_time`` after the release; a command taken back in time does nothing."""
    robot = load_robot("mrm3")
    cfg = PlantConfig(brake=BrakeConfig(engage_time=0.015, release_time=0.025))
    plant = Plant(robot, cfg, seed=0)
    dt = plant.dt
    assert cfg.brake.steps(dt) == (1500, 2500)
    plant.set_brake([False, True, False])
    for k in range(1500):
        assert not plant.brake_engaged.any(), k
        plant.step(np.zeros(3))
    assert plant.brake_engaged.tolist() == [False, True, False]
    assert not plant.brake_idle
    plant.set_brake([False] * 3)
    for k in range(2500):
        assert plant.brake_engaged[1], k
        plant.step(np.zeros(3))
    assert not plant.brake_engaged.any() and plant.brake_idle
    plant.set_brake([True] * 3)
    for _ in range(100):
        plant.step(np.zeros(3))
    plant.set_brake([False] * 3)            # taken back before it acted
    for _ in range(2000):
        plant.step(np.zeros(3))
        assert not plant.brake_engaged.any()
    assert plant.brake_idle


def test_default_holding_torque_is_derived_from_the_actuators():
    robot = load_robot("mrm3")
    plant = Plant(robot, PlantConfig(), seed=0)
    for k, m in enumerate(robot.modules):
        a = ACTUATORS[m.type.actuator]
        assert plant._brake_hold[k] == pytest.approx(HOLDING_OVER_PEAK * a.peak_torque)


@pytest.mark.parametrize("field,value", [("holding_torque", -1.0), ("holding_torque", True),
                                         ("slip_ratio", 0.0), ("slip_ratio", 1.5),
                                         ("engage_time", -0.1), ("release_time", float("nan"))])
def test_bad_brake_settings_are_refused_naming_the_field(field, value):
    with pytest.raises(InputError) as e:
        BrakeConfig(**{field: value})
    assert e.value.field == f"plant.brake.{field}"


def test_bad_brake_command_is_refused():
    plant = Plant(load_robot("mrm3"), PlantConfig(), seed=0)
    with pytest.raises(InputError) as e:
        plant.set_brake([True, False])
    assert e.value.field == "brake"


@pytest.mark.parametrize("compliant", [False, True])
@pytest.mark.parametrize("friction", [False, True])
def test_compiled_step_with_brakes_equals_the_python_step(compliant, friction):
    """The compiled plant steps (models.plant_kernel_src, models.compliant_kernel_src) with
    brakes engaging, holding, slipping and releasing: every state row equal to the bit."""
    from mrm_cosim.cosim.model_kernel import load_plant
    from mrm_cosim.models.compliant import compiled_kernel

    kern = load_plant()
    if kern is None or (compliant and compiled_kernel() is None):
        pytest.skip("numba cannot run here")
    robot = load_robot("mrm3")
    cfg = PlantConfig(friction=friction, joints="compliant" if compliant else "rigid",
                      brake=BrakeConfig(engage_time=2e-3, release_time=3e-3))
    cls = CompliantPlant if compliant else Plant
    py, nb = cls(robot, cfg, seed=2), cls(robot, cfg, seed=2)
    nb.use_kernel(kern)
    rng = np.random.default_rng(0)
    for p in (py, nb):
        p.reset(posture())
    for s in range(3000):
        if s % 500 == 0:
            mask = rng.random(3) < 0.6
            py.set_brake(mask)
            nb.set_brake(mask)
        tau = rng.normal(0.0, (1.0, 10.0, 40.0)[(s // 250) % 3], 3)
        py.step(tau)
        nb.step(tau)
        assert py.q.tobytes() == nb.q.tobytes(), s
        assert py.qd.tobytes() == nb.qd.tobytes(), s
    assert py.brake_engaged.tolist() == nb.brake_engaged.tolist()
