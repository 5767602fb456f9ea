# amaranth: UnusedElaboratable=no
"""``mrm hdl verilog --top system``: the whole robot's gateware as Verilog, lint-clean."""


from mrm_cosim.mrm.cli import main

from .lint_helpers import assert_lint_clean
from .test_chain_verilog import module_ports
from .test_verilog_codec import run_cli


def test_system_verilog_is_lint_clean(tmp_path):
    assert run_cli(["hdl", "verilog", "--top", "system", "--param", "n_nodes=2",
                    "--out", str(tmp_path)]) == 0
    path = tmp_path / "system.v"
    text = path.read_text()
    ports = module_ports(text, "system")
    assert {"enc_a", "enc_b", "torque1", "torque2", "tx_char", "rx_char", "tick_in"} <= ports
    assert "torque3" not in ports
    assert_lint_clean(path)


def test_system_rejects_bad_node_count(tmp_path, capsys):
    assert main(["hdl", "verilog", "--top", "system", "--param", "n_nodes=17",
                 "--out", str(tmp_path / "out")]) == 2
    assert "n_nodes" in capsys.readouterr().err
    assert not (tmp_path / "out" / "system.v").exists()
