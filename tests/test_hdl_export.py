# amaranth: UnusedElaboratable=no
"""What ``mrm hdl verilog`` writes beside the Verilog: lint waivers, clocks, the port list."""

import re

import pytest
from amaranth.hdl import Fragment

from mrm_cosim.hdl.export import LINT_WAIVERS, clock_constraints, lint_waivers, port_rows
from mrm_cosim.hdl.tops import TOPS, build_top
from mrm_cosim.mrm.commands import hdl as hdl_command


def _built(top: str, **params):
    """The top, elaborated (as the Verilog export does), so none of its parts goes unused."""
    component = build_top(top, **params)
    Fragment.get(component, None)
    return component


def _declared(text: str, top: str) -> dict[str, tuple[str, int]]:
    """``{port: (direction, width)}`` from the module's declarations in the Verilog."""
    body = text[text.index(f"module {top}("):]
    body = body[:body.index("endmodule")]
    out = {}
    for direction, msb, name in re.findall(r"^\s*(input|output)\s+(?:wire\s+|reg\s+)?"
                                           r"(?:signed\s+)?(?:\[(\d+):0\]\s+)?(\w+);",
                                           body, re.M):
        out[name] = (direction, int(msb) + 1 if msb else 1)
    return out


@pytest.mark.parametrize("top", ["spw_codec", "node"])
def test_port_list_matches_the_verilog(tmp_path, top):
    """Every port of the generated module, with the direction and width the Verilog declares,
    is in <top>.ports.md (and nothing else), each with a meaning from the docstrings."""
    path = hdl_command.write_verilog(top, tmp_path, {})
    declared = _declared(path.read_text(), top)
    rows = port_rows(_built(top))
    assert {name: (d, w) for name, d, w, _ in rows} == declared
    assert all(meaning for *_, meaning in rows), [r[0] for r in rows if not r[3]]
    table = path.with_suffix(".ports.md").read_text()
    for name, direction, width, _ in rows:
        assert f"| `{name}` | {direction} | {width} |" in table


def test_line_ports_say_how_many_samples_a_cycle():
    rows = {name: meaning for name, _, _, meaning in port_rows(_built("node", slots=2))}
    assert "2 samples per clk cycle" in rows["up__d_out"]
    assert rows["up__d_out"].startswith("Data-strobe line ports")


def test_clock_constraints_are_the_design_clock():
    c = clock_constraints("node")
    assert "create_clock -name clk -period 20.000 [get_ports {clk}]" in c["sdc"]
    assert 'FREQUENCY PORT "clk" 50.000000 MHz;' in c["lpf"]
    assert 'PERIOD "clk" 20 ns HIGH 50%' in c["ucf"]


def test_waivers_have_reasons_and_only_link_tops_waive_caseoverlap():
    for top in TOPS:
        waivers = lint_waivers(top)
        assert set(LINT_WAIVERS) <= set(waivers) and all(waivers.values())
        assert ("CASEOVERLAP" in waivers) == (top in ("link_node", "node", "system"))


def test_a_failed_write_leaves_no_partial_set(tmp_path, monkeypatch):
    """The fifth file fails to write: the four before it are removed again."""
    import mrm_cosim.mrm.commands.hdl as mod
    from mrm_cosim.errors import InputError

    real = mod.atomic_write_text
    calls = []

    def flaky(path, text):
        calls.append(path)
        if len(calls) == 5:
            raise OSError(28, "No space left on device")
        real(path, text)

    monkeypatch.setattr(mod, "atomic_write_text", flaky)
    out = tmp_path / "v"
    with pytest.raises(InputError) as e:
        hdl_command.write_verilog("spw_codec", out, {"slots": 1})
    assert e.value.field == "--out" and "No space left" in e.value.message
    assert not out.exists()


def test_the_command_says_what_it_wrote_and_how_to_lint_it(tmp_path, capsys):
    """``mrm hdl verilog`` prints the Verilog's path, each companion file with what it is, and
    the Verilator command that is clean with the shipped waivers (test_verilog_codec.py runs
    exactly that command)."""
    from mrm_cosim.mrm import cli
    assert cli.main(["hdl", "verilog", "--top", "spw_codec", "--out", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    v = tmp_path / "spw_codec.v"
    assert lines[0] == str(v)
    for suffix, what in hdl_command.COMPANIONS.items():
        f = tmp_path / f"spw_codec{suffix}"
        assert f.is_file() and f"{f}  ({what})" in lines
    assert lines[-1].endswith(f"verilator --lint-only -Wall {tmp_path / 'spw_codec.vlt'} {v}")
