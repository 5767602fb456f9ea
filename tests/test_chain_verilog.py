# amaranth: UnusedElaboratable=no
"""``mrm hdl verilog --top link_node``: the chain endpoint as Verilog, lint-clean."""

import re

import pytest

from mrm_cosim.mrm.commands import hdl as hdl_command
from mrm_cosim.errors import InputError

from .lint_helpers import assert_lint_clean
from .test_verilog_codec import run_cli, written

# The node ties the upstream codec's `tick_in` low (time-codes only go down), and Yosys then
# emits a `casez` whose constant-folded patterns overlap. casez takes the first match, which is
# the priority Amaranth meant, so the overlap is harmless: the .vlt of the tops with a link
# node waives CASEOVERLAP too (hdl/export.py).

@pytest.fixture(scope="module")
def node_verilog(tmp_path_factory):
    out = tmp_path_factory.mktemp("verilog")
    assert run_cli(["hdl", "verilog", "--top", "link_node", "--out", str(out)]) == 0
    return out / "link_node.v"


def module_ports(text, name):
    header = re.search(rf"module {name}\((.*?)\);", text, re.DOTALL).group(1)
    return {p.strip() for p in header.split(",")}


def test_writes_the_node_module_with_its_ports(node_verilog):
    text = node_verilog.read_text()
    assert module_ports(text, "link_node") == {
        "address", "tx__payload", "tx__valid", "tx__ready", "rx__payload", "rx__valid",
        "rx__ready", "up__d_in", "up__s_in", "up__d_out", "up__s_out", "down__d_in",
        "down__s_in", "down__d_out", "down__s_out", "tc_strobe", "tc_time", "tc_stamp",
        "tc_in_sequence", "cycle", "up_running", "down_running", "rx_stats", "dropped",
        "up_errors", "down_errors", "clk", "rst"}
    # Beat = header (32) + data (8) + last (1); six line slots per cycle by default.
    assert "input [40:0] tx__payload;" in text and "output [40:0] rx__payload;" in text
    assert "input [5:0] up__d_in;" in text and "output [5:0] down__d_out;" in text
    assert sorted(p.name for p in node_verilog.parent.iterdir()) == written("link_node")


def test_verilator_lint_is_clean(node_verilog):
    assert_lint_clean(node_verilog, timeout=120)


def test_parameters_reach_the_node(tmp_path):
    path = hdl_command.write_verilog("link_node", tmp_path,
                                     {"slots": 1, "max_payload": 40, "rx_slots": 1})
    text = path.read_text()
    assert "input up__d_in;" in text and "output down__s_out;" in text


def test_bad_payload_size_names_the_field(tmp_path):
    with pytest.raises(InputError) as exc:
        run_cli(["hdl", "verilog", "--top", "link_node", "--out", str(tmp_path / "out"),
                 "--param", "max_payload=0"])
    assert exc.value.field == "--param"
    assert "Maximum payload" in exc.value.message
    assert not (tmp_path / "out").exists()
