"""``mrm run table2``: the MRM paper's Table 2, the three controllers on the same plant.

Each controller named in the configuration runs the quintic test (paper eqs. 1–4) in closed
loop through :func:`cosim.track.run_track` on the same backend, robot, plant perturbation
seed, master timing and gains. The result folder (written atomically: a failed run leaves
nothing) holds::

    summary.json          {"controllers": {name: run_track summary, ...}, "paper": ...,
                           "ordering": ..., "config": ..., "seed", "version", ...}
    table2.md             our figures beside the paper's printed ones
    config.toml           the exact resolved configuration (loads back equal)
    fig4_tracking.png     joint angles, desired and per controller (paper Fig. 4)
    fig5_errors.png       joint and tip errors per controller (paper Fig. 5)
    torques.png           torque commands per controller with the peak-torque limits
    <controller>/         summary.json, trace.csv (1 ms), timeline.json, tracking.png (every
                          plant step),
                          timeline.png (Gantt of one period), parameters.png, and with
                          [clocks] set skew.png (each node's period start against the
                          master's over the run, docs/clocks.md)
"""

from __future__ import annotations

import csv
import inspect
import logging
import time
from pathlib import Path

import numpy as np

from mrm_cosim.cosim.experiment_config import PAPER_AMPLITUDE, PAPER_DURATION, ExperimentConfig
from mrm_cosim.errors import InputError

__all__ = ["PAPER_TABLE2", "run_table2", "table_markdown", "Progress", "timeline_json"]

_log = logging.getLogger("mrm_cosim.progress")

PAPER_TABLE2 = {
    # controller: (max velocity m/s, max error m, ratio s), MRM paper Table 2, rows 5-7
    "pid-1khz": (0.5226, 2.3e-3, 0.00440),
    "pid-fpga": (0.5226, 0.26e-3, 0.00050),
    "vdc": (0.5226, 0.0618e-3, 0.00012),
}
_NAMES = {"pid-1khz": "PID with 1000 Hz", "pid-fpga": "PID with embedded FPGA",
          "vdc": "VDC with embedded FPGA"}


class Progress:
    """Progress lines: which controller, simulated time, speed, ETA; logged at INFO on the
    ``mrm_cosim.progress`` logger, or printed on ``stream`` if one is given.

    Call :meth:`begin` / :meth:`end` around each controller's run and pass the instance as
    ``run_track``'s ``progress``: when the harness calls it as ``progress(t_sim, t_total)``
    (simulated seconds done and to do) it prints at most every ``every`` wall seconds. Runs
    side by side (``run_table2(..., jobs=2)``) report through :meth:`report` instead, each
    line naming its controller.
    """

    def __init__(self, controllers, duration: float, stream=None, every: float = 5.0):
        self.controllers = list(controllers)
        self.duration = duration
        self.stream = stream
        self.every = every
        self.parallel = False
        self._wall_per_sim: float | None = None   # measured wall s per simulated s
        self._t0 = self._last = 0.0
        self._index = 0
        self._total_wall = 0.0
        self._t0s: dict = {}
        self._lasts: dict = {}

    def _print(self, text: str) -> None:
        if self.stream is None:
            _log.info(text)
        else:
            print(text, file=self.stream, flush=True)

    def begin(self, controller: str) -> None:
        self._index = self.controllers.index(controller)
        self._t0 = self._last = time.perf_counter()
        self._t0s[controller] = self._lasts[controller] = self._t0
        eta = ""
        if self._wall_per_sim is not None and not self.parallel:
            left = (len(self.controllers) - self._index) * self.duration * self._wall_per_sim
            eta = f", ETA {_hms(left)} for the rest"
        self._print(f"[{self._index + 1}/{len(self.controllers)}] {controller}: "
                    f"{self.duration:g} s simulated{eta}")

    def __call__(self, t_sim: float, t_total: float | None = None) -> None:
        now = time.perf_counter()
        if now - self._last < self.every or t_sim <= 0:
            return
        self._last = now
        total = self.duration if t_total is None else t_total
        rate = t_sim / (now - self._t0)                  # simulated s per wall s
        left = (total - t_sim) / rate + (len(self.controllers) - self._index - 1) * total / rate
        self._print(f"    {t_sim:.3f}/{total:g} s simulated, {rate * 1e3:.3g} ms/s "
                    f"(RTF {1 / rate:.3g}), ETA {_hms(left)}")

    def report(self, controller: str, t_sim: float, t_total: float | None = None) -> None:
        """``controller``'s run, one of several side by side, is at ``t_sim``."""
        now = time.perf_counter()
        if now - self._lasts.get(controller, 0.0) < self.every or t_sim <= 0:
            return
        self._lasts[controller] = now
        total = self.duration if t_total is None else t_total
        rate = t_sim / (now - self._t0s.get(controller, now - 1e-9))
        self._print(f"    {controller}: {t_sim:.3f}/{total:g} s simulated, {rate * 1e3:.3g} "
                    f"ms/s (RTF {1 / rate:.3g}), ETA {_hms((total - t_sim) / rate)}")

    def end(self, controller: str, summary: dict) -> None:
        wall = time.perf_counter() - self._t0s.get(controller, self._t0)
        self._total_wall += wall
        done = self._index + 1
        self._wall_per_sim = self._total_wall / (done * self.duration)
        left = (len(self.controllers) - done) * self.duration * self._wall_per_sim
        tail = f", ETA {_hms(left)}" if left > 0 and not self.parallel else ""
        self._print(f"    {controller}: rho {summary['rho_s']:.3g} s, max tip error "
                    f"{1e3 * summary['max_tip_error_m']:.4g} mm in {_hms(wall)}{tail}")


