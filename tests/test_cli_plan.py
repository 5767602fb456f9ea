"""``mrm plan``: figures, sample files, and one-line errors with exit code 2."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

import mrm_cosim.mrm.cli as cli
from mrm_cosim.master import quaternion as quat

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "line_vertical.toml"

GOOD = """
[start]
pose = [[1, 0, 0, 0.3], [0, 1, 0, 0.0], [0, 0, 1, 0.4], [0, 0, 0, 1]]
[end]
pose = [[0, -1, 0, 0.1], [1, 0, 0, 0.2], [0, 0, 1, 0.5], [0, 0, 0, 1]]
[limits]
translation = { velocity = 1.0, acceleration = 4.0, jerk = 40.0 }
rotation    = { velocity = 1.0, acceleration = 4.0, jerk = 40.0 }
"""


@pytest.fixture
def mrm(capsys):
    """Run ``mrm …`` in-process; returns (exit code, stdout, stderr)."""
    assert "plan" in cli.COMMANDS

    def run(*argv):
        try:
            code = cli.main([str(a) for a in argv])
        except SystemExit as exc:          # argparse usage errors
            code = exc.code
        out, err = capsys.readouterr()
        return code, out, err
    return run


def write(tmp_path, text, name="plan.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_quintic_json_is_the_closed_form(mrm):
    code, out, err = mrm("plan", "quintic", "--q0", "0", "--qf", "0.1571", "--tf", "1",
                         "--json")
    assert code == 0 and err == ""
    fig = json.loads(out)
    assert list(fig) == ["duration_s", "peak_velocity", "peak_acceleration", "peak_jerk"]
    assert fig["duration_s"] == 1.0
    assert fig["peak_velocity"] == pytest.approx(15 / 8 * 0.1571, rel=1e-15)
    assert fig["peak_acceleration"] == pytest.approx(10 / math.sqrt(3) * 0.1571, rel=1e-15)
    assert fig["peak_jerk"] == pytest.approx(60 * 0.1571, rel=1e-15)


def test_quintic_several_joints_and_samples(mrm, tmp_path):
    out_csv = tmp_path / "q.csv"
    code, out, _ = mrm("plan", "quintic", "--q0", "0", "--qf", "0.1571", "0.3142", "--tf", "2",
                       "--json", "--samples", out_csv, "--dt", "0.01")
    assert code == 0
    fig = json.loads(out)
    assert fig["peak_velocity"] == pytest.approx([15 / 16 * 0.1571, 15 / 16 * 0.3142])
    header = out_csv.read_text().splitlines()[0].split(",")
    assert header[:3] == ["t_s", "q1_rad", "q2_rad"] and len(header) == 9
    data = np.loadtxt(out_csv, delimiter=",", skiprows=1)
    assert data.shape == (201, 9)
    assert data[-1, 1] == 0.1571 and data[-1, 2] == 0.3142
    code, out, _ = mrm("plan", "quintic", "--q0", "0", "--qf", "1", "--tf", "1")
    assert code == 0 and "peak_acceleration" in out


@pytest.mark.parametrize("argv, field", [
    (["--q0", "0", "--qf", "nan", "--tf", "1"], "--qf"),
    (["--q0", "0", "--qf", "1", "--tf", "0"], "--tf"),
    (["--q0", "0", "--qf", "1", "--tf", "-2"], "--tf"),
    (["--q0", "x", "--qf", "1", "--tf", "1"], "--q0"),
    (["--q0", "0", "0", "0", "--qf", "1", "2", "--tf", "1"], "--qf"),
    (["--q0", "0", "--qf", "1", "inf", "--tf", "1"], "--qf[1]"),
    (["--q0", "0", "--qf", "1", "--tf", "1", "--samples", "X.csv", "--dt", "0"], "--dt"),
    # peaks that overflow a float: used to print inf with a RuntimeWarning and exit 0
    (["--q0", "0", "--qf", "1", "--tf", "1e-300", "--samples", "X.csv"], "--tf"),
    (["--q0=-1e308", "--qf", "1e308", "--tf", "1"], "--qf"),
    (["--q0", "0", "--qf", "1", "--tf", "1e12", "--samples", "X.csv"], "--dt"),  # 1e15 rows
])
def test_quintic_bad_input_exits_2_naming_the_field(mrm, tmp_path, monkeypatch, argv, field):
    monkeypatch.chdir(tmp_path)
    code, out, err = mrm("plan", "quintic", *argv)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and f"{field}:" in err
    assert list(tmp_path.iterdir()) == []


def test_line_json_and_samples(mrm, tmp_path):
    out_csv = tmp_path / "line.csv"
    code, out, err = mrm("plan", "line", EXAMPLE, "--json", "--samples", out_csv)
    assert code == 0 and err == ""
    fig = json.loads(out)
    assert list(fig) == ["distance_m", "rotation_rad", "translation_time_s", "rotation_time_s",
                         "duration_s", "translation_accel_amplitude",
                         "rotation_accel_amplitude"]
    assert fig["distance_m"] == pytest.approx(0.3, rel=1e-15)
    assert fig["rotation_rad"] == pytest.approx(math.pi / 2, rel=1e-15)
    assert fig["rotation_time_s"] == pytest.approx(math.pi, rel=1e-15)    # 2θ/V binds
    assert fig["duration_s"] == fig["rotation_time_s"]
    assert fig["translation_accel_amplitude"] == pytest.approx(8 * 0.3 / math.pi**2)
    lines = out_csv.read_text().splitlines()
    header = lines[0].split(",")
    assert len(header) == 26 and header[:8] == ["t_s", "x_m", "y_m", "z_m", "qw", "qx", "qy",
                                                 "qz"]
    assert header[-3:] == ["jwx_rad_s3", "jwy_rad_s3", "jwz_rad_s3"]
    data = np.loadtxt(out_csv, delimiter=",", skiprows=1)
    assert data.shape == (math.ceil(math.pi / 0.001) + 1, 26)
    np.testing.assert_allclose(np.diff(data[:, 0]), 0.001, atol=1e-12)
    assert list(data[-1, 1:4]) == [0.1, 0.2, 0.5]
    np.testing.assert_allclose(quat.to_matrix(data[-1, 4:8]),
                               [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
    assert np.max(np.linalg.norm(data[:, 17:20], axis=1)) <= 1.0 + 1e-12


def test_line_ruckig_prints_both_durations(mrm, tmp_path):
    code, out, _ = mrm("plan", "line", EXAMPLE, "--profile", "ruckig", "--json")
    assert code == 0
    fig = json.loads(out)
    assert fig["profile"] == "ruckig"
    assert fig["duration_s"] <= fig["trig_duration_s"]
    assert fig["trig_duration_s"] == pytest.approx(math.pi, rel=1e-15)
    out_csv = tmp_path / "r.csv"
    code, out, _ = mrm("plan", "line", EXAMPLE, "--profile", "ruckig", "--samples", out_csv,
                       "--dt", "0.002")
    assert code == 0 and "trig_duration_s" in out
    data = np.loadtxt(out_csv, delimiter=",", skiprows=1)
    assert data[-1, 0] >= fig["duration_s"] and list(data[-1, 1:4]) == [0.1, 0.2, 0.5]


def test_line_projects_a_rounded_rotation_with_a_note(mrm, tmp_path):
    c, s = round(math.cos(0.5), 3), round(math.sin(0.5), 3)
    text = GOOD.replace("[[0, -1, 0, 0.1], [1, 0, 0, 0.2]",
                        f"[[{c}, {-s}, 0, 0.1], [{s}, {c}, 0, 0.2]")
    code, out, err = mrm("plan", "line", write(tmp_path, text), "--json")
    assert code == 0
    assert "note" in err and "end.pose" in err and "projected" in err
    assert json.loads(out)["rotation_rad"] == pytest.approx(0.5, abs=1e-3)


def test_line_zero_motion(mrm, tmp_path):
    text = GOOD.replace("[[0, -1, 0, 0.1], [1, 0, 0, 0.2], [0, 0, 1, 0.5]",
                        "[[1, 0, 0, 0.3], [0, 1, 0, 0.0], [0, 0, 1, 0.4]")
    out_csv = tmp_path / "z.csv"
    code, out, _ = mrm("plan", "line", write(tmp_path, text), "--json", "--samples", out_csv)
    assert code == 0
    fig = json.loads(out)
    assert fig["duration_s"] == 0.0 and fig["distance_m"] == 0.0 and fig["rotation_rad"] == 0.0
    data = np.loadtxt(out_csv, delimiter=",", skiprows=1, ndmin=2)
    assert data.shape == (1, 26)


BAD_FILES = [
    (GOOD.replace("[limits]", "[limitz]"), "limitz"),
    (GOOD.replace("[end]\npose", "[end]\nposes"), "end.poses"),
    (GOOD.replace("[start]\npose = [[1, 0, 0, 0.3], [0, 1, 0, 0.0], [0, 0, 1, 0.4], "
                  "[0, 0, 0, 1]]\n", ""), "start"),
    (GOOD + "[extra]\nx = 1\n", "extra"),
    (GOOD.replace("jerk = 40.0 }\nrotation", "jerk = 40.0, snap = 1 }\nrotation"),
     "limits.translation.snap"),
    (GOOD.replace("velocity = 1.0, acceleration = 4.0, jerk = 40.0 }\nrotation",
                  "velocity = 1.0, jerk = 40.0 }\nrotation"), "limits.translation.acceleration"),
    (GOOD.replace("rotation    = { velocity = 1.0", "rotation    = { velocity = 0.0"),
     "limits.rotation.velocity"),
    (GOOD.replace("rotation    = { velocity = 1.0", "rotation    = { velocity = -1.0"),
     "limits.rotation.velocity"),
    (GOOD.replace("jerk = 40.0 }\nrotation", "jerk = nan }\nrotation"),
     "limits.translation.jerk"),
    (GOOD.replace("jerk = 40.0 }\nrotation", "jerk = \"40\" }\nrotation"),
     "limits.translation.jerk"),
    (GOOD.replace("rotation    = { velocity = 1.0, acceleration = 4.0, jerk = 40.0 }",
                  "rotation = 3"), "limits.rotation"),
    (GOOD.replace("[0, 0, 1, 0.5], [0, 0, 0, 1]]", "[0, 0, 1, 0.5]]"), "end.pose"),
    (GOOD.replace("[0, 0, 1, 0.5], [0, 0, 0, 1]]", "[0, 0, 1, 0.5], [0, 0, 1, 1]]"),
     "end.pose[3]"),
    (GOOD.replace("[0, 0, 1, 0.5], [0, 0, 0, 1]]", "[0, 0, 1, nan], [0, 0, 0, 1]]"),
     "end.pose[2][3]"),
    (GOOD.replace("[[0, -1, 0, 0.1], [1, 0, 0, 0.2]", "[[0, 1, 0, 0.1], [1, 0, 0, 0.2]"),
     "end.pose"),                                                         # det −1
    (GOOD.replace("[[0, -1, 0, 0.1], [1, 0, 0, 0.2]", "[[0, -1.05, 0, 0.1], [1, 0, 0, 0.2]"),
     "end.pose"),                                                         # not orthonormal
    (GOOD.replace("[start]", "[start"), "FILE"),                           # TOML syntax
    (GOOD.replace("[1, 0, 0, 0.2]", "[1, 0, 0, 1e300]").replace("[0, 1, 0, 0.0]",
                                                                "[0, 1, 0, -1e300]"),
     "end.pose"),                              # the move overflows (was a numpy warning)
]


@pytest.mark.parametrize("text, field", BAD_FILES)
def test_line_bad_file_exits_2_naming_the_field(mrm, tmp_path, text, field):
    path = write(tmp_path, text)
    out_csv = tmp_path / "never.csv"
    code, out, err = mrm("plan", "line", path, "--json", "--samples", out_csv)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1
    assert f"error: {field}:" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.toml"]   # nothing written


def _limits(translation, rotation=(1.0, 4.0, 40.0)):
    t, r = translation, rotation
    return GOOD.replace(
        "translation = { velocity = 1.0, acceleration = 4.0, jerk = 40.0 }",
        f"translation = {{ velocity = {t[0]!r}, acceleration = {t[1]!r}, jerk = {t[2]!r} }}"
    ).replace(
        "rotation    = { velocity = 1.0, acceleration = 4.0, jerk = 40.0 }",
        f"rotation = {{ velocity = {r[0]!r}, acceleration = {r[1]!r}, jerk = {r[2]!r} }}")


@pytest.mark.parametrize("profile", ["trig", "ruckig"])
@pytest.mark.parametrize("text, field", [
    (_limits((1e-300, 4.0, 40.0)), "limits.translation.velocity"),
    (_limits((1.0, 4.0, 40.0), (1e-300, 4.0, 40.0)), "limits.rotation.velocity"),
    (_limits((1.0, 4.0, 40.0), (1.0, 4.0, 5e-324)), "limits.rotation.jerk"),
])
def test_line_limits_too_small_for_a_float_are_named(mrm, tmp_path, profile, text, field):
    """A velocity of 1e-300 made the move last 6e299 s; its amplitude 8L/T² ended in an
    OverflowError traceback (T**2), or the profile refused ``duration: inf``, a field the
    file does not have; the limit that sets the duration is named, exit 2."""
    code, out, err = mrm("plan", "line", write(tmp_path, text), "--profile", profile)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and f"error: {field}:" in err


@pytest.mark.parametrize("text, field", [
    (_limits((1e300, 1e300, 1e300)), "limits.translation"),              # RuckigError
    (_limits((1.0, 4.0, 40.0), (1e300, 1e300, 1e300)), "limits.rotation"),
    (_limits((1.0, 1e-300, 40.0)), "limits.translation"),
    (_limits((1e-5, 4.0, 40.0)), "limits.translation.velocity"),        # result -101
    (_limits((1.0, 4.0, 1e-15)), "limits.translation.jerk"),
])
def test_line_limits_ruckig_cannot_solve_are_named(mrm, tmp_path, text, field):
    """Extreme limits ended in a RuckigError traceback (its solver failed), or in
    ``ValueError: -101 is not a valid Result`` (a move longer than Ruckig computes); both
    are named errors now, exit 2, and the trigonometric profile still plans the move."""
    path = write(tmp_path, text)
    code, out, err = mrm("plan", "line", path, "--profile", "ruckig")
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and f"error: {field}:" in err
    assert "Ruckig" in err
    assert mrm("plan", "line", path)[0] == 0


def test_line_missing_file_and_bad_dt(mrm, tmp_path):
    code, _, err = mrm("plan", "line", tmp_path / "nope.toml")
    assert code == 2 and "FILE:" in err
    code, _, err = mrm("plan", "line", EXAMPLE, "--samples", tmp_path / "x.csv", "--dt", "-1")
    assert code == 2 and "--dt:" in err
    code, _, err = mrm("plan", "line", EXAMPLE, "--samples", tmp_path / "no" / "x.csv")
    assert code == 2 and "--samples:" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", [["quintic", "--q0", "0", "--qf", "1", "--tf", "1"],
                                     ["line", str(EXAMPLE)]])
def test_samples_naming_a_folder_or_an_unwritable_place_is_refused(mrm, tmp_path, command):
    """``--samples`` naming an existing folder ended in an IsADirectoryError traceback, and
    one in /proc in a FileNotFoundError traceback; both are refused as --samples, exit 2,
    the folder untouched and no temporary file left."""
    folder = tmp_path / "d"
    folder.mkdir()
    places = [folder] + (["/proc/mrm-samples.csv"] if Path("/proc/self").is_dir() else [])
    for place in places:
        code, out, err = mrm("plan", *command, "--samples", place)
        assert code == 2 and out == ""
        assert len(err.strip().splitlines()) == 1 and "--samples:" in err
    assert [p.name for p in tmp_path.iterdir()] == ["d"] and list(folder.iterdir()) == []


def test_existing_output_survives_a_failed_run(mrm, tmp_path):
    out_csv = tmp_path / "keep.csv"
    out_csv.write_text("old\n")
    bad = write(tmp_path, GOOD.replace("jerk = 40.0 }\nrotation", "jerk = 0 }\nrotation"))
    code, _, _ = mrm("plan", "line", bad, "--samples", out_csv)
    assert code == 2 and out_csv.read_text() == "old\n"
