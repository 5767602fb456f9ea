# amaranth: UnusedElaboratable=no
"""The nodes' observation port (NodeCore.events) in the closed loop: what each node did and when,
per period, on the 20 ns grid — its order and durations on the compiled gateware, the model
backend's approximation of it, and the Gantt timeline drawn from it (issue 5)."""

import re
from pathlib import Path

import pytest

from mrm_cosim.cosim import plots
from mrm_cosim.cosim.model_link import EVENT_TOLERANCE
from mrm_cosim.cosim.track import _phases_us
from mrm_cosim.protocol.isa import LATENCY, Op
from mrm_cosim.protocol.regs import NodeEvent
from mrm_cosim.protocol.vdc_program import vdc_microcode

from .test_model_backend import _loop

CYCLES = 150_000            # 3 ms after period 0: three A/B/C/D exchanges
N = 3


@pytest.fixture(scope="module")
def runs():
    """mrm3, VDC, the 25 Hz swing of tests/test_model_backend.py, on both backends."""
    out = {}
    for backend in ("compiled", "model"):
        result, master = _loop(backend, "vdc", CYCLES)
        out[backend] = (result, master)
    return out


def _complete(master):
    recs = [r for r in master.records if r.complete]
    assert len(recs) == 3
    return recs


def _program_cycles():
    """(start → MARK, start → END) of each VDC entry, read off the compiled program: one cycle
    to fetch, one per instruction up to the MARK / END, then the pipeline's LATENCY."""
    mc = vdc_microcode()
    out = {}
    for entry in ("first", "main"):
        start, end = mc.entries[entry], mc.ends[entry]
        mark = next(a for a in range(start, end) if mc.instrs[a].op == Op.MARK)
        out[entry] = (mark - start + 1 + LATENCY, end - start + 1 + LATENCY)
    return out


def test_every_node_reports_every_event_once_per_period(runs):
    _, master = runs["compiled"]
    # no resync on the master's grid, no primitive generator in this run
    names = {f.name for f in NodeEvent} - {"RESYNC", "DMP_STEP"}
    for rec in _complete(master):
        assert {(name, k) for name in names for k in range(1, N + 1)} == set(rec.node_events)
        for c in rec.node_events.values():
            assert rec.start <= c < rec.start + master.timing.period_cycles


def test_order_of_a_period_on_the_gateware(runs):
    """Per node: boundary at the period start on the nodes' timer grid; the Comm A request
    taken, its reply leaving, then complete at the master; Comm B taken before the VDC starts,
    the forces (MARK) before the Comm C reply leaves, which is before it is complete at the
    master; Comm D taken before the commit phase, at which it takes effect."""
    _, master = runs["compiled"]
    period = master.timing.period_cycles
    for rec in _complete(master):
        ev = rec.node_events
        assert rec.start % period == 0
        for k in range(1, N + 1):
            def at(name, k=k, ev=ev):
                return ev[(name, k)]
            assert at("BOUNDARY") == rec.start
            assert at("BOUNDARY") < at("TIMECODE") < at("RX_A") < at("TX_A") \
                < rec.arrivals[("A", k)] <= rec.events["A_done"]
            assert rec.events["B_sent"] < at("RX_B") < at("VDC_START") < at("VDC_DONE") \
                <= at("TX_C") < rec.arrivals[("C", k)] <= rec.events["C_done"]
            assert at("RX_C") < at("TX_C")
            assert at("VDC_DONE") < at("VDC_END")
            assert rec.events["D_sent"] < at("RX_D") < at("COMMIT")
            # the commit point is the configured phase (cosim default: a fifth of the period)
            assert at("COMMIT") - rec.start == period // 5
        # the replies come back in node order over the shared upstream link
        assert [rec.arrivals[("C", k)] for k in range(1, N + 1)] == \
            sorted(rec.arrivals[("C", k)] for k in range(1, N + 1))


def test_vdc_compute_takes_the_programs_cycle_count(runs):
    """VDC_START → VDC_DONE is the program's cycles to its MARK, VDC_START → VDC_END to its
    END: "first" in period 0 (the master primes the derivative history), "main" after."""
    _, master = runs["compiled"]
    cycles = _program_cycles()
    for rec in _complete(master):
        mark, end = cycles["first" if rec.index == 0 else "main"]
        for k in range(1, N + 1):
            start = rec.node_events[("VDC_START", k)]
            assert rec.node_events[("VDC_DONE", k)] - start == mark
            assert rec.node_events[("VDC_END", k)] - start == end
    # the figures docs/node.md gives for the program are these
    text = (Path(__file__).parents[1] / "docs" / "node.md").read_text()
    row = re.search(r"\| VDC `main` .*?\| \*\*(\d+)\*\* to MARK .*?\| (\d+) = ", text)
    assert (int(row.group(1)), int(row.group(2))) == cycles["main"]