def _hms(seconds: float) -> str:
    seconds = int(round(seconds))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s" if m else f"{s}s"


def skew_figure(path, result, n: int, config: ExperimentConfig, controller: str) -> bool:
    """``skew.png``: each node's period start against the master's over a run on clocks of
    their own or with the discipline (:func:`cosim.plots.plot_skew`); nothing (False) on a
    common clock with free-running timers, where every offset is 0."""
    if config.clocks.common and not config.clocks.discipline:
        return False
    from mrm_cosim.cosim.plots import plot_skew
    from mrm_cosim.cosim.skew import start_offsets
    from mrm_cosim.units import CLOCK_HZ

    timers = "disciplined" if config.clocks.discipline else "free-running"
    b = start_offsets(result.master.records, n, config.timing.period_cycles,
                      strobes=getattr(result.master, "boundary_strobes", None))
    plot_skew(path, {f"timers {timers}": b},
              f"{controller}: period starts, clocks {config.clocks.mode}",
              period_s=config.timing.period_cycles / CLOCK_HZ, spread=True)
    return True


def _run_kwargs(runner, config: ExperimentConfig, robot) -> dict:
    """Keyword arguments for ``runner`` beyond the common ones; refuses what it cannot run."""
    params = inspect.signature(runner).parameters
    kw = _safety_kwargs(params, config, robot)
    if "clocks" in params:
        kw["clocks"] = config.clocks
    elif not config.clocks.common or config.clocks.discipline:
        raise InputError("clocks", "this runner runs every node on one clock")
    tr = config.trajectory
    paper = tr.amplitude == PAPER_AMPLITUDE and tr.duration == PAPER_DURATION
    if paper:
        return kw
    if "profile" not in params:
        raise InputError("trajectory", "this tree's run_track runs only the paper's quintic "
                         f"({PAPER_AMPLITUDE} rad in {PAPER_DURATION} s); amplitude "
                         f"{tr.amplitude!r} rad in {tr.duration!r} s needs its profile argument")
    from mrm_cosim.cosim.preview import paper_test_profile

    return {**kw, "profile": paper_test_profile(robot, tr.amplitude, tr.duration)}


