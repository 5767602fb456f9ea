"""The master's reply checks: the upload CRC and count of every Comm A against the uploads
(issue 5), replies to an earlier request (late), duplicates, and a Comm D that missed its
period. The nodes' replies come from the node reference (NodeModel, equal to the gateware:
tests/test_node_core.py)."""

import numpy as np

from mrm_cosim.hdl.node.core_ref import NodeModel
from mrm_cosim.master.cycle import Master, MasterTiming
from mrm_cosim.master.uploads import Gains, node_uploads, pid_shifts
from mrm_cosim.models.robot import load_robot
from mrm_cosim.protocol.crc import crc16
from mrm_cosim.protocol.packet import BROADCAST, PacketType
from mrm_cosim.protocol.regs import Config, config_payloads, parse_comm_a

ROBOT = load_robot("mrm3")


def _master(controller="pid-fpga", uploads=None, timing=None):
    z = np.zeros(ROBOT.n)
    return Master(ROBOT, controller, lambda t: (z, z, z), ROBOT.counts_per_rev,
                  timing or MasterTiming(), uploads=uploads)


def _nodes(uploads, skip=None):
    """NodeModels that took ``uploads`` (all but index ``skip`` of the list)."""
    nodes = [NodeModel() for _ in range(ROBOT.n)]
    for i, (dest, ptype, payload) in enumerate(uploads):
        if i == skip:
            continue
        for k, node in enumerate(nodes):
            if dest in (k + 1, BROADCAST):
                node.packet(10 + i, ptype, payload)
    return nodes


def _period(master, nodes, now, seqs=None):
    """Start the period due at ``now``; every node answers the Comm A request."""
    out = master.poll(now)
    tc = next(s for s in out if s.kind == "timecode")
    req = next(s for s in out if s.kind == "packet" and s.ptype == PacketType.COMM_A)
    replies = [n.packet(now + 1, PacketType.COMM_A, b"\0", period=tc.time) for n in nodes]
    for k, r in enumerate(replies):
        master.on_packet(now + 100 + k, k + 1, PacketType.COMM_A, r,
                         seq=req.seq if seqs is None else seqs[k])
    return replies


def _uploads():
    ups = node_uploads(ROBOT, "pid-fpga", Gains())
    # a broadcast upload reaches (and is expected from) every node
    ups += [(BROADCAST, PacketType.CONFIG, p) for p in config_payloads({Config.RAMP: 7})]
    # Comm D is not an upload
    return ups + [(1, PacketType.COMM_D, bytes(40))]


def test_expected_uploads_are_the_crc_of_each_nodes_payloads():
    ups = _uploads()
    m = _master(uploads=ups)
    for k in range(1, ROBOT.n + 1):
        mine = [p for d, t, p in ups if d in (k, BROADCAST) and
                t in (PacketType.CONFIG, PacketType.PARAM)]
        assert m.expected_uploads[k] == (crc16(b"".join(mine)), len(mine))
        assert len(mine) > 10
    assert len({v for v in m.expected_uploads.values()}) == ROBOT.n


def test_every_comm_a_is_checked_and_a_lost_upload_is_counted_on_its_node():
    ups = _uploads()
    lost = next(i for i, (d, t, _) in enumerate(ups) if d == 2 and t == PacketType.PARAM)
    m = _master(uploads=ups)
    m.begin(0)
    nodes = _nodes(ups, skip=lost)
    for p in range(3):
        now = p * m.timing.period_cycles
        replies = _period(m, nodes, now)
        m.poll(now + 5_000)                     # the Comm D goes out
        a = parse_comm_a(replies[1])
        assert (a["upload_crc"], a["upload_count"]) != m.expected_uploads[2]
        assert a["upload_count"] == m.expected_uploads[2][1] - 1
    assert m.upload_errors == {1: 0, 2: 3, 3: 0}
    assert m.upload_error_total() == 3
    assert (m.overruns, m.missing, m.unexpected, m.late) == (0, 0, 0, 0)

    # all uploads taken: no error; without an expectation: nothing checked
    for uploads, nodes in ((ups, _nodes(ups)), (None, _nodes(ups, skip=lost))):
        m = _master(uploads=uploads)
        m.begin(0)
        _period(m, nodes, 0)
        assert m.upload_error_total() == 0

    # a corrupted upload (one bit) is caught too
    bad = list(ups)
    d, t, p = bad[lost]
    bad[lost] = (d, t, p[:5] + bytes([p[5] ^ 0x10]) + p[6:])
    m = _master(uploads=ups)
    m.begin(0)
    _period(m, _nodes(bad), 0)
    assert m.upload_errors == {1: 0, 2: 1, 3: 0}


