"""Plots: each writes a PNG and draws exactly the data it was given (checked on the axes);
a time series longer than four samples per drawn column through its M4 envelope."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose, assert_array_equal

from mrm_cosim.cosim import plots
from mrm_cosim.master.cycle import PeriodRecord

PNG = b"\x89PNG\r\n\x1a\n"


def _png(path):
    data = path.read_bytes()
    assert data[:8] == PNG
    return data


@pytest.fixture
def series():
    rng = np.random.default_rng(0)
    t = np.arange(50) * 1e-3
    q_d = np.cumsum(rng.normal(size=(50, 3)), axis=0) * 1e-3
    q = q_d + rng.normal(size=(50, 3)) * 1e-5
    tau = rng.normal(size=(50, 3))
    return t, q_d, q, tau


def test_tracking_draws_angles_errors_and_torques(tmp_path, series):
    t, q_d, q, tau = series
    fig = plots.plot_tracking(tmp_path / "t.png", t, q_d, q, tau, "title")
    _png(tmp_path / "t.png")
    ax_q, ax_e, ax_tau = fig.axes[:3]
    for k in range(3):
        assert_array_equal(ax_q.lines[2 * k].get_ydata(), q[:, k])
        assert_array_equal(ax_q.lines[2 * k + 1].get_ydata(), q_d[:, k])
        assert ax_q.lines[2 * k + 1].get_label() == f"q{k + 1} desired"
        assert_allclose(ax_e.lines[k].get_ydata(), 1e3 * (q_d[:, k] - q[:, k]), rtol=1e-15)
        assert_array_equal(ax_tau.lines[k].get_ydata(), tau[:, k])
        assert_array_equal(ax_tau.lines[k].get_xdata(), t)
    assert "mrad" in ax_e.get_ylabel()


def test_error_comparison_has_one_axis_per_joint_and_the_tip(tmp_path, series):
    t, q_d, q, _ = series
    errs = {"pid-1khz": 10 * (q_d - q), "vdc": q_d - q}
    tips = {"pid-1khz": np.linspace(0, 1e-3, 50), "vdc": np.linspace(0, 1e-4, 50)}
    fig = plots.plot_error_comparison(tmp_path / "e.png", t, errs, tips, "Fig. 5")
    _png(tmp_path / "e.png")
    assert len(fig.axes) == 4
    for k in range(3):
        assert [ln.get_label() for ln in fig.axes[k].lines] == ["pid-1khz", "vdc"]
        assert_allclose(fig.axes[k].lines[1].get_ydata(), 1e3 * errs["vdc"][:, k])
    assert_allclose(fig.axes[3].lines[0].get_ydata(), 1e3 * tips["pid-1khz"])
    assert "mm" in fig.axes[3].get_ylabel()


def test_joint_tracking_starts_with_the_desired_line(tmp_path, series):
    t, q_d, q, _ = series
    fig = plots.plot_joint_tracking(tmp_path / "f4.png", t, q_d, {"vdc": q}, "Fig. 4")
    _png(tmp_path / "f4.png")
    for k, ax in enumerate(fig.axes):
        assert ax.lines[0].get_label() == "desired"
        assert_array_equal(ax.lines[0].get_ydata(), q_d[:, k])
        assert_array_equal(ax.lines[1].get_ydata(), q[:, k])


def test_torques_with_peak_limits(tmp_path, series):
    t, _, _, tau = series
    peak = np.array([11.0, 28.0, 11.0])
    fig = plots.plot_torques(tmp_path / "tau.png", t, {"vdc": tau}, "τ", peak=peak)
    _png(tmp_path / "tau.png")
    for k, ax in enumerate(fig.axes):
        assert_array_equal(ax.lines[0].get_ydata(), tau[:, k])
        limits = sorted(float(ln.get_ydata()[0]) for ln in ax.lines[1:])
        assert limits == [-peak[k], peak[k]]


def test_parameters_without_estimates_say_why(tmp_path):
    note = "adaptation off (gains.adapt = 0)"
    fig = plots.plot_parameters(tmp_path / "p.png", note=note, title="vdc")
    _png(tmp_path / "p.png")
    (ax,) = fig.axes
    assert [tx.get_text() for tx in ax.texts] == [note]
    assert not ax.lines


def test_parameters_are_drawn_relative_to_their_start(tmp_path):
    t = np.arange(4) * 1e-3
    theta = np.array([[2.0, 0.0], [2.2, 0.0], [2.4, 1.0], [2.6, 2.0]])
    fig = plots.plot_parameters(tmp_path / "p.png", t, theta, ["m", "zero"])
    (ax,) = fig.axes
    assert_allclose(ax.lines[0].get_ydata(), [1.0, 1.1, 1.2, 1.3])
    assert_allclose(ax.lines[1].get_ydata(), [1.0, 1.0, 1.0, 1.0])   # 0 start: not divided


def _vdc_record():
    r = PeriodRecord(index=7, start=400_000, complete=True)
    r.arrivals = {("A", 1): 400_150, ("A", 2): 400_190, ("A", 3): 400_230,
                  ("C", 1): 402_401, ("C", 2): 402_350, ("C", 3): 402_310}
    r.events = {"A_done": 400_230, "B_sent": 401_230, "C_done": 402_401, "D_sent": 403_401}
    return r


def test_timeline_bars_follow_the_records_on_the_20ns_grid():
    bars = plots.timeline_bars(_vdc_record(), 3)
    got = {(b.row, b.label): (b.start_us, b.end_us) for b in bars}
    assert got == {
        ("master", "kinematics"): (4.6, 24.6),
        ("master", "forces"): (48.02, 68.02),
        ("node 1", "A"): (0.0, 3.0), ("node 2", "A"): (0.0, 3.8), ("node 3", "A"): (0.0, 4.6),
        ("node 1", "B→C"): (24.6, 48.02), ("node 2", "B→C"): (24.6, 47.0),
        ("node 3", "B→C"): (24.6, 46.2),
    }


def test_timeline_bars_of_a_pid_period_skip_b_and_c():
    r = PeriodRecord(index=2, start=100_000, complete=True)
    r.arrivals = {("A", 1): 100_100, ("A", 2): 100_125}
    r.events = {"A_done": 100_125, "D_sent": 101_125}
    bars = plots.timeline_bars(r, 2)
    assert [(b.row, b.label) for b in bars] == [
        ("master", "PID / references"), ("node 1", "A"), ("node 2", "A")]
    assert bars[0].end_us - bars[0].start_us == pytest.approx(20.0)


def test_timeline_bars_of_a_pid_period_from_the_nodes_events():
    """PID modes: per node A↓, A↑ and D↓ from the observation port, no B, VDC or C; the
    boundary and commit markers; the timeline JSON keeps the events per node."""
    from mrm_cosim.cosim.table2 import timeline_json

    r = PeriodRecord(index=2, start=100_000, complete=True)
    r.arrivals = {("A", 1): 100_200, ("A", 2): 100_355}
    r.events = {"A_done": 100_355, "D_sent": 101_355}
    r.node_events = {("BOUNDARY", 1): 100_000, ("RX_A", 1): 100_040, ("TX_A", 1): 100_041,
                     ("RX_D", 1): 102_210, ("COMMIT", 1): 110_000,
                     ("BOUNDARY", 2): 100_000, ("RX_A", 2): 100_050, ("TX_A", 2): 100_051,
                     ("RX_D", 2): 102_375, ("COMMIT", 2): 110_000,
                     ("VDC_START", 2): 100_300}      # not drawn in a PID period
    bars = plots.timeline_bars(r, 2)
    got = {(b.row, b.label): (b.start_us, b.end_us) for b in bars}
    assert got == {
        ("master", "PID / references"): (7.1, 27.1),
        ("node 1", "A↓"): (0.0, 0.8), ("node 1", "A↑"): (0.82, 4.0),
        ("node 1", "D↓"): (27.1, 44.2),
        ("node 2", "A↓"): (0.0, 1.0), ("node 2", "A↑"): (1.02, 7.1),
        ("node 2", "D↓"): (27.1, 47.5),
    }
    assert [(m.row, m.label, m.at_us) for m in plots.timeline_markers(r, 2)] == [
        ("node 1", "boundary", 0.0), ("node 1", "commit", 200.0),
        ("node 2", "boundary", 0.0), ("node 2", "commit", 200.0)]
    (j,) = timeline_json([r])
    assert j["node_events"]["2"] == {"BOUNDARY": 100_000, "RX_A": 100_050, "TX_A": 100_051,
                                     "VDC_START": 100_300, "RX_D": 102_375, "COMMIT": 110_000}
    assert list(j["node_events"]) == ["1", "2"]


def test_timeline_plot_rows_bars_and_slack(tmp_path):
    rec = _vdc_record()
    fig = plots.plot_timeline(tmp_path / "g.png", rec, 3, 50_000, "period 7")
    _png(tmp_path / "g.png")
    (ax,) = fig.axes
    assert [tl.get_text() for tl in ax.get_yticklabels()] == ["master", "node 1", "node 2",
                                                             "node 3"]
    bars = plots.timeline_bars(rec, 3)
    assert len(ax.collections) == len(bars)
    for coll, bar in zip(ax.collections, bars, strict=True):
        x0, x1 = coll.get_paths()[0].vertices[:, 0].min(), coll.get_paths()[0].vertices[:, 0].max()
        assert (x0, x1) == pytest.approx((bar.start_us, bar.end_us))
    assert "slack to the period end 931.98 µs" in ax.get_xlabel()
    assert ax.get_title() == "period 7"


def test_timeline_plot_states_the_runs_period_start_skew(tmp_path):
    from mrm_cosim.cosim.skew import period_skew

    recs = [PeriodRecord(i, 1000 + 50_000 * i) for i in range(3)]
    strobes = [(1000, 1), (1003, 2), (51_000 - 5, 1), (51_002, 2), (101_000, 1), (101_000, 2)]
    skew = period_skew(recs, 2, 50_000, strobes=strobes)
    fig = plots.plot_timeline(tmp_path / "g.png", _vdc_record(), 3, 50_000, "period 7",
                              skew=skew)
    title = fig.axes[0].get_title()
    assert title.startswith("period 7\nperiod starts over 3 periods")
    assert "nodes vs master: max 100 ns" in title and "between nodes: max 140 ns" in title


def test_pick_period_prefers_the_requested_time_among_complete_ones():
    recs = [PeriodRecord(i, 50_000 * i, complete=i != 5) for i in range(10)]
    assert plots.pick_period(recs, when=0.005).index in (4, 6)
    assert plots.pick_period(recs).index == 4           # 5th of the 9 complete ones
    with pytest.raises(ValueError):
        plots.pick_period([PeriodRecord(0, 0)])


def test_tool_errors_of_runs_of_different_lengths(tmp_path):
    """``run line --profile both`` without --duration: Ruckig's run is shorter than the
    trigonometric one, and the figure took one time grid for both (a ValueError after both
    runs had finished). Each run is drawn on its own grid."""
    from mrm_cosim.master.cartesian import ToolErrors

    def errors(k):
        t = np.arange(k) * 1e-5
        z = np.zeros((k, 3))
        return t, ToolErrors(position_mm=t * 2, orientation_mrad=t, se3=t / 3,
                             tool_desired=z, tool_actual=z)

    fig = plots.plot_tool_errors(tmp_path / "e.png", {"trig": errors(300), "ruckig": errors(200)},
                                 "two lengths")
    lines = fig.axes[0].get_lines()
    assert [len(line.get_xdata()) for line in lines] == [300, 200]
    assert (tmp_path / "e.png").stat().st_size > 0


def test_safe_stop_plot_shows_each_joint_from_the_cut_and_the_engagement(tmp_path):
    t = np.arange(100) * 1e-3
    q = np.outer(t, [1.0, 2.0])
    engaged = np.zeros((100, 2), dtype=bool)
    engaged[60:] = True
    fig = plots.plot_safe_stop(tmp_path / "s.png", t, {"run": (q, engaged)}, 0.05, "stop",
                               bound=1e-3)
    assert (tmp_path / "s.png").exists()
    ax = fig.axes[1]
    line = ax.get_lines()[0]
    np.testing.assert_allclose(line.get_ydata(), 1e3 * (q[:, 1] - q[50, 1]))
    xs = sorted(float(np.atleast_1d(v.get_xdata())[0]) for v in ax.get_lines()[1:])
    assert xs == [0.05, t[60]]


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 30_000), columns=st.integers(1, 700), seed=st.integers(0, 2**32 - 1))
def test_the_envelope_keeps_every_runs_extremes_in_time_order(n, columns, seed):
    """:func:`envelope` (M4): a long series keeps, for each of ``columns`` runs of consecutive
    samples, its first, last, lowest and highest sample, and nothing else, in time order; a
    series of at most ``4 · columns`` samples is drawn whole."""
    from mrm_cosim.cosim.plots import envelope

    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-5
    y = np.cumsum(rng.standard_normal(n))
    te, ye = envelope(t, y, columns)
    if n <= 4 * columns:
        assert te is t and ye is y
        return
    assert len(te) <= 4 * columns
    kept = np.rint(te / 1e-5).astype(int)
    assert np.all(np.diff(kept) > 0)                        # time order, no repeats
    assert_array_equal(ye, y[kept])
    edges = (np.arange(columns + 1) * n) // columns
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        inside = ye[(kept >= a) & (kept < b)]
        assert {a, b - 1} <= set(kept.tolist())
        assert inside.min() == y[a:b].min() and inside.max() == y[a:b].max()
        assert len(inside) <= 4


def test_a_long_run_is_drawn_through_its_envelope(tmp_path):
    """A 1.2 s run (120,000 plant steps) is drawn as its envelope: at most 4 samples per
    column, every extreme of the error kept."""
    from mrm_cosim.cosim.plots import ENVELOPE_COLUMNS, envelope

    n = 120_000
    t = np.arange(n) * 1e-5
    q_d = np.outer(np.sin(2 * np.pi * t), [1.0, 2.0])
    q = q_d + 1e-4 * np.outer(np.sin(2 * np.pi * 977 * t), [1.0, -1.0])
    q[54_321, 1] += 0.01                                    # one spike
    tau = np.outer(np.cos(t), [1.0, 1.0])
    fig = plots.plot_tracking(tmp_path / "t.png", t, q_d, q, tau, "long")
    err = fig.axes[1].lines[1]
    assert len(err.get_xdata()) <= 4 * ENVELOPE_COLUMNS
    assert err.get_ydata().min() == (1e3 * (q_d[:, 1] - q[:, 1])).min()     # the spike
    assert_array_equal(err.get_ydata(), envelope(t, 1e3 * (q_d[:, 1] - q[:, 1]))[1])


def test_skew_plot_draws_each_nodes_offsets_in_ns_per_run(tmp_path):
    """One panel per run in order, one line per node whose data are the offsets in ns (20 ns a
    cycle), a gap where a period had no boundary, the run's worst |offset| in the title."""
    on = np.array([[1.0, -2.0], [np.nan, 3.0], [0.5, -4.0]])
    off = np.array([[0.0, 0.0], [-50.0, 2.0], [-100.0, 4.0]])
    fig = plots.plot_skew(tmp_path / "s.png", {"on": on, "off": off}, "skew")
    assert (tmp_path / "s.png").stat().st_size > 0
    ax_on, ax_off = fig.axes
    for ax, b in ((ax_on, on), (ax_off, off)):
        lines = [ln for ln in ax.get_lines() if ln.get_label().startswith("node")]
        assert [ln.get_label() for ln in lines] == ["node 1", "node 2"]
        for k, ln in enumerate(lines):
            np.testing.assert_array_equal(ln.get_ydata(), b[:, k] * 20.0)
            np.testing.assert_allclose(ln.get_xdata(), [0.0, 1e-3, 2e-3])
    assert ax_on.get_title() == "on: max |offset| 80 ns"
    assert ax_off.get_title() == "off: max |offset| 2000 ns"


def test_skew_plot_adds_the_spread_between_nodes_over_periods_every_node_saw(tmp_path):
    b = np.array([[1.0, -2.0, 0.0], [np.nan, 3.0, 1.0], [0.5, -4.0, 2.0]])
    fig = plots.plot_skew(tmp_path / "s.png", {"run": b}, "skew", spread=True)
    _, ax = fig.axes
    (line,) = ax.get_lines()
    assert line.get_label() == "run"
    np.testing.assert_array_equal(line.get_ydata(), [3.0 * 20, 6.0 * 20])
    np.testing.assert_allclose(line.get_xdata(), [0.0, 2e-3])