def _safety_kwargs(params, config: ExperimentConfig, robot) -> dict:
    """The config's ``[safety]`` for ``runner``: its line faults, what the master does on a
    trip and the nodes' safe stop — refused by field where the runner cannot take them, never
    dropped."""
    safety = config.faults
    kw = {}
    if "on_trip" in params:
        kw.update(on_trip=safety.on_trip, rearm_blend=safety.rearm_blend,
                  safe_stop=safety.safe_stop)
    if safety.parsed:
        if "faults" not in params:
            raise InputError("safety.line_faults", "this runner takes no line faults")
        for f in safety.parsed:
            if config.backend == "model" and f.kind != "cut":
                raise InputError("safety.line_faults", "the model backend's link has no bits: "
                                 "it takes 'cut' faults only; inject the others on compiled "
                                 "or pysim")
            if f.node > robot.n:
                raise InputError("safety.line_faults",
                                 f"the robot has {robot.n} nodes, not {f.node}")
        kw["faults"] = list(safety.parsed)
    return kw


def run_table2(config: ExperimentConfig, out, *, progress: Progress | None = None,
               runner=None, jobs: int = 1) -> dict:
    """Run every configured controller and write the result folder ``out`` atomically.

    Parameters
    ----------
    config : ExperimentConfig
    out : path
        Result folder; replaced only when everything succeeded.
    progress : Progress, optional
    runner : callable, optional
        ``cosim.track.run_track`` (default) or a function with its signature.
    jobs : int
        Controllers run side by side on this machine's processes, the sweeps' executor
        (:class:`cosim.executors.LocalExecutor`; each run is independent: the results are the
        same as one after the other, bit for bit; only the wall time differs). ``runner``
        must then be picklable (a module-level function or class instance).

    Returns
    -------
    dict
        What ``summary.json`` holds.
    """
    from mrm_cosim.cosim.preview import paper_test_profile
    from mrm_cosim.models.robot import load_robot
    from mrm_cosim import __version__
    from mrm_cosim.results import atomic_output_dir, write_json

    if runner is None:
        from mrm_cosim.cosim.track import run_track as runner
    robot = load_robot(config.robot)
    _run_kwargs(runner, config, robot)          # refuses a trajectory it cannot run, up front
    profile = paper_test_profile(robot, config.trajectory.amplitude, config.trajectory.duration)
    t_start = time.perf_counter()
    runs = {}
    with atomic_output_dir(out, made_by="mrm run table2") as tmp:
        jobs = max(1, min(int(jobs), len(config.controllers)))
        if jobs == 1:
            for c in config.controllers:
                if progress is not None:
                    progress.begin(c)
                runs[c] = _controller_run((config, tmp, runner), c, progress)
                if progress is not None:
                    progress.end(c, runs[c][1])
        else:
            runs = _side_by_side(config, tmp, runner, jobs, progress)
        summary = {
            "experiment": config.name, "robot": robot.name, "backend": config.backend,
            "seed": config.seed, "duration_s": config.duration, "version": __version__,
            "controllers": {c: s for c, (_, s) in runs.items()},
            "paper": {c: {"max_velocity_m_s": v, "max_error_m": e, "rho_s": r}
                      for c, (v, e, r) in PAPER_TABLE2.items()},
            "ordering": _ordering(runs),
            "config": config.to_dict(),
            "wall_s": time.perf_counter() - t_start,
        }
        write_json(tmp / "summary.json", summary)
        (tmp / "config.toml").write_text(config.to_toml())
        (tmp / "table2.md").write_text(table_markdown(summary))
        _comparison_plots(tmp, robot, config, runs, profile, jobs=jobs)
    return summary


class _Trace:
    """What the comparison plots need of a run done in another process."""

    def __init__(self, t, q, tau):
        self.t, self.q, self.tau = t, q, tau


