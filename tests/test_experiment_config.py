"""Experiment TOML: defaults, exact round trip, and every bad value named by its field."""

import math
import shutil
from dataclasses import replace
from pathlib import Path

import pytest

import mrm_cosim.mrm.cli as cli
from mrm_cosim.cosim import experiment_config as ec
from mrm_cosim.errors import InputError
from mrm_cosim.master.cycle import MasterTiming
from mrm_cosim.master.uploads import Gains
from mrm_cosim.models.plant import Perturbation, PlantConfig

ROBOTS = Path(__file__).resolve().parents[1] / "models" / "robots"


def test_default_file_is_the_paper_experiment_on_the_code_defaults():
    cfg = ec.load()
    assert cfg.controllers == ("pid-1khz", "pid-fpga", "vdc")
    assert cfg.robot == "mrm3"
    assert cfg.trajectory.amplitude == 0.1571 and cfg.trajectory.duration == 1.0
    assert cfg.duration == pytest.approx(cfg.trajectory.duration + cfg.trajectory.hold)
    assert cfg.timing == MasterTiming()
    assert cfg.plant.dt == PlantConfig().dt


def test_empty_file_gives_the_dataclass_defaults():
    cfg = ec.loads("")
    assert cfg.gains == Gains()
    assert cfg.timing == MasterTiming()
    assert cfg.plant == PlantConfig()
    assert cfg.duration == pytest.approx(1.2)


@pytest.mark.parametrize("changes", [
    {},
    {"gains": replace(Gains(), lam=37.5, k_j=12.25, K=100.0, adapt=0.01, pid_fpga_hz=12.0)},
    {"plant": PlantConfig(perturbation=Perturbation(0.2, 0.05, 0.3, 0.0), friction=False,
                          current_bandwidth=700.0)},
    {"timing": MasterTiming(50_000, 2_500, 1_750), "seed": 123456789, "duration": 0.0123},
    {"controllers": ("vdc",), "name": 'a "quoted" name\\'},
])
def test_resolved_toml_loads_back_equal(changes):
    cfg = replace(ec.loads(""), **changes)
    text = cfg.to_toml()
    assert ec.loads(text) == cfg
    assert ec.loads(text).to_toml() == text


def test_floats_survive_the_round_trip_bit_for_bit():
    lam = math.nextafter(50.0, 60.0)
    cfg = replace(ec.loads(""), gains=replace(Gains(), lam=lam))
    assert ec.loads(cfg.to_toml()).gains.lam == lam


@pytest.mark.parametrize("text, field", [
    ("speed = 3", "speed"),
    ("[experiment]\nrobots = 'mrm3'", "experiment.robots"),
    ("[trajectory]\nq0 = 0.0", "trajectory.q0"),
    ("[plant]\nmass = 1.0", "plant.mass"),
    ("[plant.perturbation]\nlink = 0.1", "plant.perturbation.link"),
    ("[gains]\nkp = 1.0", "gains.kp"),
    ("[timing]\nperiod = 50000", "timing.period"),
])
def test_unknown_keys_are_rejected_by_name(text, field):
    with pytest.raises(InputError) as exc:
        ec.loads(text)
    assert exc.value.field == field


