"""`mrm hdl verilog/synth --param`: every integer parameter is bounded before the build."""

import pytest

from mrm_cosim.mrm.cli import main


@pytest.mark.parametrize("param, words", [
    ("reset_cycles=99999999999999999999", "--param reset_cycles: must be an integer from"),
    ("rx_fifo_depth=1000000", "--param rx_fifo_depth: must be an integer from 1 to 4,096"),
    ("slots=100000", "--param slots: must be an integer from 1 to 64"),
    ("wait_cycles=-99999999999", "--param wait_cycles: must be an integer from"),
    ("credit_audit=1", "Credit audit must be an integer number of cycles, 0 (off) or 2"),
    ("credit_timeout=-1", "Credit timeout must be an integer number of cycles"),
])
def test_out_of_bounds_parameters_are_refused_before_the_build(tmp_path, capsys, param, words):
    out = tmp_path / "v"
    code = main(["hdl", "verilog", "--top", "spw_codec", "--param", param, "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and words in err[0]
    assert not out.exists()


def test_the_exported_codec_can_leave_the_credit_audit_out(tmp_path):
    """A foreign peer need not grant what our codec grants at rest: the exported codec takes
    ``credit_audit=0``, and its Verilog then has no audit counter."""
    with_audit, without = tmp_path / "a", tmp_path / "b"
    assert main(["hdl", "verilog", "--top", "spw_codec", "--out", str(with_audit)]) == 0
    assert main(["hdl", "verilog", "--top", "spw_codec", "--param", "credit_audit=0",
                 "--out", str(without)]) == 0
    assert "silent" in (with_audit / "spw_codec.v").read_text()
    assert "silent" not in (without / "spw_codec.v").read_text()
