"""``mrm robot`` from the command line, including its error contract (one line, exit 2)."""

import json
import subprocess
import sys

import pinocchio as pin
import pytest

from mrm_cosim.mrm.cli import main


def test_show_json_describes_modules(capsys):
    assert main(["robot", "show", "mrm3", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["n_modules"] == 3
    assert [m["type"] for m in info["modules"]] == ["I", "II", "I"]
    assert info["modules"][1]["peak_torque_Nm"] == 28.0
    assert info["modules"][0]["counts_per_rev"] == 800_000


def test_show_text(capsys):
    assert main(["robot", "show", "mrm6"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("mrm6: 6 modules")


def test_urdf_loads_in_pinocchio(capsys):
    assert main(["robot", "urdf", "mrm6"]) == 0
    model = pin.buildModelFromXML(capsys.readouterr().out)
    assert model.nq == 6


def test_robot_file(tmp_path, capsys):
    path = tmp_path / "arm.toml"
    path.write_text('name = "two"\n[[modules]]\ntype = "I"\n[[modules]]\ntype = "II"\n'
                    'twist_deg = 90\n')
    assert main(["robot", "show", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["name"] == "two"


@pytest.mark.parametrize("argv, field", [
    (["robot", "show", "nope"], "robot"),
    (["robot", "urdf"], "robot"),
])
def test_errors_are_one_line_with_exit_2(argv, field):
    proc = subprocess.run([sys.executable, "-m", "mrm_cosim", *argv], capture_output=True,
                          text=True)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and field in lines[0]
    assert proc.stdout == ""


def test_bad_file_field_named(tmp_path):
    path = tmp_path / "arm.toml"
    path.write_text('[[modules]]\ntype = "II"\nspring = { torque = 30.0 }\n')
    proc = subprocess.run([sys.executable, "-m", "mrm_cosim", "robot", "urdf", str(path)],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stdout == ""
    assert "modules[0].spring.torque" in proc.stderr


@pytest.mark.parametrize("text, field", [
    ('[[modules]]\ntype = ["I"]\n', "modules[0].type"),
    ('[[modules]]\ntype = { name = "I" }\n', "modules[0].type"),
    ('[module_types.III]\nlike = ["I"]\n[[modules]]\ntype = "III"\n',
     "module_types.III.like"),
])
def test_a_list_or_table_as_type_name_is_one_line_exit_2(tmp_path, capsys, text, field):
    """These used to end in a TypeError traceback (unhashable type)."""
    path = tmp_path / "arm.toml"
    path.write_text(text)
    assert main(["robot", "show", str(path)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and field in err