@pytest.mark.parametrize("text, field", [
    ("experiment = 3", "experiment"),
    ("[experiment]\nrobot = 'mrm9'", "experiment.robot"),
    ("[experiment]\ncontrollers = ['vdc', 'lqr']", "experiment.controllers[1]"),
    ("[experiment]\ncontrollers = []", "experiment.controllers"),
    ("[experiment]\ncontrollers = ['vdc', 'vdc']", "experiment.controllers"),
    ("[experiment]\nbackend = 'fpga'", "experiment.backend"),
    ("[experiment]\nseed = -1", "experiment.seed"),
    ("[experiment]\nseed = 1.5", "experiment.seed"),
    ("[experiment]\nduration = 0", "experiment.duration"),
    ("[experiment]\nduration = 61.0", "experiment.duration"),
    ("[experiment]\nduration = nan", "experiment.duration"),
    ("[trajectory]\namplitude = 0.0", "trajectory.amplitude"),
    ("[trajectory]\nduration = -1.0", "trajectory.duration"),
    ("[trajectory]\nhold = -0.1", "trajectory.hold"),
    ("[plant]\ndt = 1.5e-8", "plant.dt"),
    ("[plant]\nfriction = 1", "plant.friction"),
    ("[plant]\ncurrent_bandwidth = 0.0", "plant.current_bandwidth"),
    # an amplifier that cannot follow the motion made the three controllers equal
    ("[plant]\ncurrent_bandwidth = 1e-9", "plant.current_bandwidth"),
    ("[plant]\ncurrent_bandwidth = 99.0", "plant.current_bandwidth"),
    # half a period: nothing moved, and the table still looked clean
    ("[experiment]\nduration = 0.0005", "experiment.duration"),
    # a plant step of a whole period failed at run time as 'start_cycle'
    ("[plant]\ndt = 1e-3", "plant.dt"),
    ("[plant]\nperturbation = 0.9", "plant.perturbation"),
    ("[plant.perturbation]\nlinks = 0.6", "plant.perturbation.links"),
    ("[plant.perturbation]\nfriction = 'lots'", "plant.perturbation.friction"),
    ("[gains]\nlam = -5.0", "gains.lam"),
    ("[gains]\nk_j = inf", "gains.k_j"),
    ("[gains]\npid_1khz_hz = 0", "gains.pid_1khz_hz"),
    ("[gains]\npid_fpga_hz = 250.0", "gains.pid_fpga_hz"),      # above the nodes' PID design
    ("[gains]\nlam = 1000.0", "gains.lam"),                     # fits no LAMC word
    ("[gains]\nadapt = 100.0", "gains.adapt"),
    ("[gains]\nK = 4000.0", "gains.K"),
    ("[timing]\nforce_cycles = 0", "timing.force_cycles"),
    ("[timing]\nperiod_cycles = 50001", "timing.period_cycles"),
    ("[timing]\nkinematics_cycles = 30000\nforce_cycles = 20000", "timing.kinematics_cycles"),
    # rho·T of a 2 ms period is past the RHOT word (fits at 1 ms): checked for the period run
    ("[timing]\nperiod_cycles = 100000\n[gains]\nadapt = 1.0", "gains.adapt"),
    # a period that is not a whole number of plant steps (1,500 and 1,000 cycles)
    ("[plant]\ndt = 3e-5", "plant.dt"),
    ("[plant]\ndt = 2e-5\n[timing]\nperiod_cycles = 25500", "plant.dt"),
    # the nodes' sync window (2,500 cycles) must lie inside the period
    ("[timing]\nperiod_cycles = 2500\nkinematics_cycles = 1\nforce_cycles = 1",
     "timing.period_cycles"),
    ("[gains\nlam = 1", "config"),
    ('[experiment]\nname = "run\\u001b[2J"', "experiment.name"),   # would clear the terminal
    ('[experiment]\nname = "two\\nlines"', "experiment.name"),
])
def test_bad_values_name_their_field(text, field):
    with pytest.raises(InputError) as exc:
        ec.loads(text)
    assert exc.value.field == field


@pytest.mark.parametrize("text, field", [
    ('[experiment]\nduration = "0.5"\n', "experiment.duration"),
    ('[trajectory]\namplitude = "0.1"\n', "trajectory.amplitude"),
    ('[trajectory]\nhold = "0.5"\n', "trajectory.hold"),
    ('[plant]\ndt = "1e-5"\n', "plant.dt"),
    ('[plant]\nperturbation = "0.1"\n', "plant.perturbation"),
    ('[plant.perturbation]\nlinks = "0.1"\n', "plant.perturbation.links"),
    ('[plant]\ncurrent_bandwidth = "500"\n', "plant.current_bandwidth"),
    ('[gains]\nK = "100"\n', "gains.K"),
])
def test_numbers_written_as_strings_are_refused(text, field):
    """``duration = "0.5"`` (a quoted number) was silently read as 0.5 (float() takes the
    string), hiding a quoting mistake; it is refused naming the field."""
    with pytest.raises(InputError) as exc:
        ec.loads(text)
    assert exc.value.field == field and "string" in exc.value.message


def test_relative_robot_path_is_taken_from_the_config_folder(tmp_path):
    shutil.copy(ROBOTS / "mrm3.toml", tmp_path / "arm.toml")
    (tmp_path / "exp.toml").write_text("[experiment]\nrobot = 'arm.toml'\n")
    cfg = ec.load(tmp_path / "exp.toml")
    assert cfg.robot == str((tmp_path / "arm.toml").resolve())
    assert ec.loads(cfg.to_toml()) == cfg


def test_overrides_are_validated_under_the_flag_name():
    cfg = ec.loads("")
    assert cfg.with_overrides(seed=7, duration=0.5).seed == 7
    for kw, field in [({"seed": -2}, "seed"), ({"duration": -1.0}, "duration"),
                      ({"backend": "nope"}, "backend")]:
        with pytest.raises(InputError) as exc:
            cfg.with_overrides(**kw)
        assert exc.value.field == field


def test_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError) as exc:
        ec.load(tmp_path / "none.toml")
    assert exc.value.field == "config"


