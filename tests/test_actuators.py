"""Actuator data: MRM Table 1 values, datasheet consistency, sources for every number."""

import dataclasses
import math

import pytest

from mrm_cosim.models.actuators import ACTUATORS, RPM, ActuatorSpec
from mrm_cosim.models.encoder import CYCLE
from mrm_cosim.models.robot import load_robot

# MRM paper Table 1 (seeds/003_*.txt), typed in independently of models/actuators.py.
TABLE1 = {
    "FHA-11C-100": dict(peak_torque=11.0, continuous_torque=4.2, encoder_lines=2000,
                        gear_ratio=100),
    "FHA-14C-100": dict(peak_torque=28.0, continuous_torque=6.8, encoder_lines=2000,
                        gear_ratio=100),
}


@pytest.mark.parametrize("name", sorted(TABLE1))
def test_table1_values(name):
    spec = ACTUATORS[name]
    for key, value in TABLE1[name].items():
        assert getattr(spec, key) == value, key


@pytest.mark.parametrize("name", sorted(ACTUATORS))
def test_every_value_has_a_source(name):
    spec = ACTUATORS[name]
    numeric = [f.name for f in dataclasses.fields(ActuatorSpec)
               if f.name not in ("name", "sources")]
    for key in numeric:
        assert spec.sources.get(key), f"{name}.{key} has no source"
    for key in ("coulomb_friction", "static_friction", "stribeck_velocity", "viscous_friction",
                "current_bandwidth"):
        assert "assumption" in spec.sources[key]


def test_counts_per_rev_matches_the_papers_example():
    # 2000 lines × 4 × 100 = 800,000 counts/rev; the paper: 0.1571 rad ↔ 20,000 counts.
    for spec in ACTUATORS.values():
        assert spec.counts_per_rev == 800_000
        assert 20_000 * 2.0 * math.pi / spec.counts_per_rev == pytest.approx(0.1571, abs=5e-5)


@pytest.mark.parametrize("name", sorted(ACTUATORS))
def test_datasheet_is_self_consistent(name):
    spec = ACTUATORS[name]
    # the motor current limit can deliver the peak torque; continuous ≤ peak
    assert spec.torque_constant * spec.max_current >= spec.peak_torque
    assert spec.continuous_torque < spec.peak_torque
    assert spec.static_friction >= spec.coulomb_friction > 0.0
    # friction well below what the drive can deliver continuously
    assert spec.static_friction < 0.5 * spec.continuous_torque
    # reflected inertia is the motor-side inertia times N²
    assert spec.rotor_inertia * spec.gear_ratio**2 == pytest.approx(spec.output_inertia)
    # 58 r/min maximum output speed
    assert spec.max_speed == pytest.approx(58.0 * 2.0 * math.pi / 60.0)
    assert RPM == pytest.approx(2.0 * math.pi / 60.0)
    # back-EMF at maximum speed stays under the 200 VAC supply's ~280 V DC bus
    assert spec.emf_constant * spec.max_speed < 280.0
    # current loop faster than the open-loop L/R of the winding
    assert spec.current_time_constant < spec.electrical_time_constant


@pytest.mark.parametrize("name", sorted(ACTUATORS))
def test_encoder_rate_at_max_speed_fits_50_mhz(name):
    spec = ACTUATORS[name]
    rate = spec.max_count_rate                      # counts/s at max speed
    assert rate == pytest.approx(58.0 / 60.0 * 800_000)
    cycles_per_count = 1.0 / (rate * CYCLE)
    assert cycles_per_count > 60.0                  # ≈ 64.7 FPGA cycles between counts
    assert rate < 1.0 / CYCLE


def test_rejects_inconsistent_spec():
    spec = ACTUATORS["FHA-11C-100"]
    with pytest.raises(ValueError, match="static_friction"):
        dataclasses.replace(spec, static_friction=0.1)
    with pytest.raises(ValueError, match="peak_torque"):
        dataclasses.replace(spec, peak_torque=float("nan"))
    with pytest.raises(ValueError, match="viscous_friction"):
        dataclasses.replace(spec, viscous_friction=-1.0)


@pytest.mark.parametrize("robot_name", ["mrm3", "mrm6"])
def test_robot_modules_use_known_actuators(robot_name):
    robot = load_robot(robot_name)
    for module in robot.modules:
        spec = ACTUATORS[module.type.actuator]
        assert spec.peak_torque == module.type.peak_torque
        assert spec.continuous_torque == module.type.continuous_torque
        assert spec.counts_per_rev == module.type.counts_per_rev
