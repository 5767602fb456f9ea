# amaranth: UnusedElaboratable=no
"""A clock per node (docs/clocks.md): the pysim harness and the compiled one give the same
outputs cycle for cycle with every node and the master port on clocks of their own, and the
per-node-clock harness with every offset and phase zero is the common clock's, bit for bit."""

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
