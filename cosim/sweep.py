"""Sweeps and Monte Carlo: many independent runs of an experiment, on any executor.

A sweep spec (TOML) names a base experiment config and the axes to vary::

    [sweep]
    name = "table2-seeds"
    kind = "track"                      # "track" (the config's trajectory) or "line"
    config = "table2"                   # a package config (configs/<name>.toml) or a path
    controllers = ["pid-1khz", "pid-fpga", "vdc"]    # default: the config's
    backends = ["model"]                # default: the config's
    seeds = { start = 1000, count = 32 }             # or a list; default: the config's seed
    duration = 1.2                      # optional: the config's otherwise

    [[axis]]                            # a grid axis (any number; their product)
    field = "gains.lam"                 # any config field, dotted
    values = [50.0, 100.0, 200.0]       # or: range = { start = 50.0, stop = 200.0, num = 4 }

    [draws]                             # random or Latin-hypercube draws, jointly (optional)
    method = "lhs"                      # "random" or "lhs"
    count = 16
    seed = 0
    fields = { "gains.K" = [0.0, 50.0] }

A sweep of ``kind = "line"`` runs a Cartesian line (``line = "path/to/line.toml"``, as for
``mrm run line``; its config defaults to ``"line"``, the six-module arm) over ``profiles``
(``["trig"]`` by default, ``"ruckig"`` too), and reports the tool's position and orientation
errors instead of ρ.

A sweep of ``kind = "link-faults"`` is the fault campaign: its own ``[campaign]`` table
instead of axes, chunks of link-level faults or closed-loop runs as points
(:mod:`cosim.fault_campaign`, docs/sweeps.md).

The points are the product of the grid axes, the draws, the controllers, the backends and the
seeds (a seed is the plant's draw: repeated seeds are Monte Carlo over plants). A point is a
pure function (:func:`run_point`: resolved config + controller → summary figures); it writes
its own folder ``points/<id>/`` (``id`` a hash of its resolved config, seed and controller)
and the sweep appends one line per finished point to ``points.jsonl`` as results arrive, so a
killed sweep loses only the points in flight and ``resume`` skips the finished ones.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mrm_cosim.errors import InputError
from mrm_cosim.tomlfile import read_toml

__all__ = ["SweepSpec", "load_spec", "expand", "run_point", "run_sweep", "check_out",
           "FIGURES", "summary_markdown"]

#: The figures of a point kept in points.jsonl (from :func:`cosim.track.run_track`'s summary).
FIGURES = ("rho_s", "max_tip_error_m", "max_tip_speed_m_s", "max_joint_error_rad",
           "overruns", "link_errors", "upload_errors")
#: A track's robustness figures (:func:`cosim.track.hold_figures`), kept too: the tuning's
#: constraints (cosim/tune.py).
HOLD_FIGURES = ("max_torque_ratio", "hold_error_rad", "hold_ripple_rad")
#: The period-start skew (:func:`cosim.skew.period_skew`), kept for a config with clocks of its
#: own (``[clocks]``, docs/clocks.md): cycles, against the master (largest, RMS) and between the
#: nodes (largest).
SKEW_FIGURES = ("skew_max_cycles", "skew_rms_cycles", "skew_between_max_cycles")
#: A line's figures (its summary's ``line``), kept beside the common ones.
LINE_FIGURES = ("max_position_error_mm", "max_orientation_error_mrad", "max_se3_error")
#: The two figures summary.md and the plots show per kind: (key, label, scale to the label).
SHOWN = {"track": (("rho_s", "ρ (s)", 1.0), ("max_tip_error_m", "tip error (mm)", 1e3)),
         "line": (("max_position_error_mm", "tool position error (mm)", 1.0),
                  ("max_orientation_error_mrad", "tool orientation error (mrad)", 1.0))}
#: "link-faults": the fault campaign (cosim/fault_campaign.py), its own [campaign] table.
KINDS = (*SHOWN, "link-faults")

_SPEC_KEYS = {"sweep", "axis", "draws"}
_SWEEP_KEYS = {"name", "kind", "config", "controllers", "backends", "seeds", "duration", "line",
               "profiles"}
MAX_POINTS = 1_000_000


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep spec (see the module docstring)."""

    name: str
    config: dict                              # the base config, resolved, as plain data
    config_source: str
    controllers: tuple[str, ...]
    backends: tuple[str, ...]
    seeds: tuple[int, ...]
    axes: tuple[tuple[str, tuple], ...] = ()  # (field, values) grid axes
    draws: dict = field(default_factory=dict)  # {"method", "count", "seed", "fields"}
    kind: str = "track"
    line: dict | None = None                  # kind "line": the parsed line file
    profiles: tuple[str, ...] = ("trig",)
    line_duration: float | None = None        # kind "line": [sweep] duration, if set

    def to_toml(self) -> str:
        """The resolved spec as TOML: the sweep's keys, its axes (ranges as their values),
        its draws, and the base config as every point starts from it (``[base.*]``)."""
        from mrm_cosim.cosim.experiment_config import _dump_toml

        keys = {"name": self.name, "kind": self.kind, "config": self.config_source,
                "controllers": list(self.controllers), "backends": list(self.backends),
                "seeds": list(self.seeds)}
        if self.kind == "line":
            keys["profiles"] = list(self.profiles)
        text = _dump_toml({"sweep": keys})
        for f, values in self.axes:
            text += f"\n[[axis]]\nfield = {json.dumps(f)}\nvalues = {json.dumps(list(values))}\n"
        if self.draws:
            d = self.draws
            text += (f"\n[draws]\nmethod = {json.dumps(d['method'])}\ncount = {d['count']}\n"
                     f"seed = {d['seed']}\n\n[draws.fields]\n")
            text += "".join(f"{json.dumps(k)} = {json.dumps(list(v))}\n"
                            for k, v in d["fields"].items())
        text += "\n" + _dump_toml({"base": self.config})
        if self.line is not None:
            text += "\n" + _dump_toml({"line": self.line})
        return text


