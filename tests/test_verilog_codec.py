# amaranth: UnusedElaboratable=no
"""``mrm hdl verilog``: the standalone codec as Verilog, atomically written, lint-clean."""

import argparse
import re
from pathlib import Path

import pytest

from mrm_cosim.mrm.commands import hdl as hdl_command
from mrm_cosim.errors import InputError

from .lint_helpers import assert_lint_clean

# The lint runs with the .vlt file `mrm hdl verilog` writes beside the Verilog (hdl/export.py:
# waivers for the style of Yosys-generated Verilog only); every other -Wall warning and every
# error stays fatal.
COMPANIONS = ("{}.v", "{}.vlt", "{}.sdc", "{}.lpf", "{}.ucf", "{}.ports.md")


def written(top: str) -> list[str]:
    """The files ``mrm hdl verilog --top TOP`` writes, sorted."""
    return sorted(f.format(top) for f in COMPANIONS)


def run_cli(argv):
    """Parse ``argv`` with the ``hdl`` subcommand registered as mrm.cli does, and run it."""
    parser = argparse.ArgumentParser(prog="mrm")
    hdl_command.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


@pytest.fixture(scope="module")
def codec_verilog(tmp_path_factory):
    out = tmp_path_factory.mktemp("verilog")
    assert run_cli(["hdl", "verilog", "--top", "spw_codec", "--out", str(out)]) == 0
    return out / "spw_codec.v"


def test_writes_the_codec_module_with_its_wire_ports(codec_verilog):
    text = codec_verilog.read_text()
    header = re.search(r"module spw_codec\((.*?)\);", text, re.DOTALL).group(1)
    ports = {p.strip() for p in header.split(",")}
    assert ports == {"d_in", "s_in", "d_out", "s_out", "tx__payload", "tx__valid", "tx__ready",
                     "rx__payload", "rx__valid", "rx__ready", "tick_in", "time_in", "tick_out",
                     "time_out", "link_start", "auto_start", "link_disable", "running", "state",
                     "errors", "tx_credit", "rx_credit", "run_div", "clk", "rst"}
    assert "input [5:0] d_in;" in text and "output [5:0] d_out;" in text
    assert "input [4:0] run_div;" in text, "the run rate, 2 .. 30 slots per bit"
    assert sorted(p.name for p in codec_verilog.parent.iterdir()) == written("spw_codec"), \
        "no temporary file may be left behind"


def test_verilator_lint_is_clean(codec_verilog):
    assert_lint_clean(codec_verilog, timeout=120)


def test_parameters_reach_the_generated_ports(tmp_path):
    path = hdl_command.write_verilog("spw_codec", tmp_path, {"slots": 1, "rx_fifo_depth": 16})
    text = path.read_text()
    assert "input d_in;" in text and "output d_out;" in text


@pytest.mark.parametrize("argv,field", [
    (["--top", "nope"], "--top"),
    (["--top", "spw_codec", "--param", "slots"], "--param"),
    (["--top", "spw_codec", "--param", "slots=x"], "--param slots"),
    (["--top", "spw_codec", "--param", "colour=1"], "--param colour"),
    (["--top", "spw_codec", "--param", "slots=9"], "--param"),
])
def test_bad_input_names_the_field_and_writes_nothing(tmp_path, argv, field):
    out = tmp_path / "out"
    with pytest.raises(InputError) as exc:
        run_cli(["hdl", "verilog", "--out", str(out), *argv])
    assert exc.value.field == field
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")
def test_out_where_no_folder_can_be_made_is_refused_as_out(tmp_path):
    """``--out /proc/x`` (or a folder under a file) built the top, then ended in a
    FileNotFoundError / NotADirectoryError traceback; it is refused as --out before the build,
    nothing made."""
    (tmp_path / "a-file").write_text("keep me")
    for out in ("/proc/mrm-verilog", str(tmp_path / "a-file" / "v"),
                str(tmp_path / "a-file" / "v" / "w")):
        with pytest.raises(InputError) as exc:
            run_cli(["hdl", "verilog", "--top", "spw_codec", "--out", out])
        assert exc.value.field == "--out"
    assert [p.name for p in tmp_path.iterdir()] == ["a-file"]
    assert (tmp_path / "a-file").read_text() == "keep me"


def test_a_failed_write_leaves_no_folder(tmp_path, monkeypatch):
    def fail(path, text):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(hdl_command, "atomic_write_text", fail)
    with pytest.raises(InputError) as exc:
        hdl_command.write_verilog("spw_codec", tmp_path / "a" / "b", {})
    assert exc.value.field == "--out" and "No space left" in exc.value.message
    assert list(tmp_path.iterdir()) == []


def test_out_must_be_a_folder(tmp_path):
    target = tmp_path / "file"
    target.write_text("keep me")
    with pytest.raises(InputError, match="not a folder"):
        hdl_command.write_verilog("spw_codec", target, {})
    assert target.read_text() == "keep me"


def test_tops_lists_the_codec(capsys):
    assert run_cli(["hdl", "tops"]) == 0
    assert "spw_codec" in capsys.readouterr().out
