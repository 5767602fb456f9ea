"""Figures of a run (PNG through matplotlib's Agg canvas: no display, no pyplot state).

Every function writes one PNG and returns the :class:`matplotlib.figure.Figure` it drew, so
tests can check the data on each axis rather than pixels. Figures follow the MRM paper: joint
tracking (Fig. 4), tracking errors (Fig. 5); plus torque commands, parameter estimates, and a
Gantt timeline of one period's A/B/C/D exchange on the 20 ns grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from mrm_cosim.units import CLOCK_HZ

__all__ = ["plot_tracking", "plot_joint_tracking", "plot_error_comparison", "plot_torques",
           "plot_parameters", "plot_timeline", "timeline_bars", "timeline_markers",
           "pick_period", "Bar", "Marker", "plot_tool_errors", "plot_tool_path",
           "plot_safe_stop", "plot_skew"]

_COLORS = {"pid-1khz": "tab:red", "pid-fpga": "tab:orange", "vdc": "tab:blue"}


def _figure(rows: int, height: float = 2.6, width: float = 8.0):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, max(2.5, height * rows)), constrained_layout=True)
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    return fig, axes


def _save(fig, path) -> None:
    fig.savefig(path, dpi=110)


#: Samples a time series keeps on a plot (:func:`envelope`): 2,000 columns, more than twice a
#: figure's 880-pixel width at 110 dpi.
ENVELOPE_COLUMNS = 2000


def envelope(t, y, columns: int = ENVELOPE_COLUMNS):
    """``(t, y)`` reduced for drawing: where a series is longer than ``4 · columns`` samples,
    each of ``columns`` runs of consecutive samples keeps its first, last, lowest and highest
    sample, in time order (M4 aggregation, Jugel et al., VLDB 2014): a line through them
    draws the same pixels as the whole series at up to ``columns`` pixels of width, every
    peak and step kept. A 1.2 s run has 120,000 plant steps per joint; drawing them all made
    the figures most of ``mrm run table2``'s time. Shorter series are returned as given.

    Parameters
    ----------
    t : ndarray, shape (n,)
    y : ndarray, shape (n,)

    Returns
    -------
    (ndarray, ndarray)
        The kept samples' times and values (views of the inputs where nothing is dropped).
    """
    t = np.asarray(t)
    y = np.asarray(y)
    n = len(y)
    if n <= 4 * columns or len(t) != n or y.ndim != 1 or \
            (y.dtype.kind == "f" and np.isnan(y).any()):
        return t, y             # (a gap in the series: drawn whole, its breaks where they are)
    edges = (np.arange(columns + 1) * n) // columns         # run k: [edges[k], edges[k + 1])
    starts = edges[:-1]
    run_len = np.diff(edges)
    width = int(run_len.max())
    # each run's samples as one row (the shorter runs padded with their last sample)
    idx = np.minimum(starts[:, None] + np.arange(width)[None, :], (edges[1:] - 1)[:, None])
    rows = y[idx]
    lo, hi = rows.argmin(axis=1), rows.argmax(axis=1)
    keep = np.concatenate([starts, edges[1:] - 1, starts + lo, starts + hi])
    keep = np.unique(keep)                                  # sorted: time order
    return t[keep], y[keep]


def _plot(ax, t, y, *args, **kwargs):
    """``ax.plot(t, y, …)`` of a time series through :func:`envelope`."""
    te, ye = envelope(t, y)
    return ax.plot(te, ye, *args, **kwargs)


def plot_tracking(path, t, q_d, q, tau, title: str):
    """Joint tracking (Fig. 4), tracking errors (Fig. 5) and torque commands of one run.

    Parameters
    ----------
    t : ndarray, shape (n_samples,), s
    q_d, q, tau : ndarray, shape (n_samples, n_joints), rad, rad and N·m
    title : str

    Returns
    -------
    matplotlib.figure.Figure
        Axes 0: q (solid, labels ``q1``…) and q_d (dashed, ``q1 desired``…); axis 1: q_d − q
        in mrad; axis 2: torque commands.
    """
    t, q_d, q, tau = (np.asarray(a, dtype=float) for a in (t, q_d, q, tau))
    fig, axes = _figure(3, 3.0)
    for k in range(q.shape[1]):
        (line,) = _plot(axes[0], t, q[:, k], label=f"q{k + 1}")
        _plot(axes[0], t, q_d[:, k], "--", color=line.get_color(), lw=0.8,
                     label=f"q{k + 1} desired")
        _plot(axes[1], t, 1e3 * (q_d[:, k] - q[:, k]), label=f"e{k + 1}")
        _plot(axes[2], t, tau[:, k], label=f"τ{k + 1}")
    axes[0].set_ylabel("joint position (rad)\n— actual, -- desired")
    axes[1].set_ylabel("tracking error (mrad)")
    axes[2].set_ylabel("torque command (N·m)")
    axes[2].set_xlabel("time (s)")
    for ax in axes:
        ax.grid(True, lw=0.3)
        ax.legend(loc="upper right", fontsize=7, ncol=min(2 * q.shape[1], 6))
    axes[0].set_title(title)
    _save(fig, path)
    return fig


def plot_joint_tracking(path, t, q_d, runs: dict, title: str):
    """The paper's Fig. 4: desired and actual angle of every joint, one line per controller.

    Parameters
    ----------
    t : ndarray, shape (n_samples,), s
    q_d : ndarray, shape (n_samples, n_joints), rad
    runs : dict of str -> ndarray, shape (n_samples, n_joints), rad
        Actual joint angles per controller.

    Returns
    -------
    Figure
        One axis per joint; its first line is ``desired``, then one per controller.
    """
    q_d = np.asarray(q_d, dtype=float)
    fig, axes = _figure(q_d.shape[1], 2.2)
    for k, ax in enumerate(axes):
        _plot(ax, t, q_d[:, k], "k--", lw=1.2, label="desired")
        for name, q in runs.items():
            _plot(ax, t, np.asarray(q)[:, k], color=_COLORS.get(name), lw=0.9, label=name)
        ax.set_ylabel(f"q{k + 1} (rad)")
        ax.grid(True, lw=0.3)
        ax.legend(loc="lower right", fontsize=7)
    axes[0].set_title(title)
    axes[-1].set_xlabel("time (s)")
    _save(fig, path)
    return fig


def plot_error_comparison(path, t, errors: dict, tip_errors: dict, title: str):
    """The paper's Fig. 5: joint tracking errors per controller, and the tip position error.

    Parameters
    ----------
    t : ndarray, shape (n_samples,), s
    errors : dict of str -> ndarray, shape (n_samples, n_joints), rad
        q_d − q per controller.
    tip_errors : dict of str -> ndarray, shape (n_samples,), m
        ‖p_d − p‖ of the tip per controller.

    Returns
    -------
    Figure
        Axes 0…n−1: joint errors in mrad; last axis: tip error in mm (the numerator of ρ).
    """
    n = np.asarray(next(iter(errors.values()))).shape[1]
    fig, axes = _figure(n + 1, 2.0)
    for name, e in errors.items():
        e = np.asarray(e, dtype=float)
        for k in range(n):
            _plot(axes[k], t, 1e3 * e[:, k], color=_COLORS.get(name), lw=0.9, label=name)
    for name, e in tip_errors.items():
        _plot(axes[n], t, 1e3 * np.asarray(e, dtype=float), color=_COLORS.get(name), lw=0.9,
                     label=name)
    for k in range(n):
        axes[k].set_ylabel(f"e{k + 1} (mrad)")
    axes[n].set_ylabel("tip error (mm)")
    axes[n].set_xlabel("time (s)")
    for ax in axes:
        ax.grid(True, lw=0.3)
        ax.legend(loc="upper right", fontsize=7)
    axes[0].set_title(title)
    _save(fig, path)
    return fig


def plot_torques(path, t, torques: dict, title: str, peak=None):
    """Torque commands of every joint, one line per controller.

    Parameters
    ----------
    t : ndarray, shape (n_samples,), s
    torques : dict of str -> ndarray, shape (n_samples, n_joints), N·m
    peak : ndarray, shape (n_joints,), N·m, optional
        Drawn as dotted limits.
    """
    n = np.asarray(next(iter(torques.values()))).shape[1]
    fig, axes = _figure(n, 2.2)
    for name, tau in torques.items():
        tau = np.asarray(tau, dtype=float)
        for k in range(n):
            _plot(axes[k], t, tau[:, k], color=_COLORS.get(name), lw=0.8, label=name)
    for k, ax in enumerate(axes):
        if peak is not None:
            for s in (1, -1):
                ax.axhline(s * peak[k], color="grey", ls=":", lw=0.8)
        ax.set_ylabel(f"τ{k + 1} (N·m)")
        ax.grid(True, lw=0.3)
        ax.legend(loc="upper right", fontsize=7)
    axes[0].set_title(title)
    axes[-1].set_xlabel("time (s)")
    _save(fig, path)
    return fig


def plot_tool_errors(path, errors: dict, title: str):
    """Cartesian errors of the tool over time, one line per run (a profile or controller).

    Parameters
    ----------
    errors : dict of str -> (ndarray, master.cartesian.ToolErrors)
        Per run, its time grid (s) and its errors on that grid (runs may differ in length:
        Ruckig's move is shorter than the trigonometric one).

    Returns
    -------
    matplotlib.figure.Figure
        Axis 0: position error (mm); axis 1: orientation error (mrad); axis 2: the se(3)
        error ‖log(T_d⁻¹ T_a)‖.
    """
    fig, axes = _figure(3, 2.4)
    for name, (t, e) in errors.items():
        _plot(axes[0], t, e.position_mm, lw=0.9, label=name)
        _plot(axes[1], t, e.orientation_mrad, lw=0.9, label=name)
        _plot(axes[2], t, e.se3, lw=0.9, label=name)
    axes[0].set_ylabel("position error (mm)")
    axes[1].set_ylabel("orientation error\n(mrad)")
    axes[2].set_ylabel("‖log(T_d⁻¹ T_a)‖")
    axes[2].set_xlabel("time (s)")
    for ax in axes:
        ax.grid(True, lw=0.3)
        ax.legend(loc="upper right", fontsize=7)
    axes[0].set_title(title)
    _save(fig, path)
    return fig


def plot_tool_path(path, desired, actual: dict, title: str):
    """The tool's path in 3-D: desired (dashed) and each run's actual path.

    Parameters
    ----------
    desired : ndarray, shape (k, 3), m
    actual : dict of str -> ndarray, shape (k, 3), m

    Returns
    -------
    matplotlib.figure.Figure
        One 3-D axis; lines labelled ``desired`` and by ``actual``'s keys, in mm.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.5, 5.5), constrained_layout=True)
    ax = fig.add_subplot(projection="3d")
    d = 1e3 * np.asarray(desired, dtype=float)
    ax.plot(d[:, 0], d[:, 1], d[:, 2], "k--", lw=1.2, label="desired")
    for name, a in actual.items():
        a = 1e3 * np.asarray(a, dtype=float)
        ax.plot(a[:, 0], a[:, 1], a[:, 2], lw=0.9, label=name)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.legend(loc="upper left", fontsize=7)
    ax.set_title(title)
    _save(fig, path)
    return fig


def plot_parameters(path, t=None, theta=None, names=None, title: str = "",
                    note: str | None = None):
    """Parameter estimates over time, or a figure that says why there are none.

    Parameters
    ----------
    t : ndarray, shape (n_samples,), s, optional
    theta : ndarray, shape (n_samples, n_params), optional
        Estimates in SI units; each is drawn relative to its first value (θ̂/θ̂₀).
    names : list of str, optional
    note : str, optional
        Shown instead of curves when ``theta`` is None (e.g. "adaptation off").
    """
    fig, (ax,) = _figure(1, 3.5)
    if theta is None:
        ax.text(0.5, 0.5, note or "no parameter estimates recorded", ha="center",
                va="center", wrap=True, transform=ax.transAxes)
        ax.set_axis_off()
    else:
        theta = np.asarray(theta, dtype=float)
        first = theta[0]
        rel = np.divide(theta, first, out=np.ones_like(theta), where=first != 0)
        names = names or [f"θ{k + 1}" for k in range(theta.shape[1])]
        for k in range(theta.shape[1]):
            _plot(ax, t, rel[:, k], lw=0.8, label=names[k])
        ax.set_ylabel("estimate / initial")
        ax.set_xlabel("time (s)")
        ax.grid(True, lw=0.3)
        ax.legend(loc="upper right", fontsize=6, ncol=4)
    ax.set_title(title)
    _save(fig, path)
    return fig


# --- timeline ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Bar:
    """One bar of the Gantt timeline, µs from the period start (exact multiples of 0.02)."""

    row: str          # "master" or "node k"
    label: str        # what happens
    start_us: float
    end_us: float


def pick_period(records, when: float | None = None, period_s: float = 1e-3):
    """The complete period at time ``when`` (s) or, without it, the one nearest the middle."""
    complete = [r for r in records if r.complete]
    if not complete:
        raise ValueError("no complete period to show")
    if when is None:
        return complete[len(complete) // 2]
    return min(complete, key=lambda r: abs(r.index * period_s - when))


def timeline_bars(record, n_nodes: int, clock_hz: float = float(CLOCK_HZ)) -> list[Bar]:
    """Bars of one period's exchange from a :class:`master.cycle.PeriodRecord`.

    Rows and bars (cycles counted from ``record.start``; a bar is drawn when both its ends
    were recorded):

    * ``master``: ``kinematics`` from the last Comm A arrival (``A_done``) to Comm B sent
      (VDC) or ``PID / references`` to Comm D sent (PID modes); ``forces`` from the last
      Comm C arrival (``C_done``) to Comm D sent.
    * ``node k``, from its observation port (``record.node_events``, :class:`protocol.regs.
      NodeEvent`): ``A↓`` period start (time-code and Comm A request leave the master) → the
      request's last byte taken (``RX_A``); ``A↑`` its reply leaves the node's reply FSM
      (``TX_A``) → complete at the master; ``B↓`` Comm B sent (the master hands it to its
      link; node k's comes after those of nodes 1 … k−1) → its last byte taken (``RX_B``);
      ``VDC`` the node's compute, ``VDC_START`` → ``VDC_DONE`` (MARK: forces ready);
      ``adapt`` the rest of the VDC program (adaptation, history), ``VDC_DONE`` → ``VDC_END``;
      ``C↑`` the Comm C reply leaves (``TX_C``) → complete at the master; ``D↓`` Comm D sent
      → its last byte taken (``RX_D``). PID modes have no B, VDC or C.
    * A node without observation-port events (a record from a harness that does not report
      them) gets the master's view instead: ``A`` period start → its Comm A reply arriving;
      ``B→C`` Comm B sent → its Comm C reply arriving.
    """
    per_us = clock_hz / 1e6                   # cycles per µs; dividing rounds once

    def t(cycle):
        return (cycle - record.start) / per_us

    ev = record.events
    bars = []
    pid = "B_sent" not in ev
    if pid and "A_done" in ev and "D_sent" in ev:
        bars.append(Bar("master", "PID / references", t(ev["A_done"]), t(ev["D_sent"])))
    if "A_done" in ev and "B_sent" in ev:
        bars.append(Bar("master", "kinematics", t(ev["A_done"]), t(ev["B_sent"])))
    if "C_done" in ev and "D_sent" in ev:
        bars.append(Bar("master", "forces", t(ev["C_done"]), t(ev["D_sent"])))
    node_events = getattr(record, "node_events", {})
    for k in range(1, n_nodes + 1):
        row = f"node {k}"
        arr = record.arrivals
        if not any(node == k for _, node in node_events):
            if ("A", k) in arr:
                bars.append(Bar(row, "A", 0.0, t(arr[("A", k)])))
            if ("C", k) in arr and "B_sent" in ev:
                bars.append(Bar(row, "B→C", t(ev["B_sent"]), t(arr[("C", k)])))
            continue
        at = {name: c for (name, node), c in node_events.items() if node == k}
        spans = [("A↓", record.start, at.get("RX_A")),
                 ("A↑", at.get("TX_A"), arr.get(("A", k))),
                 ("B↓", ev.get("B_sent"), at.get("RX_B")),
                 ("VDC", at.get("VDC_START"), at.get("VDC_DONE")),
                 ("adapt", at.get("VDC_DONE"), at.get("VDC_END")),
                 ("C↑", at.get("TX_C"), arr.get(("C", k))),
                 ("D↓", ev.get("D_sent"), at.get("RX_D"))]
        if pid:
            spans = [s for s in spans if s[0] not in ("B↓", "VDC", "adapt", "C↑")]
        for label, c0, c1 in spans:
            if c0 is not None and c1 is not None:
                bars.append(Bar(row, label, t(c0), t(c1)))
    return bars


@dataclass(frozen=True)
class Marker:
    """One instant of the Gantt timeline, µs from the period start."""

    row: str          # "node k"
    label: str        # "boundary" (the node's snapshot) or "commit" (Comm D takes effect)
    at_us: float


def timeline_markers(record, n_nodes: int, clock_hz: float = float(CLOCK_HZ)) -> list[Marker]:
    """Node k's period boundary (``BOUNDARY``: its timer's phase 0, the snapshot Comm A
    reports) and Comm D commit (``COMMIT``) in the period of ``record``, where recorded."""
    per_us = clock_hz / 1e6
    node_events = getattr(record, "node_events", {})
    out = []
    for k in range(1, n_nodes + 1):
        for name, label in (("BOUNDARY", "boundary"), ("COMMIT", "commit")):
            if (name, k) in node_events:
                out.append(Marker(f"node {k}", label,
                                  (node_events[(name, k)] - record.start) / per_us))
    return out


_BAR_COLORS = {"A": "tab:green", "B→C": "tab:purple", "kinematics": "tab:grey",
               "forces": "tab:brown", "PID / references": "tab:grey",
               "A↓": "tab:olive", "A↑": "tab:green", "B↓": "tab:cyan", "VDC": "tab:red",
               "adapt": "lightsalmon", "C↑": "tab:purple", "D↓": "tab:blue"}
_MARKERS = {"boundary": ("|", "k"), "commit": ("v", "tab:orange")}
# (offset from the row's centre, height): a node's compute in the lower half of its row, the
# transfers (which overlap it: the Comm C reply leaves while the adaptation runs) in the upper
_LANES = {"VDC": (-0.38, 0.36), "adapt": (-0.38, 0.36), "A↓": (0.02, 0.36),
          "A↑": (0.02, 0.36), "B↓": (0.02, 0.36), "C↑": (0.02, 0.36), "D↓": (0.02, 0.36)}


def plot_timeline(path, record, n_nodes: int, period_cycles: int, title: str,
                  clock_hz: float = float(CLOCK_HZ), skew: dict | None = None):
    """Gantt chart of one period's time-code/A/B/C/D exchange per node.

    Parameters
    ----------
    record : master.cycle.PeriodRecord
    n_nodes : int
    period_cycles : int
        Length of the period (for the slack annotation: the period's end less the latest end
        of any bar or Comm D sent — with the nodes' events, the last Comm D taken by a node or
        the last VDC program ending, whichever is later).
    skew : dict, optional
        The run's period-start skew (:func:`cosim.skew.period_skew`), written under the title:
        the nodes' period starts against the master's and against each other, max and RMS.

    Returns
    -------
    Figure
        Its ``broken_barh`` collections are in the order of :func:`timeline_bars`; its lines
        are the markers of :func:`timeline_markers` (in their order), then the vertical
        lines; y tick labels are the rows, master on top.
    """
    bars = timeline_bars(record, n_nodes, clock_hz)
    rows = ["master"] + [f"node {k}" for k in range(1, n_nodes + 1)]
    fig, (ax,) = _figure(1, 0.6 * len(rows) + 1.5, 10.5)
    y = {r: len(rows) - 1 - i for i, r in enumerate(rows)}
    seen = set()
    for b in bars:
        off, height = _LANES.get(b.label, (-0.35, 0.7))
        ax.broken_barh([(b.start_us, b.end_us - b.start_us)], (y[b.row] + off, height),
                       facecolors=_BAR_COLORS.get(b.label, "tab:cyan"),
                       label=None if b.label in seen else b.label)
        seen.add(b.label)
    markers = timeline_markers(record, n_nodes, clock_hz)
    for mk in markers:
        shape, color = _MARKERS[mk.label]
        ax.plot([mk.at_us], [y[mk.row]], linestyle="none", marker=shape, color=color,
                markersize=11 if shape == "|" else 7,
                label=None if mk.label in seen else f"node {mk.label}")
        seen.add(mk.label)
    per_us = clock_hz / 1e6
    d_sent = record.events.get("D_sent")
    end = max((b.end_us for b in bars), default=0.0)
    if d_sent is not None:
        d = (d_sent - record.start) / per_us
        ax.axvline(d, color="k", lw=0.8, ls="--", label="Comm D sent")
        end = max(end, d)
    ax.axvline(0.0, color="k", lw=0.8, ls=":", label="time-code + Comm A request")
    slack = period_cycles / per_us - end
    ax.set_yticks([y[r] for r in rows], rows)
    ax.set_xlabel(f"µs from the period start (20 ns grid); slack to the period end "
                  f"{slack:.2f} µs of {period_cycles / per_us:.0f} µs")
    right = max([end] + [mk.at_us for mk in markers])
    ax.set_xlim(-0.02 * right - 1.0, 1.08 * right + 1.0)
    ax.grid(True, axis="x", lw=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)
    if skew is not None:        # (one line would run past the figure's left edge)
        title += "\n" + skew_line(skew).replace("; between nodes", "\nbetween nodes")
    ax.set_title(title, fontsize=10)
    _save(fig, path)
    return fig


def skew_line(skew: dict) -> str:
    """One line of a run's period-start skew (:func:`cosim.skew.period_skew`)."""
    nm, bn = skew["node_vs_master"], skew["between_nodes"]
    if nm["max_abs_cycles"] is None:
        return "period starts: no node boundary seen"
    text = (f"period starts over {skew['periods']} periods — nodes vs master: max "
            f"{nm['max_abs_ns']:.0f} ns, RMS {nm['rms_ns']:.1f} ns")
    if bn["max_cycles"] is not None:
        text += f"; between nodes: max {bn['max_ns']:.0f} ns, RMS {bn['rms_ns']:.1f} ns"
    if skew.get("missing"):
        text += f"; {skew['missing']} unseen"
    return text


def plot_skew(path, runs: dict, title: str, period_s: float = 1e-3,
              clock_hz: float = float(CLOCK_HZ), spread: bool = False):
    """Each node's period start against the master's over a run (issue 21 item 3): one panel
    per run (e.g. ``{"discipline on": b_on, "discipline off": b_off}``), one line per node,
    ns against the period's time; with ``spread`` a last panel of each run's spread between
    the nodes per period (``max_k b − min_k b`` over periods every node saw).

    Parameters
    ----------
    runs : dict
        label → ``(periods, n_nodes)`` start offsets in cycles of the reference clock
        (:func:`cosim.skew.start_offsets`; NaN where a period had no boundary strobe: a gap
        in the line).
    period_s : float
        The master's period (the x axis: period index × ``period_s``).

    Returns
    -------
    Figure
        One axis per run, in ``runs``' order; on each, one line per node (node 1 first) whose
        data are the offsets in ns, and the run's largest ``|offset|`` in the axis title; with
        ``spread``, then the spread axis, one line per run.
    """
    fig, axes = _figure(len(runs) + bool(spread), 2.4, 9.0)
    ns = 1e9 / clock_hz
    for ax, (label, b) in zip(axes[:len(runs)], runs.items(), strict=True):
        b = np.asarray(b, dtype=float)
        t = np.arange(b.shape[0]) * period_s
        for k in range(b.shape[1]):
            ax.plot(t, b[:, k] * ns, lw=0.9, label=f"node {k + 1}")
        seen = b[~np.isnan(b)]
        worst = f"max |offset| {np.abs(seen).max() * ns:.0f} ns" if seen.size else "no boundary"
        ax.set_title(f"{label}: {worst}", fontsize=9)
        ax.set_ylabel("period start − master's (ns)", fontsize=8)
        ax.axhline(0.0, color="k", lw=0.5)
        ax.grid(True, lw=0.3)
        ax.legend(loc="upper left", fontsize=7, ncol=min(6, b.shape[1]))
    if spread:
        ax = axes[-1]
        for label, b in runs.items():
            b = np.asarray(b, dtype=float)
            full = ~np.isnan(b).any(axis=1)
            t = np.arange(b.shape[0])[full] * period_s
            ax.plot(t, (b[full].max(axis=1) - b[full].min(axis=1)) * ns, lw=0.9, label=label)
        ax.set_ylabel("spread between nodes (ns)", fontsize=8)
        ax.grid(True, lw=0.3)
        ax.legend(loc="upper left", fontsize=7)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(title, fontsize=10)
    _save(fig, path)
    return fig


def plot_dmp_paths(path, results: dict, period_ms: int, title: str):
    """The tool's paths of the motion-primitive comparison, one panel per path: desired,
    traditional and modularized at master period ``period_ms``, in the paths' plane
    (coordinates along its ``e1, e2`` from the start, mm)."""
    from matplotlib.figure import Figure

    n = len(results)
    cols = min(n, 2)
    rows = -(-n // cols)
    fig = Figure(figsize=(5.0 * cols, 4.2 * rows), layout="constrained")
    for i, (name, res) in enumerate(results.items()):
        ax = fig.add_subplot(rows, cols, i + 1)
        runs = res.runs
        first = next(iter(runs.values()))
        origin = first.tool_desired[0]
        plane = np.stack([res.plane_e1, res.plane_e2])

        def uv(p, plane=plane, origin=origin):
            return 1e3 * (p - origin) @ plane.T

        d = uv(first.tool_desired)
        ax.plot(d[:, 0], d[:, 1], "k-", lw=2.0, label="desired")
        lo, hi = d.min(axis=0), d.max(axis=0)
        pad = np.maximum(0.3 * (hi - lo).max(), 5.0)
        for arch, style in (("traditional", "C3--"), ("feedforward", "C2-."),
                            ("modularized", "C0-")):
            run = runs.get((arch, period_ms))
            if run is not None:
                a = uv(run.tool_actual)
                ax.plot(a[:, 0], a[:, 1], style, lw=1.0, label=f"{arch}, {period_ms} ms")
        # the desired path's extent: a run that leaves it is drawn up to the frame
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel("e1 (mm)")
        ax.set_ylabel("e2 (mm)")
        ax.set_title(name)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(title)
    _save(fig, path)


def plot_dmp_errors(path, results: dict, title: str):
    """Eq. (10)'s error and the tool position error over time, one row per path, every run
    (architecture and master period) as a line."""
    fig, axes = _figure(len(results), height=2.4, width=11.0)
    axes = np.atleast_1d(axes)
    for ax_row, (name, res) in zip(axes, results.items(), strict=True):
        for (arch, period), run in res.runs.items():
            style = {"traditional": "--", "feedforward": "-.", "modularized": "-",
                     "reference": ":"}[arch]
            ax_row.semilogy(run.t, np.maximum(run.position_mm, 1e-6), style, lw=0.9,
                            label=f"{arch} {period} ms")
        ax_row.set_ylabel(f"{name}\nposition error (mm)")
        ax_row.grid(alpha=0.3)
        ax_row.legend(fontsize=7, ncol=3)
    axes[-1].set_xlabel("time from the motion's start (s)")
    axes[0].set_title(title)
    _save(axes[0].figure, path)


def plot_safe_stop(path, t, runs: dict, t_cut: float, title: str, bound: float | None = None):
    """Joint motion through a safe stop (docs/faults.md "Safe stop"): per joint, the angle
    minus its angle at the cut, mrad, of each run, with the cut and each run's brake
    engagement marked.

    Parameters
    ----------
    t : ndarray, shape (n_samples,), s
    runs : dict
        label -> ``(q, engaged)``: angles, ndarray (n_samples, n), rad; the brakes' state,
        bool ndarray (n_samples, n) (each joint's engagement marked on its own axes: with
        the brake at standstill the joints' brakes engage at different times).
    t_cut : float, s
    bound : float, optional, rad
        The hold bound, drawn about each run's angle at its engagement.
    """
    first = next(iter(runs.values()))[0]
    n = first.shape[1]
    fig, axes = _figure(n, height=2.0)
    i_cut = int(np.searchsorted(t, t_cut))
    styles = ["-", "--", ":", "-."]
    for k, ax in enumerate(axes):
        for j, (label, (q, engaged)) in enumerate(runs.items()):
            _plot(ax, t, 1e3 * (q[:, k] - q[i_cut, k]), styles[j % 4], lw=1.0, label=label)
            held = engaged[:, k]
            if held.any():
                e = int(np.argmax(held))
                ax.axvline(t[e], color="0.5", lw=0.6, ls=styles[j % 4])
                if bound is not None:
                    y = 1e3 * (q[e, k] - q[i_cut, k])
                    ax.fill_between(t[e:], y - 1e3 * bound, y + 1e3 * bound, color="0.85",
                                    lw=0)
        ax.axvline(t_cut, color="tab:red", lw=0.8)
        ax.set_ylabel(f"q{k + 1} − q{k + 1}(cut)\nmrad")
        ax.grid(alpha=0.3)
    axes[-1].legend(fontsize=8, loc="lower right")
    axes[0].set_title(title, fontsize=10)
    axes[-1].set_xlabel("t (s from period 0); red: the cut; grey: the brakes engaged")
    _save(fig, path)
    return fig
