"""Line cuts on the model backend's link (cosim/model_link.py): what is lost, what is counted."""

import pytest

from mrm_cosim.cosim.closed_loop import PERMANENT, LineFault
from mrm_cosim.cosim.model_link import (
    _FIRST_HOP, _HOP, DISCONNECT_CYCLES, RESTART_CYCLES, LinkTiming, frame_cycles,
)
from mrm_cosim.master.cycle import Send
from mrm_cosim.protocol.packet import BROADCAST, PacketType


def packet(dest: int, size: int = 1) -> Send:
    return Send("packet", dest, int(PacketType.COMM_A), bytes(size), 1)


def delivered(link: LinkTiming) -> list[int]:
    """Nodes (1-based) with something in their inbox (emptied)."""
    out = [k + 1 for k, box in enumerate(link.inbox) if box]
    for box in link.inbox:
        box.clear()
    return out


def test_a_cut_line_loses_what_crosses_it_and_only_that():
    """Line 2 cut at 10,000 for 500 cycles: a broadcast reaches node 1 but not nodes 2 and 3
    while the line is down and until the link is back in Run; before and after, all."""
    link = LinkTiming(3)
    link.cut(2, 10_000, 500)
    link.send(packet(BROADCAST), 5_000)
    assert delivered(link) == [1, 2, 3]
    link.send(packet(BROADCAST), 10_000)
    assert delivered(link) == [1]
    assert not [e for e in link.errors if e[2] == "router"]   # (lost on the line)
    back = 10_000 + 500 + RESTART_CYCLES
    link.send(packet(3), back - 400)                    # still restarting when it passes:
    assert delivered(link) == []                        # node 1 discards it, and counts it
    assert [e[1:] for e in link.errors if e[2] == "router"] == [(1, "router")]
    link.send(packet(BROADCAST), back - 30)             # a broadcast: node 1 keeps its copy
    assert delivered(link) == [1]                       # and sends none down (uncounted)
    assert len([e for e in link.errors if e[2] == "router"]) == 1
    link.send(packet(BROADCAST), back)
    assert delivered(link) == [1, 2, 3]
    assert link.lost == 2 * 2 + 1                       # two broadcasts (nodes 2, 3), one more


def test_the_master_port_holds_its_packets_while_line_1_is_down():
    """Line 1 not running: the master port's FIFO keeps the packets (in order) and sends them
    when the link is back in Run; its time-codes are not sent."""
    link = LinkTiming(2)
    link.cut(1, 1_000, 2_000)
    back = 1_000 + 2_000 + RESTART_CYCLES
    link.send(packet(1), 1_000 + DISCONNECT_CYCLES + 5)
    link.send(Send("timecode", time=3), 1_500)
    link.send(packet(2), 1_600)
    assert [e[0] > back for e in link.inbox[0] + link.inbox[1]] == [True, True]
    assert [e[2] for e in link.inbox[0] + link.inbox[1]] == ["packet", "packet"]
    assert link.inbox[0][0][0] < link.inbox[1][0][0]


def test_a_packet_in_flight_when_the_line_fails_is_lost():
    """Characters on the line when it is cut are lost: the last one reaches node 2 after the
    cut began though the packet left before it."""
    link = LinkTiming(3)
    size = 40
    arrive = 1_000 + frame_cycles(size) + _FIRST_HOP + _HOP      # its last byte at node 2
    link.cut(2, arrive - 20, 1)
    link.send(packet(2, size), 1_000)
    assert delivered(link) == []


def test_replies_and_timecodes_across_a_cut_are_lost():
    link = LinkTiming(3)
    link.cut(1, 2_000, PERMANENT)
    link.reply(2, 1_000, int(PacketType.COMM_A), bytes(40), 1)    # before: reaches the master
    link.reply(2, 2_100, int(PacketType.COMM_A), bytes(40), 2)    # after: node 1 drops it
    assert [r[4] for r in link.replies_before(10**9)] == [1]
    assert (2_100, 1, "router") in link.errors
    link.send(Send("timecode", time=5), 3_000)
    assert delivered(link) == []


def test_each_end_of_a_cut_line_counts_one_error_after_the_disconnect_time():
    link = LinkTiming(3)
    link.cut(1, 100, 10)
    link.cut(3, 700, 10)
    assert sorted(link.errors) == sorted([
        (100 + DISCONNECT_CYCLES, 1, "up"), (100 + DISCONNECT_CYCLES, 0, "down"),
        (700 + DISCONNECT_CYCLES, 3, "up"), (700 + DISCONNECT_CYCLES, 2, "down")])
    with pytest.raises(ValueError):
        link.cut(4, 0, 1)


def test_the_fault_spec_is_the_gateware_backends_and_inf_is_permanent():
    f = LineFault.parse("cut:down:1@0.5s+inf")
    assert (f.node, f.direction, f.kind, f.cycle, f.cycles) == (1, "down", "cut", 25_000_000,
                                                                PERMANENT)
    assert LineFault.parse("cut:up:2@1ms+5ms").cycles == 250_000


def test_the_model_backend_refuses_faults_it_cannot_model():
    from mrm_cosim.cosim.model import ModelBackend
    from mrm_cosim.errors import InputError

    with pytest.raises(InputError) as e:
        ModelBackend(faults=[LineFault.parse("bit:up:1@1ms")])
    assert e.value.field == "faults"
