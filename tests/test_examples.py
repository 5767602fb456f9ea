"""The examples run, and say what they claim (examples/testbenches/, examples/api_tour.py)."""

import importlib.util
from pathlib import Path

import numpy as np

from mrm_cosim.hdl.link.chars import CharKind
from mrm_cosim.hdl.link.codec_ref import char_value

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
DATA, EOP, EEP = (k.value for k in CharKind)


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_codec_testbench(tmp_path):
    r = _load(EXAMPLES / "testbenches" / "codec_link.py").main(vcd_dir=str(tmp_path))
    assert r["received"] == [char_value(DATA, 0x12), char_value(DATA, 0x34),
                             char_value(DATA, 0x56), char_value(EOP)]
    assert r["sent_on_the_line"][-2:] == [("DATA", 0xA5), ("EOP",)]
    assert r["errors"] == {"disconnect": 0, "parity": 1, "escape": 0, "credit": 0,
                           "sequence": 0, "credit_timeout": 0}
    assert r["running_again"]
    assert (tmp_path / "codec_link.vcd").stat().st_size > 0      # the waveform on request


def test_block_against_reference_testbench():
    assert _load(EXAMPLES / "testbenches" / "sincos_vs_reference.py").main(n=60) == []


def test_vdc_engine_testbench(monkeypatch):
    example = _load(EXAMPLES / "testbenches" / "vdc_engine_vs_reference.py")
    assert example.main(periods=8) == []
    # the testbench sees a difference of one LSB in one force word
    step = example.VdcModel.step

    def off_by_one(self, x):
        F_a, F_b = step(self, x)
        return F_a, F_b[:5] + [F_b[5] + 1]

    monkeypatch.setattr(example.VdcModel, "step", off_by_one)
    bad = example.main(periods=2)
    assert [(period, what) for period, what, *_ in bad] == [(0, "forces"), (1, "forces")]


def test_own_component_testbench():
    r = _load(EXAMPLES / "testbenches" / "my_component.py").main()
    assert r == {"running": 1, "data_bytes": 7, "packets": 3}


def test_api_tour(tmp_path):
    r = _load(EXAMPLES / "api_tour.py").main(out=tmp_path / "tour.png", duration=0.02)
    assert r["modules"] == ["I", "II", "I"]
    assert r["newton_euler_vs_pinocchio_Nm"] < 1e-9
    assert np.abs(r["sag_after_50ms_rad"]).max() > 1e-3          # gravity acts
    assert 0 < r["max_tip_error_m"] < 1e-3 and r["steps"] == 2000
    assert (tmp_path / "tour.png").read_bytes()[:4] == b"\x89PNG"