def test_late_duplicate_and_stale_replies_are_counted_not_used():
    ups = _uploads()
    nodes = _nodes(ups)
    m = _master(uploads=ups)
    m.begin(0)
    P = m.timing.period_cycles
    old = _period(m, nodes, 0)
    m.poll(5_000)
    # a reply to the old request arriving in the next period: wrong sequence number, and
    # (without one) the wrong period echoed
    out = m.poll(P)
    seq = next(s.seq for s in out if s.kind == "packet")
    m.on_packet(P + 10, 1, PacketType.COMM_A, old[0], seq=(seq - 1) & 0xFF)
    m.on_packet(P + 11, 1, PacketType.COMM_A, old[0])
    assert m.late == 2 and 1 not in m._a
    # the real reply is taken; a second copy is unexpected
    r = nodes[0].packet(P + 20, PacketType.COMM_A, b"\0", period=1)
    m.on_packet(P + 30, 1, PacketType.COMM_A, r, seq=seq)
    m.on_packet(P + 31, 1, PacketType.COMM_A, r, seq=seq)
    assert m.unexpected == 1 and 1 in m._a
    # a malformed reply and one from no node are unexpected
    m.on_packet(P + 40, 2, PacketType.COMM_A, b"\0" * 7, seq=seq)
    m.on_packet(P + 41, ROBOT.n + 1, PacketType.COMM_A, r, seq=seq)
    assert m.unexpected == 3
    # the period ends with two replies missing
    m.poll(2 * P)
    assert (m.overruns, m.missing, m.late) == (1, ROBOT.n - 1, 2)


def test_a_comm_d_still_waiting_at_the_period_end_is_an_overrun():
    ups = _uploads()
    nodes = _nodes(ups)
    P = 2_000
    m = _master(uploads=ups, timing=MasterTiming(period_cycles=P, kinematics_cycles=1_990))
    m.begin(0)
    _period(m, nodes, 0)                        # replies at ~100: Comm D due at ~2,090
    assert m.records[0].complete
    m.poll(P)
    assert m.overruns == 1 and m.missing == 0 and not m.records[0].complete


def test_model_backend_run_reports_a_lost_upload():
    """End to end on the model backend: node 3 never gets one PARAM packet; the master, which
    expects the full list, counts every Comm A of node 3 and nothing else."""
    from mrm_cosim.cosim.closed_loop import ClosedLoop
    from mrm_cosim.cosim.model import ModelBackend
    from mrm_cosim.cosim.track import _trajectory
    from mrm_cosim.models.plant import Plant, PlantConfig

    gains = Gains()
    ups = node_uploads(ROBOT, "pid-fpga", gains)
    lost = max(i for i, (d, t, _) in enumerate(ups) if d == 3 and t == PacketType.PARAM)
    m = Master(ROBOT, "pid-fpga", _trajectory(ROBOT), ROBOT.counts_per_rev, uploads=ups)
    plant = Plant(ROBOT, PlantConfig(), seed=0)
    plant.reset(ROBOT.home)
    loop = ClosedLoop(ROBOT, ModelBackend(pid_shift=pid_shifts(ROBOT)), m, plant, 50_000,
                      ups[:lost] + ups[lost + 1:])
    loop.run(3 * 50_000)
    assert m.upload_errors[1] == m.upload_errors[2] == 0
    assert m.upload_errors[3] == len(m.records) == 3
    assert (m.overruns, m.missing, m.unexpected, m.late) == (0, 0, 0, 0)
