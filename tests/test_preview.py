"""The float closed-loop preview (the main job until the gateware loop exists)."""

import json
from pathlib import Path

import numpy as np
import pytest

from mrm_cosim.cosim.preview import paper_test_profile, run_preview
from mrm_cosim.models.robot import load_robot
from mrm_cosim.mrm.cli import main
from mrm_cosim.errors import InputError
from mrm_cosim.results import MARKER, atomic_output_dir


@pytest.fixture(scope="module")
def short_run():
    return run_preview("mrm3", duration=0.3, seed=1)


def test_preview_tracks_the_quintic(short_run):
    s = short_run.summary
    assert s["max_joint_error_rad"] < 2e-3
    assert s["rho_s"] == pytest.approx(s["max_tip_error_m"] / s["max_tip_speed_m_s"])
    # The test trajectory is the paper's: joint i moves by i·q_d.
    np.testing.assert_allclose(short_run.q_d[-1] / short_run.q_d[-1, 0], [1.0, 2.0, 3.0])


def test_preview_is_deterministic_and_seeded(short_run):
    again = run_preview("mrm3", duration=0.3, seed=1)
    assert again.summary["trace_sha256"] == short_run.summary["trace_sha256"]
    np.testing.assert_array_equal(again.q, short_run.q)
    other = run_preview("mrm3", duration=0.3, seed=2)
    assert other.summary["trace_sha256"] != short_run.summary["trace_sha256"]


def test_paper_profile_pattern_for_six_modules():
    robot = load_robot("mrm6")
    prof = paper_test_profile(robot)
    np.testing.assert_allclose(prof.delta, 0.1571 * np.array([1, 2, 3, 1, 2, 3]))


def test_preview_rejects_bad_duration():
    with pytest.raises(InputError) as info:
        run_preview("mrm3", duration=float("nan"))
    assert info.value.field == "duration"


