"""``mrm run line``: a Cartesian line through IK into the closed loop on the six-module arm."""

import json
from pathlib import Path

import numpy as np
import pytest

from mrm_cosim.cosim.line import line_reference, robot_at, run_line
from mrm_cosim.master.trig_planner import plan_line
from mrm_cosim.models.robot import load_robot
from mrm_cosim.mrm.cli import main
from mrm_cosim.master.line_file import load_line_file

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
LINE = str(EXAMPLES / "line.toml")


def _plan(path=LINE):
    return plan_line(*load_line_file(path))


def test_robot_at_moves_only_the_home_posture():
    robot = load_robot("mrm6")
    q0 = np.linspace(0.1, 0.6, 6)
    moved = robot_at(robot, q0)
    assert np.array_equal(moved.home, q0)
    assert np.allclose(moved.tip_pose(q0), robot.tip_pose(q0), atol=0.0)
    assert np.array_equal(moved.counts_per_rev, robot.counts_per_rev)


def test_run_line_starts_at_the_line_and_follows_it():
    plan = _plan()
    ref = line_reference("mrm6", plan, "trig")
    run = run_line("mrm6", plan, duration=0.02, reference=ref)
    # the plant starts at the reference's first sample, so the first error is ~0
    assert run.errors.position_mm[0] < 1e-3
    np.testing.assert_array_equal(run.q_desired, ref.evaluate(run.result.t)[0])
    line = run.summary["line"]
    assert line["profile"] == "trig"
    assert line["max_position_error_mm"] == pytest.approx(run.errors.position_mm.max())
    assert 0.0 < line["max_position_error_mm"] < 1.0
    assert len(line["peak_torque_Nm"]) == 6
    assert run.summary["overruns"] == 0 and run.summary["link_errors"] == 0


def test_cli_runs_both_profiles_side_by_side(tmp_path, capsys):
    out = tmp_path / "line"
    code = main(["run", "line", LINE, "--robot", "mrm6", "--profile", "both",
                 "--duration", "0.02", "--out", str(out), "-q"])
    assert code == 0
    for name in ("summary.json", "line.md", "config.toml", "tool_errors.png",
                 "tool_path.png", "tracking_trig.png", "tracking_ruckig.png"):
        assert (out / name).stat().st_size > 0, name
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["runs"]) == {"trig", "ruckig"}
    trig, ruckig = (summary["runs"][p]["line"] for p in ("trig", "ruckig"))
    # Ruckig's time-optimal profile is shorter than the trigonometric one, and its
    # piecewise-constant jerk shows as a jump the trigonometric profile does not have
    assert ruckig["move_duration_s"] < trig["move_duration_s"]
    assert (ruckig["reference"]["jerk_jump"]["jump_rad_s3"]
            > 10 * trig["reference"]["jerk_jump"]["jump_rad_s3"])
    table = (out / "line.md").read_text()
    assert "| trig |" in table and "| ruckig |" in table


@pytest.mark.parametrize("argv, field", [
    # examples/line_vertical.toml's vertical tool axis: on mrm6 only a singular posture has it
    (["examples/line_vertical.toml", "--robot", "mrm6"], "sample t = 0 s"),
    ([LINE, "--robot", "mrm3"], "--robot"),
    ([LINE, "--duration", "-1"], "--duration"),
    # the config's robot is the default of --robot; a three-joint one is named as the config's
    ([LINE, "--config", "configs/table2.toml"], "experiment.robot"),
])
def test_cli_refuses_before_anything_is_written(tmp_path, capsys, argv, field):
    argv = [str(Path(__file__).resolve().parents[1] / a)
            if a.startswith(("examples/", "configs/")) else a for a in argv]
    out = tmp_path / "line"
    code = main(["run", "line", *argv, "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and field in err[0]
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_the_default_config_is_the_six_module_arms(tmp_path):
    """Without --config and --robot, ``mrm run line`` reads the package's configs/line.toml:
    mrm6 and the VDC gains chosen for it on a held-out move (benchmarks/line_gains.py), not
    table2.toml's mrm3 gains, which drove mrm6's torques to their limits at low speed."""
    from mrm_cosim.cosim.experiment_config import LINE_CONFIG, load

    out = tmp_path / "line"
    assert main(["run", "line", LINE, "--duration", "0.01", "--out", str(out), "-q"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["robot"] == "mrm6"
    used = load(out / "config.toml")
    assert used.gains == load(LINE_CONFIG).gains != load().gains