def _config_path(name: str, base_dir: Path) -> Path:
    from mrm_cosim import configs

    if name.endswith(".toml"):
        path = Path(name)
        return path if path.is_absolute() else base_dir / path
    path = Path(configs.__file__).resolve().parent / f"{name}.toml"
    if not path.is_file():
        raise InputError("sweep.config", f"no package config {name!r} (a name from "
                         "configs/ or a path ending in .toml)")
    return path


def _set(tree: dict, dotted: str, value) -> dict:
    """A copy of the nested dict ``tree`` with ``dotted`` set to ``value``."""
    out = json.loads(json.dumps(tree))
    node = out
    parts = dotted.split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise InputError(dotted, "is not a table of the config")
    node[parts[-1]] = value
    return out


def _check_field(config: dict, dotted: str, value, where: str) -> None:
    """Refuse (naming ``where``) a field the config does not have or a value it refuses."""
    from mrm_cosim.cosim.experiment_config import from_dict

    if not isinstance(dotted, str) or "." not in dotted:
        raise InputError(where, f"must be a dotted config field like 'gains.lam', not {dotted!r}")
    if dotted.split(".")[0] == "experiment":
        raise InputError(where, f"{dotted}: the experiment's controllers, backend, seed and "
                         "duration are the sweep's own keys ([sweep] controllers, backends, "
                         "seeds, duration)")
    try:
        from_dict(_set(config, dotted, value))
    except InputError as exc:
        raise InputError(where, f"{exc.field}: {exc.message}") from None


def _numbers(value, where: str) -> tuple:
    if not isinstance(value, list) or not value:
        raise InputError(where, f"must be a non-empty list, not {value!r}")
    return tuple(value)