@pytest.mark.parametrize("duration", ["0.0001", "0.001"])
def test_cli_refuses_a_duration_shorter_than_two_samples(tmp_path, capsys, duration):
    """Under one controller sample ended in numpy's AxisError traceback; one sample wrote
    rho_s NaN (0/0: no motion yet). Both are refused as --duration, nothing written."""
    out = tmp_path / "res"
    assert main(["run", "preview", "--duration", duration, "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--duration" in err and "2 controller samples" in err
    assert list(tmp_path.iterdir()) == []


def test_two_samples_are_enough():
    s = run_preview("mrm3", duration=0.002).summary
    assert np.isfinite(s["rho_s"]) and s["max_tip_speed_m_s"] > 0.0


def test_cli_writes_results_folder(tmp_path, capsys):
    out = tmp_path / "res"
    assert main(["run", "preview", "--duration", "0.05", "--out", str(out), "--quiet"]) == 0
    assert capsys.readouterr().out == ""
    summary = json.loads((out / "summary.json").read_text())
    assert summary["robot"] == "mrm3" and summary["version"]
    assert (out / "tracking.png").stat().st_size > 1000
    assert len((out / "trace.csv").read_text().splitlines()) == 1 + 50
    config = json.loads((out / "config.json").read_text())
    assert config["seed"] == 0 and config["robot"]["name"] == "mrm3"


def test_cli_bad_input_leaves_nothing(tmp_path, capsys):
    out = tmp_path / "res"
    assert main(["run", "preview", "--duration", "-1", "--out", str(out)]) == 2
    assert "duration" in capsys.readouterr().err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_atomic_output_dir_keeps_old_results_on_failure(tmp_path):
    out = tmp_path / "res"
    with atomic_output_dir(out) as tmp:
        (tmp / "a.txt").write_text("old")
    with pytest.raises(RuntimeError), atomic_output_dir(out) as tmp:
        (tmp / "a.txt").write_text("half")
        raise RuntimeError("simulated crash")
    assert (out / "a.txt").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"]
    with atomic_output_dir(out) as tmp:
        (tmp / "b.txt").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "b.txt"]


def test_a_result_folder_is_made_as_any_folder_is(tmp_path):
    """Result folders came out 0700 (the temporary folder's mode, renamed into place): the
    results of a run on a shared machine were readable by their owner only. They get the mode
    a new folder gets (0777 less the umask), like the folders above them."""
    import os
    import stat

    mask = os.umask(0o022)
    try:
        with atomic_output_dir(tmp_path / "res") as tmp:
            (tmp / "a.txt").write_text("x")
        (tmp_path / "plain").mkdir()
    finally:
        os.umask(mask)
    mode = stat.S_IMODE((tmp_path / "res").stat().st_mode)
    assert mode == stat.S_IMODE((tmp_path / "plain").stat().st_mode) == 0o755


@pytest.mark.parametrize("command", [["run", "preview"], ["run", "track", "--backend", "model"],
                                     ["run", "table2"]])
def test_cli_refuses_an_existing_file_as_out_and_leaves_it(tmp_path, capsys, command):
    """``--out`` naming a file used to replace it with the result folder (the file was gone,
    exit 0); it is refused as --out before anything runs, the file untouched."""
    target = tmp_path / "notes.txt"
    target.write_text("precious")
    assert main([*command, "--duration", "0.05", "--out", str(target), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "not a folder" in err
    assert target.read_text() == "precious"
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]


def test_atomic_output_dir_refuses_to_replace_a_file(tmp_path):
    target = tmp_path / "notes.txt"
    target.write_text("precious")
    with pytest.raises(InputError) as info, atomic_output_dir(target) as tmp:
        (tmp / "a.txt").write_text("result")
    assert info.value.field == "out"
    assert target.read_text() == "precious"
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]


@pytest.mark.parametrize("out", ["", " ", ".", "./", "..", "../here", "/"])
def test_cli_refuses_an_out_that_is_no_folder_of_its_own(tmp_path, monkeypatch, capsys, out):
    """``--out ''``, ``.``, ``..`` or ``/`` used to run, then fail replacing the folder with an
    OSError traceback, leaving ``..xxxx`` temporary folders (with the results) behind, even in
    ``/``; they are refused as --out before anything runs, nothing made."""
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    root_before = sorted(p.name for p in Path("/").iterdir())
    assert main(["run", "preview", "--duration", "0.05", "--out", out, "--quiet"]) == 2
    assert "--out" in capsys.readouterr().err
    assert [p.name for p in tmp_path.iterdir()] == ["here"] and list(here.iterdir()) == []
    assert sorted(p.name for p in Path("/").iterdir()) == root_before


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")
@pytest.mark.parametrize("command", [["run", "preview"], ["run", "track", "--backend", "model"],
                                     ["run", "table2"]])
def test_cli_refuses_an_out_where_no_folder_can_be_made(tmp_path, capsys, command):
    """An unwritable place (``/proc/x``, under a file) used to run, then end in a
    FileNotFoundError traceback; it is refused as --out before anything runs."""
    (tmp_path / "a-file").write_text("x")
    for out in ("/proc/mrm-results", str(tmp_path / "a-file" / "res")):
        assert main([*command, "--duration", "0.05", "--out", out, "--quiet"]) == 2
        err = capsys.readouterr().err
        assert "--out" in err and "Traceback" not in err
    assert [p.name for p in tmp_path.iterdir()] == ["a-file"]


def test_atomic_output_dir_removes_the_folders_it_made_on_failure(tmp_path):
    with pytest.raises(RuntimeError), atomic_output_dir(tmp_path / "a" / "b" / "res") as tmp:
        (tmp / "x.txt").write_text("half")
        raise RuntimeError("simulated crash")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", [["run", "preview"], ["run", "track", "--backend", "model"],
                                     ["run", "table2"]])
@pytest.mark.parametrize("seed", ["-3", "1.5", "x"])
def test_cli_refuses_a_bad_seed_naming_the_flag(tmp_path, capsys, command, seed):
    """Refused by the argument parser, before anything is built or run (a negative seed
    used to be found by the plant, after the start of the run, as ``seed``)."""
    out = tmp_path / "res"
    with pytest.raises(SystemExit) as e:
        main([*command, "--seed", seed, "--out", str(out)])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "--seed" in err and "non-negative integer" in err
    assert list(tmp_path.iterdir()) == []
