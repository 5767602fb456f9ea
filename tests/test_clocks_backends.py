# amaranth: UnusedElaboratable=no
"""A clock per node (docs/clocks.md): the pysim harness and the compiled one give the same
outputs cycle for cycle with every node and the master port on clocks of their own, and the
per-node-clock harness with every offset and phase zero is the common clock's, bit for bit."""

import bisect
from pathlib import Path

import numpy as np
import pytest

from mrm_cosim.cosim.backends import CompiledBackend, PysimBackend
from mrm_cosim.cosim.clocks import ClockPlan
from mrm_cosim.cosim.gateware_side import PlantLines
from mrm_cosim.cosim.track import loop_system, loop_system_key
from mrm_cosim.master.cycle import Send
from mrm_cosim.models.robot import load_robot
from mrm_cosim.protocol import packet as ref
from mrm_cosim.protocol.link import DEFAULT_SLOTS

ROBOT = load_robot("mrm3")
#: ±100 ppm, phases anywhere in the cycle (master port first)
PLAN = ClockPlan.from_ppm([-61.4, 97.0, -100.0, 38.2], [0.0, 0.83, 0.351, 0.6],
                          DEFAULT_SLOTS)


async def exchange(be, cycles: int, chunk: int = 200):
    """Bring the links up, then a time-code and a Comm A request to every node; ``cycles``
    master cycles in all. Returns what reached the master."""
    be.power_on([0] * ROBOT.n)
    rest = PlantLines(counts=[5, -3, 7])
    seen, sent, done = [], False, 0
    while done < cycles:
        if be.link_up and not sent:
            be.send(Send("timecode", time=1))
            be.send(Send("packet", ref.BROADCAST, int(ref.PacketType.COMM_A), b"\0", 1))
            sent = True
        n = min(chunk, cycles - done)
        seen.append(await be.advance(n, rest))
        done += n
    return seen


def run(be, cycles):
    return be.execute(exchange(be, cycles))


@pytest.fixture(scope="module")
def compiled_node_clocks():
    return lambda plan: CompiledBackend(lambda: loop_system(ROBOT, "node"),
                                        loop_system_key(ROBOT, "node"), record=True,
                                        clocks=plan)


def test_pysim_and_compiled_agree_with_a_clock_per_node(compiled_node_clocks):
    cycles = 2_600                      # link up at ~1,100, replies of all three by ~2,400
    pysim = PysimBackend(loop_system(ROBOT, "node"), record=True, clocks=PLAN)
    a = run(pysim, cycles)
    comp = compiled_node_clocks(PLAN)
    b = run(comp, cycles)
    assert pysim.samples.keys() == comp.samples.keys()
    for name in pysim.samples:
        np.testing.assert_array_equal(pysim.trace(name), comp.trace(name), err_msg=name)
    assert a == b
    replies = [r for o in b for r in o.replies]
    assert sorted(r.src for r in replies if r.ptype == ref.PacketType.COMM_A) == [1, 2, 3]
    events = {(node, name) for o in b for _c, node, name in o.events}
    assert {(k, "TIMECODE") for k in (1, 2, 3)} <= events
    assert comp.link_errors == 0 and comp.crc_errors == 0
    assert comp.merged_strobes == pysim.merged_strobes


def test_zero_offsets_are_the_common_clock(compiled_node_clocks):
    cycles = 2_600
    common = CompiledBackend(lambda: loop_system(ROBOT), loop_system_key(ROBOT), record=True)
    a = run(common, cycles)
    zero = compiled_node_clocks(ClockPlan.from_ppm([0] * 4, [0] * 4, DEFAULT_SLOTS))
    b = run(zero, cycles)
    assert a == b
    for name in common.samples:
        np.testing.assert_array_equal(common.trace(name), zero.trace(name), err_msg=name)
    # and a clock 100 ppm off is not (the test can fail)
    off = compiled_node_clocks(ClockPlan.from_ppm([0, 100, 0, 0], [0] * 4, DEFAULT_SLOTS))
    c = run(off, cycles)
    assert any(not np.array_equal(common.trace(n), off.trace(n)) for n in common.samples)
    assert [r.src for o in c for r in o.replies] == [r.src for o in a for r in o.replies]