def _grid_values(axis: dict, where: str) -> tuple:
    if ("values" in axis) == ("range" in axis):
        raise InputError(where, "needs exactly one of 'values' (a list) or 'range' "
                         "({ start, stop, num })")
    if "values" in axis:
        values = _numbers(axis["values"], f"{where}.values")
        for k, v in enumerate(values):
            if values.index(v) != k:        # a repeated value would run the same points twice
                raise InputError(f"{where}.values", f"{v!r} is given twice")
        return values
    r = axis["range"]
    if not isinstance(r, dict) or set(r) - {"start", "stop", "num", "log"} or \
            not {"start", "stop", "num"} <= set(r):
        raise InputError(f"{where}.range", "must be { start, stop, num [, log] }")
    num = r["num"]
    if isinstance(num, bool) or not isinstance(num, int) or not 1 <= num <= 10_000:
        raise InputError(f"{where}.range.num", f"must be a whole number 1..10000, not {num!r}")
    lo, hi = (float(r["start"]), float(r["stop"]))
    if r.get("log", False):
        if lo <= 0 or hi <= 0:
            raise InputError(f"{where}.range", "a log range needs positive ends")
        return tuple(float(x) for x in np.geomspace(lo, hi, num))
    return tuple(float(x) for x in np.linspace(lo, hi, num))


def _seeds(value) -> tuple[int, ...]:
    if isinstance(value, dict):
        if set(value) != {"start", "count"}:
            raise InputError("sweep.seeds", "must be a list or { start, count }")
        start, count = value["start"], value["count"]
        for k, v in (("start", start), ("count", count)):
            if isinstance(v, bool) or not isinstance(v, int) or v < (1 if k == "count" else 0):
                raise InputError(f"sweep.seeds.{k}", f"must be a whole number, not {v!r}")
        return tuple(range(start, start + count))
    seeds = _numbers(value, "sweep.seeds")
    for s in seeds:
        if isinstance(s, bool) or not isinstance(s, int) or s < 0:
            raise InputError("sweep.seeds", f"must be non-negative integers, not {s!r}")
    return seeds


def load_spec(path) -> SweepSpec:
    """Read and validate a sweep spec (every axis against the base config)."""
    from mrm_cosim.cosim.experiment_config import load
    from mrm_cosim.cosim.track import BACKENDS
    from mrm_cosim.master.cycle import CONTROLLERS

    path = Path(path)
    data = read_toml(path, "SPEC")
    if isinstance(data.get("sweep"), dict) and data["sweep"].get("kind") == "link-faults":
        from mrm_cosim.cosim.fault_campaign import load_campaign

        return load_campaign(data, path)
    for key in data:
        if key not in _SPEC_KEYS:
            raise InputError(key, f"unknown table; known: {', '.join(sorted(_SPEC_KEYS))}")
    sw = data.get("sweep", {})
    if not isinstance(sw, dict):
        raise InputError("sweep", "must be a table")
    for key in sw:
        if key not in _SWEEP_KEYS:
            raise InputError(f"sweep.{key}",
                             f"unknown key; known: {', '.join(sorted(_SWEEP_KEYS))}")
    kind = sw.get("kind", "track")
    if kind not in KINDS:
        raise InputError("sweep.kind", f"must be one of {', '.join(KINDS)}, not {kind!r}")
    line, profiles = None, ("trig",)
    if kind == "line":
        line, profiles = _line_keys(sw, path.resolve().parent)
    elif "line" in sw or "profiles" in sw:
        raise InputError("sweep.line" if "line" in sw else "sweep.profiles",
                         "only for kind = \"line\"")
    source = sw.get("config", "line" if kind == "line" else "table2")
    if not isinstance(source, str) or not source:
        raise InputError("sweep.config", f"must be a config name or path, not {source!r}")
    try:
        base = load(_config_path(source, path.resolve().parent))
    except InputError as exc:
        if exc.field != "config":           # a field of the named config: its own name
            raise
        raise InputError("sweep.config", exc.message) from None
    if "duration" in sw:
        base = base.with_overrides(duration=sw["duration"], field_prefix="sweep.")
    config = base.to_dict()
    controllers = tuple(sw.get("controllers", base.controllers))
    for c in controllers:
        if c not in CONTROLLERS:
            raise InputError("sweep.controllers", f"unknown controller {c!r}; known: "
                             f"{', '.join(CONTROLLERS)}")
    backends = tuple(sw.get("backends", [base.backend]))
    for b in backends:
        if b not in BACKENDS:
            raise InputError("sweep.backends", f"unknown backend {b!r}; known: "
                             f"{', '.join(BACKENDS)}")
    seeds = _seeds(sw.get("seeds", [base.seed]))
    axes = []
    raw_axes = data.get("axis", [])
    if not isinstance(raw_axes, list):
        raise InputError("axis", "must be an array of tables ([[axis]])")
    for k, axis in enumerate(raw_axes):
        where = f"axis[{k}]"
        if not isinstance(axis, dict) or set(axis) - {"field", "values", "range"}:
            raise InputError(where, "must be a table with 'field' and 'values' or 'range'")
        values = _grid_values(axis, where)
        f = axis.get("field")
        for v in values:
            _check_field(config, f, v, f"{where}.field")
        axes.append((f, values))
    draws = {}
    if "draws" in data:
        draws = _draws(data["draws"], config)
    spec = SweepSpec(str(sw.get("name", path.stem)), config, source, controllers, backends,
                     seeds, tuple(axes), draws, kind, line, profiles,
                     base.duration if kind == "line" and "duration" in sw else None)
    n = _count(spec)
    if n > MAX_POINTS:
        raise InputError("SPEC", f"{n:,} points; at most {MAX_POINTS:,} in one sweep")
    return spec