def test_track_summary_reports_node_compute_and_commit(runs):
    _, master = runs["compiled"]
    phases = _phases_us(master)
    cycles = _program_cycles()
    marks = [cycles["first" if r.index == 0 else "main"][0] for r in _complete(master)]
    assert phases["node_compute"] == [pytest.approx(sum(marks) / len(marks) / 50.0)] * N
    assert phases["commit"] == [pytest.approx(master.timing.period_cycles // 5 / 50.0)] * N
    assert {"A", "B", "C", "D", "cycle"} <= set(phases)


def test_model_events_lie_within_the_stated_tolerance(runs):
    """The model backend's node events against the gateware's: the boundary, the commit and
    the VDC's durations exactly (the node's timer and program), the rest within
    EVENT_TOLERANCE cycles (the modelled link latency; both loops send the master's packets
    at the cycle they are due, so no event is a whole plant step apart)."""
    (_, m_c), (model, m_m) = runs["compiled"], runs["model"]
    assert model.violations == []
    worst = 0
    for rc, rm in zip(_complete(m_c), _complete(m_m), strict=True):
        assert rc.start == rm.start
        for name in ("B_sent", "D_sent"):
            assert abs(rc.events[name] - rm.events[name]) <= EVENT_TOLERANCE, name
        assert set(rc.node_events) == set(rm.node_events)
        for key, c in rc.node_events.items():
            d = rm.node_events[key] - c
            if key[0] in ("BOUNDARY", "COMMIT"):
                assert d == 0, key
            assert abs(d) <= EVENT_TOLERANCE, (rc.index, key, d)
            worst = max(worst, abs(d))
        for k in range(1, N + 1):
            for first, last in (("VDC_START", "VDC_DONE"), ("VDC_START", "VDC_END")):
                assert rm.node_events[(last, k)] - rm.node_events[(first, k)] == \
                    rc.node_events[(last, k)] - rc.node_events[(first, k)]
        for key, c in rc.arrivals.items():
            assert abs(rm.arrivals[key] - c) <= EVENT_TOLERANCE, key
    assert worst > 0            # the latencies are modelled, not copied


def test_the_masters_packets_leave_when_they_are_due(runs):
    """Comm B and Comm D enter the master port at the cycle the master's modelled compute
    ends, not on the plant's 10 µs grid: node 1 takes them a frame's transfer later (40-byte
    payload: 48 characters at 150 Mbit/s, 3.1 µs, plus the hop and the core's delivery,
    about 1.1 µs), never the up to 500 cycles of a grid wait more. Every period's B and D
    compute ends off the grid here, so a loop that waited for it would fail."""
    _, master = runs["compiled"]
    for r in _complete(master):
        for sent, taken in (("B_sent", "RX_B"), ("D_sent", "RX_D")):
            assert (r.events[sent] - r.start) % 500 != 0
            assert 150 < r.node_events[(taken, 1)] - r.events[sent] < 250, (r.index, sent)


def test_gantt_draws_the_nodes_phases(runs, tmp_path):
    _, master = runs["compiled"]
    rec = _complete(master)[1]
    bars = plots.timeline_bars(rec, N)
    labels = ["A↓", "A↑", "B↓", "VDC", "adapt", "C↑", "D↓"]
    for k in range(1, N + 1):
        assert [b.label for b in bars if b.row == f"node {k}"] == labels
    got = {(b.row, b.label): (b.start_us, b.end_us) for b in bars}
    ev, ne = rec.node_events, rec.events

    def us(c):
        return (c - rec.start) / 50

    for k in range(1, N + 1):
        row = f"node {k}"
        assert got[(row, "A↓")] == (0.0, us(ev[("RX_A", k)]))
        assert got[(row, "A↑")] == (us(ev[("TX_A", k)]), us(rec.arrivals[("A", k)]))
        assert got[(row, "B↓")] == (us(ne["B_sent"]), us(ev[("RX_B", k)]))
        assert got[(row, "VDC")] == (us(ev[("VDC_START", k)]), us(ev[("VDC_DONE", k)]))
        assert got[(row, "C↑")] == (us(ev[("TX_C", k)]), us(rec.arrivals[("C", k)]))
        assert got[(row, "D↓")] == (us(ne["D_sent"]), us(ev[("RX_D", k)]))
        # the VDC bar is the program's 282 cycles to its MARK on the 20 ns grid
        start, end = got[(row, "VDC")]
        assert round((end - start) * 50) == _program_cycles()["main"][0]
    fig = plots.plot_timeline(tmp_path / "t.png", rec, N, 50_000, "period 1")
    (ax,) = fig.axes
    assert len(ax.collections) == len(bars)
    for coll, bar in zip(ax.collections, bars, strict=True):
        xs = coll.get_paths()[0].vertices[:, 0]
        assert (xs.min(), xs.max()) == pytest.approx((bar.start_us, bar.end_us))
    markers = plots.timeline_markers(rec, N)
    assert [(m.row, m.label) for m in markers] == [
        (f"node {k}", lab) for k in range(1, N + 1) for lab in ("boundary", "commit")]
    assert len(ax.lines) > len(markers)             # markers first, then the vertical lines
    for line, m in zip(ax.lines, markers, strict=False):
        assert tuple(line.get_xdata()) == (m.at_us,)
    assert [m.at_us for m in markers if m.label == "commit"] == [200.0] * N
    # slack: the period less the latest bar end (the last node's VDC program or Comm D)
    last = max(b.end_us for b in bars)
    assert f"slack to the period end {1000 - last:.2f} µs" in ax.get_xlabel()