def _vcd_changes(path, drop: int) -> dict[str, list[tuple[int, int]]]:
    """``{dotted name: [(time, value), ...]}`` of a VCD's ``wire`` variables (names below
    ``drop`` outer scopes, a leading backslash escape removed); enum strings are skipped.
    Written here because pyvcd's reader refuses the escaped names Amaranth's writer uses."""
    scope, ids, out, t = [], {}, {}, 0
    toks = Path(path).read_text().split()
    i = 0
    while i < len(toks):
        k = toks[i]
        if k == "$scope":
            scope.append(toks[i + 2])
            i = toks.index("$end", i) + 1
        elif k == "$upscope":
            scope.pop()
            i += 2
        elif k == "$var":
            end = toks.index("$end", i)
            vtype, _size, ident, name = toks[i + 1:i + 5]
            if vtype == "wire":
                dotted = ".".join([*scope[drop:], name.lstrip("\\")])
                ids.setdefault(ident, []).append(dotted)
                out[dotted] = []
            i = end + 1
        elif k in ("$comment", "$date", "$timescale", "$version"):
            i = toks.index("$end", i) + 1
        elif k.startswith("$"):
            i += 1
        elif k[0] == "#":
            t = int(k[1:])
            i += 1
        elif k[0] in "sSrR":                     # string (enum names), real: not compared
            i += 2
        else:
            if k[0] in "bB":
                ident, v = toks[i + 1], k[1:]
                i += 2
            else:
                ident, v = k[1:], k[0]
                i += 1
            for name in ids.get(ident, ()):
                out[name].append((t, int(v, 2) if set(v) <= {"0", "1"} else v))
    return out


def test_pysim_waveform_with_a_clock_per_node_is_the_simulators_own(tmp_path):
    """pysim's waveform with clocks of their own (docs/clocks.md): one sample per instant
    with a rising edge, stamped in femtoseconds, each domain's registers changing at its own
    edges. Checked against Amaranth's own VCD writer on the same run: at every stamp, every
    signal in the window has the value Amaranth recorded for that time."""
    from mrm_cosim.cosim.backends import VcdWindow

    window = VcdWindow(150, 330, tmp_path / "w.vcd", "*")
    be = PysimBackend(loop_system(ROBOT, "node"), vcd=window, clocks=PLAN)
    sim = be.simulator()

    async def bench(ctx):
        be.bind(ctx)
        await exchange(be, 360)

    sim.add_testbench(bench)
    with sim.write_vcd(str(tmp_path / "amaranth.vcd")):
        sim.run()
    ours = _vcd_changes(window.path, drop=1)
    theirs = _vcd_changes(tmp_path / "amaranth.vcd", drop=2)    # bench.top.…
    head = window.path.read_text()[:200]
    assert "$timescale 1fs $end" in head
    assert not any(name.endswith("_clk") or name == "clk" for name in ours)
    stamps = sorted({t for changes in ours.values() for t, _v in changes})
    # every edge of the four clocks in the window, at its own time
    edges = set()
    for d in range(PLAN.n_domains):
        P, phi = PLAN.periods[d], PLAN.phases[d]
        edges |= {phi + (c + 1) * P for c in range(500)}
    t0 = PLAN.phases[0] + 150 * PLAN.periods[0]
    t1 = PLAN.phases[0] + 330 * PLAN.periods[0]
    assert set(stamps) <= edges
    assert len(stamps) >= 4 * 170
    assert t0 <= stamps[0] and stamps[-1] <= t1 + PLAN.periods[0]
    # the node domains' registers change between the master's edges
    assert any(t not in {PLAN.phases[0] + (c + 1) * PLAN.periods[0] for c in range(500)}
               for t, _v in ours["node2.core.timer.phase"])
    compared = 0
    for name, changes in ours.items():
        if name not in theirs:
            continue
        times = [t for t, _v in theirs[name]]
        j, cur = 0, None
        for s in stamps:
            while j < len(changes) and changes[j][0] <= s:
                cur = changes[j][1]
                j += 1
            k = bisect.bisect_right(times, s) - 1
            assert cur == (theirs[name][k][1] if k >= 0 else None), (name, s)
        compared += 1
    assert compared > 0.95 * len(ours)
