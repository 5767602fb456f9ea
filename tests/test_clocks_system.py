# amaranth: UnusedElaboratable=no
"""The per-node-clock System and its time base (docs/clocks.md): the common clock's design and
wrapper are today's; node clocks bring the hop lines out; the resampler in exact integers."""

import pytest
from amaranth.back import verilog

from mrm_cosim.cosim.clocks import NOMINAL_FS, ClockedEngine, ClockPlan, system_lines
from mrm_cosim.cosim.compiled import Port, _wrapper
from mrm_cosim.hdl.system import System


def test_the_common_clock_is_todays_system():
    s = System(1, clocks="common")
    assert s.node_domains == [] and not any("_clk" in p for p in s.verilog_ports())
    a = verilog.convert(s, name="system", emit_src=False)
    assert "down_d_out1" not in a and "n1_clk" not in a and "n1_" not in a


def test_node_clocks_bring_the_lines_out():
    s = System(1, clocks="node", line_faults=True)
    text = verilog.convert(s, name="system", emit_src=False, ports=s.verilog_ports())
    head = text[text.index("module system("):text.index(");")]
    for name in ("n1_clk", "clk", *{p for line in system_lines(1)
                                               for p in (line[0], line[2])}):
        assert f" {name}," in head or f"({name}," in head or f" {name}\n" in head, name
    with pytest.raises(ValueError, match="clocks"):
        System(2, clocks="per-node")


def test_every_port_keeps_its_signatures_direction():
    """``verilog_ports`` names the ports and leaves their directions to Amaranth (an output
    where the design drives it): each comes out as its signature member's flow says, the
    domains' clocks as inputs."""
    import re

    from amaranth.lib.wiring import In

    s = System(2, clocks="node", line_faults=True)
    text = verilog.convert(s, name="system", emit_src=False, ports=s.verilog_ports())
    top = text[text.index("module system("):]
    top = top[:top.index("endmodule")]
    declared = dict((name, kind) for kind, name in
                    re.findall(r"^\s*(input|output)\s+(?:\[[^\]]*\]\s*)?(\w+);", top, re.M))
    want = {"__".join(map(str, path)): "input" if member.flow == In else "output"
            for path, member, _ in s.signature.flatten(s)}
    want.update({f"{cd.name}_clk": "input" for cd in s.node_domains})
    assert want and {k: declared.get(k) for k in want} == want


def test_the_wrapper_of_one_clock_has_no_event_loop():
    ports = [Port("clk", 0, 1, False, "input"), Port("x", 1, 8, False, "output")]
    assert "mrm_clk_run" not in _wrapper("top", ports, False)
    clocked = [*ports, Port("n1_clk", 2, 1, False, "input")]
    assert "mrm_clk_run" in _wrapper("top", clocked, False)


def test_the_time_base():
    plan = ClockPlan.from_ppm([0, 100, -100.1], [0, 0.5, 0.9999999], 6)
    assert plan.periods == (NOMINAL_FS, NOMINAL_FS - 2000, NOMINAL_FS + 2000)
    assert all(p % 4 == 0 for p in plan.periods + plan.phases)
    assert plan.phases[:2] == (0, NOMINAL_FS // 2) and plan.phases[2] < plan.periods[2]


def test_the_resampler_takes_the_peer_level_at_the_start_of_each_slot():
    # sender (domain 0) with 6 slots; the receiver half a cycle late samples its word's upper
    # half, then the next word's lower half
    plan = ClockPlan((60, 60), (0, 30), 6)
    eng = ClockedEngine(plan, [("tx", 0, "rx", 1)])
    eng.hist[0] = {0: 0b000111, 1: 0b101000}
    eng.cycle = [1, 0]
    assert eng.level_word(0, 1) == 0b000_000   # bits 3..5 of 0b000111, bits 0..2 of 0b101000
    eng.hist[0] = {0: 0b111000, 1: 0b000101}
    assert eng.level_word(0, 1) == 0b101_111
    same = ClockedEngine(ClockPlan((60, 60), (0, 0), 6), [("tx", 0, "rx", 1)])
    same.hist[0] = {0: 0b100110}
    assert same.level_word(0, 1) == 0b100110