def _controller_run(ctx, c: str, report) -> tuple:
    """One controller's run, its folder written: ``(trace, summary)``. ``ctx`` is
    ``(config, folder, runner)``; ``report(t_sim, t_total)`` its progress. A top-level function
    so that a process executor can run it (:mod:`cosim.executors`)."""
    from mrm_cosim import __version__
    from mrm_cosim.cosim.preview import paper_test_profile
    from mrm_cosim.models.robot import load_robot

    config, folder, runner = ctx
    if runner is None:
        from mrm_cosim.cosim.track import run_track as runner
    robot = load_robot(config.robot)
    profile = paper_test_profile(robot, config.trajectory.amplitude, config.trajectory.duration)
    result, summary = runner(robot, c, config.backend, config.duration, config.seed,
                             gains=config.gains, timing=config.timing,
                             plant_config=config.plant, progress=report,
                             **_run_kwargs(runner, config, robot))
    summary = dict(summary, version=__version__)
    _write_controller(folder / c, robot, c, config, result, summary, profile)
    return _Trace(result.t, result.q, result.tau), summary


def _controller_point(ctx, c: str, report) -> tuple:
    """:func:`_controller_run` with its progress sent as ``("progress", c, t_sim, t_total)``."""
    return _controller_run(ctx, c, lambda t_sim, t_total=None: report("progress", c, t_sim,
                                                                       t_total))


def _side_by_side(config, folder, runner, jobs: int, progress) -> dict:
    """Every controller's run, ``jobs`` at a time on this machine's processes (the executor
    seam of the sweeps, :class:`cosim.executors.LocalExecutor`); returns ``{c: (trace,
    summary)}`` in the order of the controllers. Progress comes back as messages; the parent
    does all the printing. The first run that fails stops the table (no worker outlives it)."""
    from functools import partial

    from mrm_cosim.cosim.executors import LocalExecutor

    controllers = list(config.controllers)
    if progress is not None:
        progress.parallel = True
        for c in controllers[:jobs]:
            progress.begin(c)

    def on_message(kind, c, t_sim, t_total):
        if progress is not None:
            progress.report(c, t_sim, t_total)

    _preload(config)
    runs, started = {}, jobs
    with LocalExecutor(jobs) as ex:
        for i, status, value in ex.run(partial(_controller_point, (config, folder, runner)),
                                       controllers, on_message):
            c = controllers[i]
            if status == "input":
                raise InputError(*value)
            if status == "error":
                raise RuntimeError(f"the {c} run failed in its process:\n{value}")
            runs[c] = value
            if progress is not None:
                progress.end(c, value[1])
                if started < len(controllers):
                    progress.begin(controllers[started])
                    started += 1
    return {c: runs[c] for c in controllers}


def _preload(config) -> None:
    """Before the workers fork: what every run loads, loaded once here so that each worker
    starts with it (the model backend's compiled kernel from numba's cache and its pinocchio
    library, :mod:`cosim.pin_shim`, built or from the cache; matplotlib's Agg
    canvas, the loop's modules) — 1.2 s of CPU per worker otherwise, and the parent's own
    comparison plots need matplotlib anyway."""
    import matplotlib.backends.backend_agg  # noqa: F401
    import matplotlib.figure  # noqa: F401

    from mrm_cosim.cosim import closed_loop, plots, track  # noqa: F401

    if config.backend == "model":
        import importlib.util
        from concurrent.futures import ThreadPoolExecutor

        from mrm_cosim.cosim import pin_shim
        from mrm_cosim.cosim.model_kernel import kernel_choice, load

        if kernel_choice() == "numba" and importlib.util.find_spec("numba") is not None:
            # the kernel's pinocchio library too: on a first run, its compiler (a process of
            # its own) runs while numba compiles the kernel here
            with ThreadPoolExecutor(1) as pool:
                library = pool.submit(pin_shim.load)
                load()
                library.result()
        elif kernel_choice() == "numba":
            load()                              # (its one warning: numba is missing)