def _line_keys(sw: dict, base_dir: Path) -> tuple[dict, tuple[str, ...]]:
    """The line file (parsed and checked) and the profiles of a sweep of kind ``line``."""
    from mrm_cosim.cosim.line import PROFILES
    from mrm_cosim.master.line_file import parse_line_spec

    name = sw.get("line")
    if not isinstance(name, str) or not name.endswith(".toml"):
        raise InputError("sweep.line", f"must name the line's .toml file, not {name!r}")
    path = Path(name) if Path(name).is_absolute() else base_dir / name
    doc = read_toml(path, "sweep.line")
    try:
        parse_line_spec(doc)
    except InputError as exc:
        raise InputError(f"sweep.line: {exc.field}", exc.message) from None
    profiles = tuple(sw.get("profiles", ["trig"]))
    for p in profiles:
        if p not in PROFILES:
            raise InputError("sweep.profiles", f"unknown profile {p!r}; known: "
                             f"{', '.join(PROFILES)}")
    return doc, profiles


def _draws(d, config) -> dict:
    if not isinstance(d, dict) or set(d) - {"method", "count", "seed", "fields"}:
        raise InputError("draws", "must be { method, count, seed, fields }")
    method = d.get("method", "random")
    if method not in ("random", "lhs"):
        raise InputError("draws.method", f"must be 'random' or 'lhs', not {method!r}")
    count, seed = d.get("count"), d.get("seed", 0)
    for k, v in (("count", count), ("seed", seed)):
        if isinstance(v, bool) or not isinstance(v, int) or v < (1 if k == "count" else 0):
            raise InputError(f"draws.{k}", f"must be a whole number, not {v!r}")
    fields = d.get("fields")
    if not isinstance(fields, dict) or not fields:
        raise InputError("draws.fields", "must map config fields to [low, high]")
    out = {}
    for f, bounds in fields.items():
        where = f"draws.fields.{f}"
        if (not isinstance(bounds, list) or len(bounds) != 2
                or not all(isinstance(b, int | float) and not isinstance(b, bool) for b in bounds)
                or not bounds[0] < bounds[1]):
            raise InputError(where, f"must be [low, high] with low < high, not {bounds!r}")
        for b in bounds:
            _check_field(config, f, float(b), where)
        out[f] = (float(bounds[0]), float(bounds[1]))
    return {"method": method, "count": count, "seed": seed, "fields": out}


def _draw_params(draws: dict) -> list[dict]:
    """The draws' parameter sets: uniform random, or a Latin hypercube (one draw in each of
    ``count`` equal strata per field, strata paired at random), from ``draws["seed"]``."""
    if not draws:
        return [{}]
    rng = np.random.default_rng(draws["seed"])
    n, fields = draws["count"], draws["fields"]
    cols = {}
    for f, (lo, hi) in fields.items():
        if draws["method"] == "lhs":
            u = (rng.permutation(n) + rng.random(n)) / n
        else:
            u = rng.random(n)
        cols[f] = lo + (hi - lo) * u
    return [{f: float(cols[f][i]) for f in fields} for i in range(n)]