def test_cli_names_the_field_exits_2_and_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[gains]\nlam = -1.0\n")
    out = tmp_path / "out"
    code = cli.main(["run", "table2", "--config", str(bad), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert "gains.lam" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
    assert list(tmp_path.iterdir()) == [bad]


def test_friction_comp_uploads_the_nominal_friction_as_vdc_joint_estimates():
    from mrm_cosim.master.uploads import Gains, JointParams, node_uploads
    from mrm_cosim.models.actuators import ACTUATORS
    from mrm_cosim.models.robot import load_robot
    from mrm_cosim.protocol.regs import joint_upload

    robot = load_robot("mrm3")
    plain = node_uploads(robot, "vdc", Gains())
    rich = node_uploads(robot, "vdc", Gains(friction_comp=0.5))
    changed = [(a, b) for a, b in zip(plain, rich, strict=True) if a != b]
    assert changed and all(a[0] == b[0] and a[1] == b[1] for a, b in changed)
    from mrm_cosim.master.uploads import _joint_inertia, pid_shifts
    from mrm_cosim.master.uploads import hold_gains
    from mrm_cosim.protocol.safe_stop import SafeStopParams

    # VDC's PID words hold the safe stop's hold gains (docs/node.md "Safe stop")
    hold = hold_gains(SafeStopParams(), _joint_inertia(robot))
    shifts = pid_shifts(robot)
    for k, mod in enumerate(robot.modules):
        spec = ACTUATORS[mod.type.actuator]
        expect = JointParams.from_float(
            counts_per_rev=mod.type.counts_per_rev, tick_cycles=50, lam=Gains().lam,
            k_j=Gains().k_j, inertia=spec.output_inertia, viscous=0.5 * spec.viscous_friction,
            coulomb=0.5 * spec.coulomb_friction, k_p=hold["kp"][k], k_i=hold["ki"][k],
            k_d=hold["kd"][k], i_max=0.05, pid_shift=shifts[k])
        assert expect.th1 > 0 and expect.th2 > 0
        sent = [p for dest, _, p in rich if dest == k + 1]
        assert all(p in sent for p in joint_upload(expect))
    with pytest.raises(ec.InputError, match="gains.friction_comp"):
        ec.loads("[gains]\nfriction_comp = -1\n")


def _long_robot(tmp_path, n):
    text = 'name = "long"\n' + '[[modules]]\ntype = "I"\ntwist_deg = 90.0\n' * n
    (tmp_path / "long.toml").write_text(text)
    return tmp_path / "long.toml"


def test_a_robot_with_more_modules_than_nodes_is_refused_as_the_robot(tmp_path):
    """17 modules: the system has 16 nodes. Refused as the config's robot, not later as a gain
    word that does not fit (``joint1.kp``, which is what the user used to read)."""
    path = _long_robot(tmp_path, 17)
    with pytest.raises(InputError, match="17 modules.*at most 16") as exc:
        ec.loads(f"[experiment]\nrobot = '{path}'\n")
    assert exc.value.field == "experiment.robot"
    from mrm_cosim.cosim.track import check_robot_fits
    from mrm_cosim.models.robot import load_robot

    check_robot_fits(load_robot(str(_long_robot(tmp_path, 16))), "experiment.robot")


def test_the_period_must_be_a_whole_number_of_the_configured_plant_steps():
    """The loader checked the period against a 500-cycle plant step whatever ``[plant] dt``:
    dt = 20 µs with a 0.51 ms period was accepted and every other period's time-code and
    Comm A request left 10 µs late (the loops poll the master on the plant's grid; the
    summary's phase A moved from 10.3 to 15.3 µs), and dt = 30 µs got past the loader to fail
    at run time as ``start_cycle``. Both are refused naming plant.dt; a 5 µs step allows a
    period of 25,250 cycles, which the old check refused."""
    cfg = ec.loads("[plant]\ndt = 5e-6\n[timing]\nperiod_cycles = 25250\n")
    assert cfg.timing.period_cycles == 25_250 and cfg.plant.cycles_per_step == 250
    from mrm_cosim.cosim.track import run_track

    with pytest.raises(InputError) as exc:
        run_track("mrm3", "vdc", "model", duration=0.01, plant_config=PlantConfig(dt=2e-5),
                  timing=MasterTiming(period_cycles=25_500))
    assert exc.value.field == "plant.dt"


def test_a_table_claims_the_papers_order_only_for_runs_that_moved_and_stand_apart():
    from mrm_cosim.cosim.table2 import RHO_MARGIN, _ordering

    def runs(rhos, speed=0.5):
        return {c: (None, {"rho_s": r, "max_tip_speed_m_s": speed}) for c, r in rhos.items()}

    paper = {"vdc": 2e-5, "pid-fpga": 3e-4, "pid-1khz": 3e-3}
    assert _ordering(runs(paper))["as_paper"]
    assert not _ordering(runs({**paper, "vdc": 5e-3}))["as_paper"]          # out of order
    close = {**paper, "pid-fpga": paper["vdc"] * (1 + RHO_MARGIN / 2)}
    assert not _ordering(runs(close))["as_paper"]                          # within the noise
    assert not _ordering(runs(paper, speed=0.0))["as_paper"]                # nothing moved
