"""Period-start skew (cosim/skew.py): offsets and statistics against hand-made strobes, and
what a run on one clock reports."""

import math

import numpy as np
import pytest

from mrm_cosim.cosim.skew import period_skew, start_offsets
from mrm_cosim.master.cycle import PeriodRecord

P = 50_000


def _records(starts_at=1000, periods=4):
    return [PeriodRecord(index=i, start=starts_at + i * P) for i in range(periods)]


def test_offsets_take_the_nearest_start_and_early_boundaries_count_negative():
    recs = _records()
    strobes = [(1000 + 0, 1), (1000 + 3, 2),                 # period 0: on time, 3 late
               (1000 + P - 5, 1),                             # node 1 five cycles early for 1
               (1000 + P + 2, 2),
               (1000 + 2 * P, 1),                             # period 2: node 2 missing
               (1000 + 3 * P - 1, 1), (1000 + 3 * P + 1, 2)]
    b = start_offsets(recs, 2, P, strobes=strobes)
    expect = np.array([[0, 3], [-5, 2], [0, np.nan], [-1, 1]])
    np.testing.assert_array_equal(b, expect)
    s = period_skew(recs, 2, P, strobes=strobes)
    assert s["periods"] == 4 and s["missing"] == 1
    nm = s["node_vs_master"]
    assert nm["max_abs_cycles"] == 5
    assert nm["rms_cycles"] == pytest.approx(math.sqrt((0 + 9 + 25 + 4 + 0 + 1 + 1) / 7))
    assert nm["max_abs_ns"] == 100.0
    assert nm["per_node"][0]["max_abs_cycles"] == 5 and nm["per_node"][1]["max_abs_cycles"] == 3
    # spreads of the complete periods: 3, 7, 2
    bn = s["between_nodes"]
    assert bn["max_cycles"] == 7
    assert bn["rms_cycles"] == pytest.approx(math.sqrt((9 + 49 + 4) / 3))


def test_without_every_strobe_the_records_first_ones_are_used():
    recs = _records(periods=2)
    recs[0].node_events = {("BOUNDARY", 1): 1000, ("TIMECODE", 1): 1012}
    recs[1].node_events = {("BOUNDARY", 1): 1000 + P + 4, ("TIMECODE", 1): 1000 + P + 12}
    s = period_skew(recs, 1, P)
    assert s["node_vs_master"]["per_node"][0]["max_abs_cycles"] == 4
    assert s["timecode_latency_cycles"] == [[12.0, 12.0]]
    assert s["missing"] == 0


def test_a_run_without_boundaries_reports_none():
    s = period_skew(_records(periods=2), 3, P)
    assert s["missing"] == 6
    assert s["node_vs_master"]["max_abs_cycles"] is None
    assert s["between_nodes"]["max_cycles"] is None
    assert s["timecode_latency_cycles"] == [None, None, None]


def test_one_clock_one_reset_every_period_starts_together():
    """Today's simulation (one 50 MHz clock, one reset): every node's boundary on the master's
    period start, the time-code 12 cycles a hop down the chain."""
    from mrm_cosim.cosim.track import run_track

    result, summary = run_track("mrm3", "vdc", "model", duration=0.005)
    s = summary["period_skew"]
    assert s["periods"] >= 5 and s["missing"] == 0
    # the master kept every boundary, one per node per period
    assert len(result.master.boundary_strobes) == 3 * s["periods"]
    assert s["node_vs_master"]["max_abs_cycles"] == 0
    assert s["between_nodes"]["max_cycles"] == 0
    lat = s["timecode_latency_cycles"]
    assert lat[0][0] == lat[0][1] > 0
    assert lat[1][0] - lat[0][0] == lat[2][0] - lat[1][0] > 0     # the same hop delay


def test_the_master_keeps_every_boundary_a_record_would_drop():
    """A record keeps each period's first strobe of a name; an early boundary of the next
    period lands in the same record after the on-time one. The master's
    ``boundary_strobes`` keeps both, so the skew sees the early start (−5), not a gap."""
    from mrm_cosim.master.cycle import Master
    from mrm_cosim.models.robot import load_robot

    robot = load_robot("mrm3")
    master = Master(robot, "pid-fpga", lambda t: (np.zeros(3),) * 3, robot.counts_per_rev)
    master.begin(1000)
    master.records = _records(periods=2)
    master.on_node_events([(1000, 1, "BOUNDARY"), (1000 + P - 5, 1, "BOUNDARY"),
                           (1000 + P - 5, 1, "RX_A")])
    assert master.boundary_strobes == [(1000, 1), (1000 + P - 5, 1)]
    assert master.records[0].node_events[("BOUNDARY", 1)] == 1000        # the first only
    with_all = period_skew(master.records, 1, P, strobes=master.boundary_strobes)
    firsts = period_skew(master.records, 1, P)
    assert with_all["missing"] == 0 and with_all["node_vs_master"]["max_abs_cycles"] == 5
    assert firsts["missing"] == 1


def test_period_zeros_early_boundary_is_kept():
    """A node whose clock runs early starts period 0 a few cycles before the master does:
    strobed before :meth:`Master.begin` (or before the start, after it), it is kept if it lies
    within half a period of period 0's start — older boundaries are earlier periods'."""
    from mrm_cosim.master.cycle import Master
    from mrm_cosim.models.robot import load_robot

    robot = load_robot("mrm3")
    master = Master(robot, "pid-fpga", lambda t: (np.zeros(3),) * 3, robot.counts_per_rev)
    master.on_node_events([(1000 - P, 1, "BOUNDARY"), (1000 - 7, 1, "BOUNDARY"),
                           (1000 - 7, 1, "RX_A")])
    master.begin(1000)
    master.on_node_events([(1000 - 3, 2, "BOUNDARY"), (1000 - P // 2 - 1, 3, "BOUNDARY")])
    assert master.boundary_strobes == [(1000 - 7, 1), (1000 - 3, 2)]
    master.records = _records(periods=1)
    b = start_offsets(master.records, 3, P, strobes=master.boundary_strobes)
    assert b[0, :2].tolist() == [-7, -3] and np.isnan(b[0, 2])