def _count(spec: SweepSpec) -> int:
    grid = math.prod(len(v) for _, v in spec.axes)
    return (grid * max(1, spec.draws.get("count", 1)) * len(spec.controllers)
            * len(spec.backends) * len(spec.seeds) * len(spec.profiles))


def point_id(config: dict, controller: str, task: dict | None = None) -> str:
    """A point's name: the hash of its resolved config (seed and backend included), its
    controller and, for a line, the line and its profile (``task``)."""
    text = json.dumps({"config": config, "controller": controller, **(task or {})},
                      sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def expand(spec: SweepSpec) -> list[dict]:
    """Every point of the sweep, each validated (a bad one is named by its field and
    parameters before anything runs): ``{"id", "params", "seed", "controller", "backend",
    "config"}``."""
    from mrm_cosim.cosim.experiment_config import from_dict

    if spec.kind == "link-faults":
        from mrm_cosim.cosim.fault_campaign import expand_campaign

        return expand_campaign(spec)
    grid = [dict(zip([f for f, _ in spec.axes], combo, strict=True))
            for combo in itertools.product(*(v for _, v in spec.axes))]
    points, seen = [], set()
    for g, d, c, b, s, prof in itertools.product(grid, _draw_params(spec.draws),
                                                 spec.controllers, spec.backends, spec.seeds,
                                                 spec.profiles):
        params = {**g, **d}
        cfg = spec.config
        for f, v in params.items():
            cfg = _set(cfg, f, v)
        cfg = _set(_set(_set(cfg, "experiment.seed", s), "experiment.backend", b),
                   "experiment.controllers", [c])
        try:
            cfg = from_dict(cfg).to_dict()
        except InputError as exc:
            raise InputError(f"point {params or ''} {c} seed {s}: {exc.field}".replace("  ", " "),
                             exc.message) from None
        # a line runs the move and its hold unless the sweep sets a duration
        task = ({"kind": "line", "line": spec.line, "profile": prof,
                 "duration": spec.line_duration} if spec.kind == "line" else None)
        pid = point_id(cfg, c, task)
        if pid in seen:
            continue
        seen.add(pid)
        points.append({"id": pid, "params": params, "seed": s, "controller": c, "backend": b,
                       "kind": spec.kind, "profile": prof if spec.kind == "line" else None,
                       "line": spec.line, "line_duration": spec.line_duration, "config": cfg})
    return points


def run_point(point: dict, report=None) -> dict:
    """Run one point: a pure function of ``point["config"]`` and ``point["controller"]``
    (and ``point["folder"]``, where it writes ``summary.json`` and ``config.toml`` when
    given). Returns the figures kept in points.jsonl."""
    if point.get("kind") == "link-faults":
        from mrm_cosim.cosim.fault_campaign import run_campaign_point

        return run_campaign_point(point)
    from mrm_cosim import __version__
    from mrm_cosim.cosim.experiment_config import from_dict
    from mrm_cosim.cosim.table2 import _run_kwargs
    from mrm_cosim.cosim.track import run_faults, run_track
    from mrm_cosim.models.robot import load_robot
    from mrm_cosim.results import write_json

    config = from_dict(point["config"])
    robot = load_robot(config.robot)
    t0 = time.perf_counter()
    if point.get("kind", "track") == "line":
        from mrm_cosim.cosim.line import run_line
        from mrm_cosim.master.line_file import parse_line_spec
        from mrm_cosim.master.trig_planner import plan_line

        plan = plan_line(*parse_line_spec(point["line"]))
        summary = run_line(robot, plan, profile=point["profile"],
                           controller=point["controller"], backend=config.backend,
                           seed=config.seed, gains=config.gains, timing=config.timing,
                           plant_config=config.plant,
                           duration=point.get("line_duration")).summary
        figures = {k: summary[k] for k in FIGURES if k != "rho_s"}
        figures.update({k: summary["line"][k] for k in LINE_FIGURES})
    else:
        _, summary = run_track(robot, point["controller"], config.backend, config.duration,
                               config.seed, gains=config.gains, timing=config.timing,
                               plant_config=config.plant,
                               **_run_kwargs(run_track, config, robot))
        figures = {k: summary[k] for k in FIGURES + HOLD_FIGURES}
        if not config.clocks.common:
            skew = summary["period_skew"]
            figures.update(zip(SKEW_FIGURES, (skew["node_vs_master"]["max_abs_cycles"],
                                              skew["node_vs_master"]["rms_cycles"],
                                              skew["between_nodes"]["max_cycles"]),
                               strict=True))
    out = {"figures": figures, "faults": run_faults(summary),
           "trace_sha256": summary["trace_sha256"], "wall_s": time.perf_counter() - t0}
    if point.get("folder"):
        folder = Path(point["folder"])
        folder.mkdir(parents=True, exist_ok=True)
        write_json(folder / "summary.json", dict(summary, version=__version__,
                                                 params=point["params"]))
        (folder / "config.toml").write_text(config.to_toml())
    return out


def _stats(values) -> dict:
    a = np.asarray(values, dtype=float)
    return {"n": int(a.size), "mean": float(a.mean()), "median": float(np.median(a)),
            "p5": float(np.percentile(a, 5)), "p95": float(np.percentile(a, 95))}


def summary_markdown(spec: SweepSpec, rows: list[dict]) -> str:
    """Per axis value (and per controller): mean, median and 5–95 % interval of ρ and of the
    largest tip error over the finished points."""
    ok = [r for r in rows if r["status"] == "ok"]
    lines = [f"# Sweep {spec.name}", "",
             f"{len(ok)} of {len(rows)} points finished; config {spec.config_source}, "
             f"controllers {', '.join(spec.controllers)}, backends {', '.join(spec.backends)}, "
             f"{len(spec.seeds)} seed(s).", ""]
    failed = [r for r in rows if r["status"] != "ok"]
    if failed:
        lines += [f"**{len(failed)} point(s) failed** (points.jsonl has the errors).", ""]
    if spec.kind == "track" and len(spec.seeds) > 1:
        lines += distribution_table(ok, spec.controllers)
    if any(SKEW_FIGURES[0] in r["figures"] for r in ok):
        lines += skew_table(ok, spec.controllers)
    (k1, l1, _), (k2, l2, _) = SHOWN[spec.kind]
    axes = ["controller"] + (["backend"] if len(spec.backends) > 1 else []) + \
        (["profile"] if len(spec.profiles) > 1 else []) + \
        [f for f, _ in spec.axes] + list(spec.draws.get("fields", {}))
    for axis in axes:
        lines += [f"## By {axis}", "",
                  f"| {axis} | points | {l1}: mean | median | 5–95 % | {l2}: median | "
                  "5–95 % |", "|---|---|---|---|---|---|---|"]
        def key(r, axis=axis):
            return (r.get(axis) if axis in ("controller", "backend", "profile")
                    else r["params"].get(axis))

        values = sorted({key(r) for r in ok}, key=lambda v: (str(type(v)), v))
        if axis in spec.draws.get("fields", {}):
            values = []                      # drawn values are all different: bins instead
            lo, hi = spec.draws["fields"][axis]
            edges = np.linspace(lo, hi, 5)
            for a, b in zip(edges[:-1], edges[1:], strict=True):
                sel = [r for r in ok if a <= r["params"][axis] <= b]
                if sel:
                    lines.append(_row(f"{a:.4g}–{b:.4g}", sel, spec.kind))
        for v in values:
            sel = [r for r in ok if key(r) == v]
            lines.append(_row(v, sel, spec.kind))
        lines.append("")
    return "\n".join(lines)


def distribution(values) -> dict:
    """Median and 5–95 % interval (numpy's linear percentiles) of ``values``."""
    return _stats(values)


def distribution_table(ok: list[dict], controllers) -> list[str]:
    """Table 2 as a prediction: per controller, ρ's median and 5–95 % interval over the
    finished points (over plants, and over whatever else the sweep varies) beside the MRM
    paper's ρ (Table 2)."""
    from mrm_cosim.cosim.table2 import PAPER_TABLE2

    lines = ["## ρ over plants (Table 2 as a prediction)", "",
             "| controller | points | ρ median (s) | ρ 5 % (s) | ρ 95 % (s) | paper ρ (s) | "
             "tip error median (mm) | 5–95 % (mm) |", "|---|---|---|---|---|---|---|---|"]
    for c in controllers:
        sel = [r for r in ok if r["controller"] == c]
        if not sel:
            continue
        rho = distribution([r["figures"]["rho_s"] for r in sel])
        err = distribution([1e3 * r["figures"]["max_tip_error_m"] for r in sel])
        paper = PAPER_TABLE2.get(c)
        lines.append(f"| {c} | {rho['n']} | {rho['median']:.4g} | {rho['p5']:.4g} | "
                     f"{rho['p95']:.4g} | {'–' if paper is None else f'{paper[2]:.2g}'} | "
                     f"{err['median']:.4g} | {err['p5']:.4g} – {err['p95']:.4g} |")
    return lines + [""]


def skew_table(ok: list[dict], controllers) -> list[str]:
    """The period-start skew over the points (clocks drawn from each seed, docs/clocks.md):
    per controller, the median, 5–95 % interval and worst of each run's largest offset
    against the master, its RMS and the largest spread between the nodes, in cycles."""
    lines = ["## Period-start skew over clock draws (cycles)", "",
             "| controller | points | max vs master: median | 5–95 % | worst | "
             "RMS: median | 5–95 % | between nodes, max: median | worst |",
             "|---|---|---|---|---|---|---|---|---|"]
    for c in controllers:
        sel = [r["figures"] for r in ok if r["controller"] == c and
               all(r["figures"].get(k) is not None for k in SKEW_FIGURES)]
        if not sel:
            continue
        mx, rms, btw = (_stats([f[k] for f in sel]) for k in SKEW_FIGURES)
        lines.append(f"| {c} | {mx['n']} | {mx['median']:.4g} | {mx['p5']:.4g} – "
                     f"{mx['p95']:.4g} | {max(f[SKEW_FIGURES[0]] for f in sel):.4g} | "
                     f"{rms['median']:.3g} | {rms['p5']:.3g} – {rms['p95']:.3g} | "
                     f"{btw['median']:.4g} | {max(f[SKEW_FIGURES[2]] for f in sel):.4g} |")
    return lines + [""]


def _row(label, sel, kind: str = "track") -> str:
    (k1, _, s1), (k2, _, s2) = SHOWN[kind]
    rho = _stats([s1 * r["figures"][k1] for r in sel])
    err = _stats([s2 * r["figures"][k2] for r in sel])
    return (f"| {label} | {rho['n']} | {rho['mean']:.4g} | {rho['median']:.4g} | "
            f"{rho['p5']:.4g} – {rho['p95']:.4g} | {err['median']:.4g} | "
            f"{err['p5']:.4g} – {err['p95']:.4g} |")


def _plots(out: Path, spec: SweepSpec, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in rows if r["status"] == "ok"]
    if not ok:
        return
    (key, label, scale), _ = SHOWN[spec.kind]
    fig, ax = plt.subplots(figsize=(6.5, 3.5))
    data = [[scale * r["figures"][key] for r in ok if r["controller"] == c]
            for c in spec.controllers]
    ax.boxplot([d if d else [np.nan] for d in data], tick_labels=list(spec.controllers))
    ax.set_yscale("log")
    ax.set_ylabel(label)
    ax.set_title(f"{spec.name}: {label} per controller ({len(ok)} points)")
    ax.grid(True, lw=0.3)
    fig.tight_layout()
    fig.savefig(out / f"{_stem(key)}_by_controller.png", dpi=110)
    plt.close(fig)
    fields = [f for f, _ in spec.axes] + list(spec.draws.get("fields", {}))
    for f in fields:
        fig, ax = plt.subplots(figsize=(6.5, 3.5))
        for c in spec.controllers:
            sel = [r for r in ok if r["controller"] == c]
            ax.plot([r["params"][f] for r in sel], [scale * r["figures"][key] for r in sel], "o",
                    ms=3, label=c)
        ax.set_yscale("log")
        ax.set_xlabel(f)
        ax.set_ylabel(label)
        ax.legend(fontsize=7)
        ax.grid(True, lw=0.3)
        fig.tight_layout()
        fig.savefig(out / f"{_stem(key)}_vs_{f.replace('.', '_')}.png", dpi=110)
        plt.close(fig)


def _stem(key: str) -> str:
    """File-name stem of a figure: ``rho`` for ρ, ``position_error`` for a line's."""
    return {"rho_s": "rho", "max_position_error_mm": "position_error"}.get(key, key)


def _finished(path: Path) -> dict[str, dict]:
    rows = {}
    if path.is_file():
        for line in path.read_text().splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:      # a line cut by a kill: that point reruns
                continue
            rows[row["id"]] = row
    return rows


def _point_task(point: dict, report) -> dict:
    return run_point(point, report)


def check_out(out, resume: bool = False) -> Path:
    """The result folder of a sweep, or ``InputError`` naming ``out``: not a file, and not a
    folder that already holds a sweep unless ``resume``."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError("out", f"{str(out)!r} exists and is not a folder")
    if (out / "points.jsonl").exists() and not resume:
        raise InputError("out", f"{str(out)!r} holds a sweep already: --resume it or choose "
                         "another folder")
    return out


def run_sweep(spec: SweepSpec, out, executor, *, resume: bool = False, progress=None,
              plots: bool = True) -> dict:
    """Run every point of ``spec`` not yet finished in ``out`` on ``executor``; append each
    result to ``out/points.jsonl`` as it arrives; then write ``summary.md`` and (unless
    ``plots`` is false) the plots.
    Returns ``{"total", "ran", "skipped", "failed", "rows"}``."""
    out = check_out(out, resume)
    jsonl = out / "points.jsonl"
    points = expand(spec)
    done = {k: v for k, v in _finished(jsonl).items() if v.get("status") == "ok"}
    todo = [dict(p, folder=str(out / "points" / p["id"])) for p in points if p["id"] not in done]
    # plant by plant: a sweep cut short has run every controller on the same plants
    todo.sort(key=lambda p: spec.seeds.index(p["seed"]))
    out.mkdir(parents=True, exist_ok=True)
    (out / "sweep.toml").write_text(spec.to_toml())
    rows = {p["id"]: done[p["id"]] for p in points if p["id"] in done}
    t0, finished, failed = time.perf_counter(), 0, 0
    with open(jsonl, "a", encoding="utf-8") as fh:
        if jsonl.stat().st_size and not jsonl.read_bytes().endswith(b"\n"):
            fh.write("\n")                 # a line cut by a kill stays a line of its own
        for i, status, value in executor.run(_point_task, todo):
            p = todo[i]
            row = {"id": p["id"], "params": p["params"], "seed": p["seed"],
                   "controller": p["controller"], "backend": p["backend"], "status": status}
            if p.get("profile"):
                row["profile"] = p["profile"]
            if status == "ok":
                row.update(value)
            else:
                failed += 1
                row["error"] = (f"{value[0]}: {value[1]}" if status == "input" else value)
            fh.write(json.dumps(row) + "\n")
            fh.flush()
            rows[p["id"]] = row
            finished += 1
            if progress is not None:
                rate = finished / max(time.perf_counter() - t0, 1e-9)
                progress(finished, len(todo), rate, (len(todo) - finished) / rate)
    ordered = [rows[p["id"]] for p in points if p["id"] in rows]
    if spec.kind == "link-faults":
        from mrm_cosim.cosim.fault_campaign import write_campaign_summary

        write_campaign_summary(out, spec, ordered, plots)
    else:
        (out / "summary.md").write_text(summary_markdown(spec, ordered))
        if plots:
            _plots(out, spec, ordered)
    return {"total": len(points), "ran": finished, "skipped": len(points) - len(todo),
            "failed": failed, "rows": ordered}


def print_progress(done: int, total: int, rate: float, eta: float, stream=None) -> None:
    """One progress line: done/total, rate and ETA."""
    stream = stream or sys.stderr
    stream.write(f"sweep: {done}/{total} points, {rate:.3g} points/s, ETA {eta:.0f} s\n")
    stream.flush()