def _ordering(runs: dict) -> dict:
    rho = {c: s["rho_s"] for c, (_, s) in runs.items()}
    order = sorted(rho, key=rho.get)
    paper = [c for c in ("vdc", "pid-fpga", "pid-1khz") if c in rho]
    moved = all(s["max_tip_speed_m_s"] > MOVED_M_S for _, s in runs.values())
    apart = all(rho[b] > (1.0 + RHO_MARGIN) * rho[a]
                for a, b in zip(order, order[1:], strict=False))
    return {"best_to_worst": order, "moved": moved, "apart": apart,
            "as_paper": order == paper and moved and apart and len(paper) > 1}


#: A run "moved" when its desired tip speed exceeded this (m/s); a run shorter than the
#: motion's start has speed 0 and a ρ of 0/0.
MOVED_M_S = 1e-3
#: Two controllers' ρ are "apart" when the larger exceeds the smaller by this fraction: the
#: spread of ρ over plant seeds is a few per cent (docs/experiments.md), so a closer pair is
#: not an ordering.
RHO_MARGIN = 0.10


def table_markdown(summary: dict) -> str:
    """Table 2 rows of this run beside the paper's printed ones (Markdown)."""
    lines = [f"# Table 2 — {summary['robot']}, backend {summary['backend']}, "
             f"seed {summary['seed']}, {summary['duration_s']:g} s simulated",
             "",
             "| controller | max tip speed (m/s) | max tip error (mm) | ρ (s) "
             "| paper speed (m/s) | paper error (mm) | paper ρ (s) | max joint error (mrad) "
             "| overruns | link errors |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for c, s in summary["controllers"].items():
        v, e, r = PAPER_TABLE2[c]
        lines.append(
            f"| {_NAMES[c]} (`{c}`) | {s['max_tip_speed_m_s']:.4f} "
            f"| {1e3 * s['max_tip_error_m']:.4f} | {s['rho_s']:.6f} | {v} | {1e3 * e:.4g} "
            f"| {r:.6f} | {1e3 * s['max_joint_error_rad']:.4f} | {s['overruns']} "
            f"| {s['link_errors']} |")
    from mrm_cosim.cosim.track import run_faults

    faults = {c: run_faults(s) for c, s in summary["controllers"].items()}
    lines += [""] + [f"**NOT A CLEAN RUN**, `{c}`: " + "; ".join(f) + "."
                     for c, f in faults.items() if f]
    if not any(faults.values()):
        lines.append("Every run clean: no overrun, missing, late or unexpected reply, upload "
                     "or link error, watchdog trip or node counter.")
    if "clocks" in summary.get("config", {}):
        lines += [""] + skew_lines(summary)
    order = summary["ordering"]
    lines += ["", "Ordering by ρ, best first: " + " < ".join(order["best_to_worst"])
              + (" — as in the paper." if order["as_paper"] else
                 " — NOT the paper's order (vdc < pid-fpga < pid-1khz)."
                 if order.get("moved", True) and order.get("apart", True) else
                 " — no ordering can be claimed: "
                 + ("a run did not move (its duration ends before the motion starts)"
                    if not order.get("moved", True) else
                    f"two ρ are within {RHO_MARGIN:.0%} of each other")
                 + "."),
              "", "ρ = max‖tip error‖ / max‖tip velocity‖ over the run (paper eq. 5 for this "
              "one trajectory); the tip velocity is the desired one. See docs/experiments.md.",
              ""]
    return "\n".join(lines)


#: What a model-backend table on clocks of their own is (docs/clocks.md "The model backend").
_MODEL_CLOCKS = {
    False: "The model backend with free-running timers: each node's reference on its own "
           "clock, the gateware's run bit for bit.",
    True: "The model backend with the discipline: its link delivers the time-code 12 cycles a "
          "hop exactly, so the skew is the loop's and the clocks', without the link's "
          "character jitter the gateware adds (about one cycle RMS), and the runs follow the "
          "gateware's within it, not bit for bit (docs/clocks.md \"The model backend\").",
}


def skew_lines(summary: dict) -> list[str]:
    """The clocks a table ran on and each controller's period-start skew (``period_skew``,
    :mod:`cosim.skew`), Markdown."""
    clk = summary["config"]["clocks"]
    first = next(iter(summary["controllers"].values()))
    ran = first.get("clocks", {})
    ppm = ", ".join(f"{p:+g}" for p in ran.get("ppm", []))
    out = [f"Clocks: `{clk['mode']}`"
           + (f" within ±{clk['range_ppm']:g} ppm" if clk["mode"] == "drawn" else "")
           + (f" — master port {ran['master_ppm']:+g} ppm, nodes {ppm} ppm" if ran else "")
           + "; node timers " + ("disciplined by the time-code (CONFIG TC_DISCIPLINE)."
                                 if clk["discipline"] else "free-running."),
           *([""] + [_MODEL_CLOCKS[bool(clk["discipline"])]]
             if summary["config"]["experiment"].get("backend") == "model" else []),
           "",
           "| controller | node vs master, max (cycles) | RMS (cycles) | between nodes, max "
           "(cycles) | RMS (cycles) | merged strobes |",
           "|---|---|---|---|---|---|"]

    def num(x):
        return "–" if x is None else f"{x:.3g}"

    for c, s in summary["controllers"].items():
        sk = s["period_skew"]
        nm, bn = sk["node_vs_master"], sk["between_nodes"]
        out.append(f"| `{c}` | {num(nm['max_abs_cycles'])} | {num(nm['rms_cycles'])} "
                   f"| {num(bn['max_cycles'])} | {num(bn['rms_cycles'])} "
                   f"| {s.get('clocks', {}).get('merged_strobes', 0)} |")
    return out


def timeline_json(records) -> list:
    """Every period's events, per-node arrivals and the nodes' observation-port events
    (``node_events``: node number → {NodeEvent name → first cycle in the period}), absolute
    20 ns cycles, JSON-ready."""
    out = []
    for r in records:
        nodes: dict = {}
        for (name, node), c in sorted(getattr(r, "node_events", {}).items(),
                                      key=lambda item: (item[0][1], item[1])):
            nodes.setdefault(str(node), {})[name] = c
        out.append({"period": r.index, "start_cycle": r.start, "complete": r.complete,
                    "events": dict(r.events),
                    "arrivals": {f"{ph}{node}": c for (ph, node), c in r.arrivals.items()},
                    "node_events": nodes})
    return out


def _every_ms(t) -> int:
    return max(1, round(1e-3 / (t[1] - t[0]))) if len(t) > 1 else 1


def _write_controller(folder: Path, robot, controller, config, result, summary, profile):
    from mrm_cosim.cosim.plots import pick_period, plot_parameters, plot_timeline, plot_tracking
    from mrm_cosim.results import write_json

    folder.mkdir()
    write_json(folder / "timeline.json", timeline_json(result.master.records))
    every = _every_ms(result.t)
    t = result.t[::every]
    q_d = profile.evaluate(t)[0]
    q, tau = result.q[::every], result.tau[::every]
    with open(folder / "trace.csv", "w", newline="") as f:
        w = csv.writer(f)
        n = robot.n
        w.writerow(["t_s"] + [f"q_d{k + 1}_rad" for k in range(n)]
                   + [f"q{k + 1}_rad" for k in range(n)] + [f"tau{k + 1}_Nm" for k in range(n)])
        for i in range(len(t)):
            w.writerow([repr(float(t[i]))] + [repr(float(x)) for x in q_d[i]]
                       + [repr(float(x)) for x in q[i]] + [repr(float(x)) for x in tau[i]])
    title = f"{robot.name}: quintic test, {controller} on {config.backend}"
    # every plant step: a 1 ms sampling would hide whatever happens inside the period
    plot_tracking(folder / "tracking.png", result.t, profile.evaluate(result.t)[0], result.q,
                  result.tau, title)
    try:
        record = pick_period(result.master.records, when=0.5 * config.trajectory.duration)
        plot_timeline(folder / "timeline.png", record, robot.n, config.timing.period_cycles,
                      f"{controller}: period {record.index} exchange ("
                      + ("the nodes' references" if config.backend == "model" else
                         "gateware") + " in the loop)",
                      skew=summary.get("period_skew"))
    except ValueError:
        plot_parameters(folder / "timeline.png", title=title,
                        note="no complete period in this run: no timeline to draw")
    skew_figure(folder / "skew.png", result, robot.n, config, controller)
    theta = getattr(result, "theta", None)
    if theta is not None:
        plot_parameters(folder / "parameters.png", result.t, theta, title=title)
    else:
        if controller != "vdc":
            note = f"{controller} has no parameter estimates (no model in the controller)"
        elif config.gains.adapt == 0.0:
            note = ("adaptation off (gains.adapt = 0): the VDC estimates stay at the nominal "
                    "Table 1 values for the whole run")
        else:
            note = (f"adaptation on (gains.adapt = {config.gains.adapt:g}), but this backend "
                    "does not report the node's estimates: nothing to plot")
        plot_parameters(folder / "parameters.png", title=title, note=note)
        summary["parameter_estimates"] = note
    write_json(folder / "summary.json", summary)


def tip_error(robot, q_d, q) -> np.ndarray:
    """‖p_tip(q_d) − p_tip(q)‖ per sample, m; ``q_d, q`` shape (n_samples, n)."""
    return np.array([np.linalg.norm(robot.tip_pose(a)[:3, 3] - robot.tip_pose(b)[:3, 3])
                     for a, b in zip(q_d, q, strict=True)])


def _comparison_plots(folder: Path, robot, config, runs, profile, jobs: int = 1) -> None:
    """The paper's Fig. 4 and 5 and the torques of every controller (three PNGs); with
    ``jobs`` > 1 drawn side by side on forked processes (the same files: each figure is drawn
    from the same data by the same code wherever it runs)."""
    first = next(iter(runs.values()))[0]
    every = _every_ms(first.t)
    t = first.t[::every]
    q_d = profile.evaluate(t)[0]
    qs = {c: r.q[::every][: len(t)] for c, (r, _) in runs.items()}
    sub = f"{robot.name}, {config.backend}, seed {config.seed}"
    from mrm_cosim.cosim.plots import plot_error_comparison, plot_joint_tracking, plot_torques

    figures = [
        (plot_joint_tracking, (folder / "fig4_tracking.png", t, q_d, qs,
                               f"Joint tracking (paper Fig. 4), {sub}"), {}),
        (plot_error_comparison, (folder / "fig5_errors.png", t,
                                 {c: q_d - q for c, q in qs.items()},
                                 {c: tip_error(robot, q_d, q) for c, q in qs.items()},
                                 f"Tracking errors (paper Fig. 5), {sub}"), {}),
        (plot_torques, (folder / "torques.png", first.t,
                        {c: r.tau for c, (r, _) in runs.items()},
                        f"Torque commands (every plant step), {sub}"),
         {"peak": robot.peak_torques}),
    ]
    if jobs <= 1:
        for spec in figures:
            _draw(spec)
        return
    from mrm_cosim.cosim.executors import LocalExecutor

    with LocalExecutor(min(jobs, len(figures))) as ex:
        for i, status, value in ex.run(_draw, figures):
            if status != "ok":
                raise RuntimeError(f"drawing {figures[i][1][0].name} failed in its "
                                   f"process:\n{value}")


def _draw(spec, report=None) -> None:
    """One of :func:`_comparison_plots`' figures, ``(plot, args, kwargs)``: ``plot(*args,
    **kwargs)`` (``report``: the executor's, unused)."""
    plot, args, kwargs = spec
    plot(*args, **kwargs)
