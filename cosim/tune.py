"""One tuning procedure for every controller (issue 20 item 3), run as sweeps.

A tuning spec (TOML) names the base experiment, the controllers and, per controller, the
config fields to tune with their bounds; the tuning set (plant seeds and short quintics that
are not the test's); the constraints; the budget::

    [tune]
    name = "table2-compliant"
    config = "table2"                  # a package config or a path to a .toml
    controllers = ["pid-1khz", "pid-fpga", "vdc"]
    backend = "model"
    seeds = [3000, 3001]               # tuning plants: never a test plant (held_out)
    held_out = ["../sweeps/table2-seeds.toml"]   # test sweeps (relative to the spec)
    amplitudes = [0.10, -0.07]         # rad, joint 1 of the tuning quintics
    trajectory_duration = 0.3          # s, t_f of the tuning quintics
    hold = 0.2                         # s after t_f
    budget = 12                        # evaluations per controller (same for every one)
    initial = 6                        # of which the Latin hypercube
    seed = 0                           # the hypercube's seed
    max_torque_ratio = 0.95            # constraint: |τ| below this fraction of peak torque
    settle_error = 0.002               # rad, constraint: joint error at the end of the hold
    ripple = 0.001                     # rad, constraint: peak-to-peak error at the end

    [tune.set]                         # fields set on the base config for tuning
    "plant.joints" = "compliant"

    [tune.space.vdc]                   # per controller: field = [low, high]
    "gains.lam" = [20.0, 400.0]

**The procedure**, the same for every controller: the gains live in the unit cube (a field
with a positive lower bound on a log scale, one starting at 0 on a linear scale), rounded to
three significant figures. First ``initial`` points of a seeded Latin hypercube (scipy's
``qmc.LatinHypercube``), then a bounded Nelder–Mead (scipy) from the best of them, until the
controller has had ``budget`` distinct evaluations. One evaluation is one sweep
(:func:`cosim.sweep.run_sweep`) of the controller over the tuning plants × the tuning
quintics, in ``OUT/<controller>/e<k>/``; its objective is the mean of log10 ρ over those runs
when every run is feasible, and otherwise ``PENALTY`` plus the summed relative violations (so
the search is pulled back to the feasible side, and any feasible point beats any infeasible
one). A run is feasible when it is clean (:func:`cosim.track.run_faults`), no torque command
reaches ``max_torque_ratio`` of its actuator's peak torque, and over the last
:data:`cosim.track.HOLD_WINDOW` s of the hold the joint error stays below ``settle_error``
and its peak-to-peak below ``ripple`` (no divergence, no limit cycle).
"""

from __future__ import annotations

import datetime
import json
import math
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mrm_cosim.errors import InputError
from mrm_cosim.tomlfile import read_toml

__all__ = ["TuneSpec", "load_tune_spec", "run_tuning", "apply_gains", "PENALTY",
           "PROVENANCE_MARK"]

#: Objective of an infeasible evaluation (plus its relative violations): above any mean
#: log10 ρ a feasible run gives (ρ < 1 s).
PENALTY = 10.0
#: The first line of the provenance block :func:`apply_gains` writes into a config.
PROVENANCE_MARK = "# Tuned by mrm tune"
_KEYS = {"name", "config", "controllers", "backend", "seeds", "held_out", "amplitudes",
         "trajectory_duration", "hold", "budget", "initial", "seed", "max_torque_ratio",
         "settle_error", "ripple", "set", "space"}


@dataclass(frozen=True)
class TuneSpec:
    """A validated tuning spec (see the module docstring)."""

    name: str
    path: str                                  # the spec file
    config_path: str                           # the base config file
    config: dict                               # base config with [tune.set], as plain data
    controllers: tuple[str, ...]
    backend: str
    seeds: tuple[int, ...]
    held_out_seeds: tuple[int, ...]
    amplitudes: tuple[float, ...]
    trajectory_duration: float
    hold: float
    budget: int
    initial: int
    seed: int
    max_torque_ratio: float
    settle_error: float
    ripple: float
    set_fields: dict
    space: dict                                # controller -> {field: (low, high)}


def _pos_int(value, where: str, low: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise InputError(where, f"must be a whole number ≥ {low}, not {value!r}")
    return value


def _pos_float(value, where: str, top: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) \
            or value <= 0 or (top is not None and value > top):
        raise InputError(where, f"must be a positive number{'' if top is None else f' ≤ {top}'},"
                         f" not {value!r}")
    return float(value)


def load_tune_spec(path) -> TuneSpec:
    """Read and validate a tuning spec: every field against the base config, and the tuning
    set against the held-out test set (a tuning seed that is a test seed, or a tuning
    quintic that is the test's, is refused naming the field)."""
    from mrm_cosim.cosim.experiment_config import from_dict, load
    from mrm_cosim.cosim.sweep import _check_field, _config_path, _seeds, _set, load_spec
    from mrm_cosim.cosim.track import BACKENDS
    from mrm_cosim.master.cycle import CONTROLLERS

    path = Path(path)
    data = read_toml(path, "SPEC")
    for key in data:
        if key != "tune":
            raise InputError(key, "unknown table; known: tune")
    t = data.get("tune", {})
    if not isinstance(t, dict):
        raise InputError("tune", "must be a table")
    for key in t:
        if key not in _KEYS:
            raise InputError(f"tune.{key}", f"unknown key; known: {', '.join(sorted(_KEYS))}")
    here = path.resolve().parent
    source = t.get("config", "table2")
    if not isinstance(source, str) or not source:
        raise InputError("tune.config", f"must be a config name or path, not {source!r}")
    try:
        config_path = _config_path(source, here)
    except InputError as exc:
        raise InputError("tune.config", exc.message) from None
    try:
        base = load(config_path)
    except InputError as exc:
        if exc.field != "config":
            raise
        raise InputError("tune.config", exc.message) from None
    config = base.to_dict()
    set_fields = t.get("set", {})
    if not isinstance(set_fields, dict):
        raise InputError("tune.set", "must map config fields to values")
    for f, v in set_fields.items():
        _check_field(config, f, v, f"tune.set.{f}")
        config = _set(config, f, v)

    controllers = t.get("controllers", list(base.controllers))
    if not isinstance(controllers, list) or not controllers:
        raise InputError("tune.controllers", f"must be a non-empty list, not {controllers!r}")
    for c in controllers:
        if c not in CONTROLLERS:
            raise InputError("tune.controllers", f"unknown controller {c!r}; known: "
                             f"{', '.join(CONTROLLERS)}")
    backend = t.get("backend", base.backend)
    if backend not in BACKENDS:
        raise InputError("tune.backend", f"must be one of {', '.join(BACKENDS)}, not "
                         f"{backend!r}")
    try:
        seeds = _seeds(t.get("seeds"))
    except InputError as exc:
        raise InputError(exc.field.replace("sweep.", "tune."), exc.message) from None
    except TypeError:
        raise InputError("tune.seeds", "must be a list or { start, count }") from None

    # the held-out set: the config's own seed (the headline table) and every test sweep's
    held = {base.seed: str(config_path.name)}
    raw_held = t.get("held_out", [])
    if not isinstance(raw_held, list) or not all(isinstance(h, str) for h in raw_held):
        raise InputError("tune.held_out", "must be a list of sweep spec paths")
    for k, h in enumerate(raw_held):
        hp = Path(h) if Path(h).is_absolute() else here / h
        try:
            test = load_spec(hp)
        except InputError as exc:
            raise InputError(f"tune.held_out[{k}]", f"{exc.field}: {exc.message}") from None
        for s in test.seeds:
            held.setdefault(s, h)
    overlap = sorted(set(seeds) & set(held))
    if overlap:
        raise InputError("tune.seeds", f"seed(s) {overlap} are test plants ({held[overlap[0]]}"
                         "): tune on plants the test does not use")

    amps = t.get("amplitudes")
    if not isinstance(amps, list) or not amps:
        raise InputError("tune.amplitudes", f"must be a non-empty list of rad, not {amps!r}")
    tf = _pos_float(t.get("trajectory_duration"), "tune.trajectory_duration", 60.0)
    hold = _pos_float(t.get("hold"), "tune.hold", 60.0)
    test_tr = base.trajectory
    for k, a in enumerate(amps):
        where = f"tune.amplitudes[{k}]"
        if isinstance(a, bool) or not isinstance(a, int | float):
            raise InputError(where, f"must be a number, not {a!r}")
        if a == test_tr.amplitude and tf == test_tr.duration:
            raise InputError(where, f"{a!r} rad in {tf!r} s is the test's quintic: tune on "
                             "other trajectories")
        _check_field(config, "trajectory.amplitude", float(a), where)
    from mrm_cosim.cosim.track import HOLD_WINDOW

    if hold <= HOLD_WINDOW:
        raise InputError("tune.hold", f"must be longer than the window the constraints "
                         f"judge ({HOLD_WINDOW} s), not {hold!r}")
    config = _set(_set(_set(config, "trajectory.duration", tf), "trajectory.hold", hold),
                  "experiment.duration", tf + hold)
    try:
        from_dict(config)
    except InputError as exc:
        raise InputError("tune.trajectory_duration", f"{exc.field}: {exc.message}") from None

    budget = _pos_int(t.get("budget"), "tune.budget")
    initial = _pos_int(t.get("initial", max(1, budget // 2)), "tune.initial")
    if initial > budget:
        raise InputError("tune.initial", f"{initial} is more than the budget ({budget})")
    seed = _pos_int(t.get("seed", 0), "tune.seed", 0)
    space_raw = t.get("space")
    if not isinstance(space_raw, dict):
        raise InputError("tune.space", "must have a table per controller: field = [low, high]")
    space = {}
    for c in controllers:
        fields = space_raw.get(c)
        if not isinstance(fields, dict) or not fields:
            raise InputError(f"tune.space.{c}", "must map the controller's gains to "
                             "[low, high]")
        space[c] = {}
        for f, b in fields.items():
            where = f"tune.space.{c}.{f}"
            if (not isinstance(b, list) or len(b) != 2 or not all(
                    isinstance(x, int | float) and not isinstance(x, bool) for x in b)
                    or not 0 <= b[0] < b[1]):
                raise InputError(where, f"must be [low, high] with 0 ≤ low < high, not {b!r}")
            for x in b:
                _check_field(config, f, float(x), where)
            space[c][f] = (float(b[0]), float(b[1]))
    for c in space_raw:
        if c not in controllers:
            raise InputError(f"tune.space.{c}", "is not one of tune.controllers")
    return TuneSpec(
        str(t.get("name", path.stem)), str(path), str(config_path), config, tuple(controllers),
        backend, seeds, tuple(sorted(held)), tuple(float(a) for a in amps), tf, hold, budget,
        initial, seed,
        _pos_float(t.get("max_torque_ratio", 0.95), "tune.max_torque_ratio", 1.0),
        _pos_float(t.get("settle_error", 2e-3), "tune.settle_error"),
        _pos_float(t.get("ripple", 1e-3), "tune.ripple"), dict(set_fields), space)


# --- the search ------------------------------------------------------------------------------
def _to_gains(space: dict, u) -> dict:
    """Unit-cube point → gains (log scale for a positive lower bound), 3 significant figures."""
    out = {}
    for (f, (lo, hi)), x in zip(space.items(), u, strict=True):
        x = min(max(float(x), 0.0), 1.0)
        v = lo * (hi / lo) ** x if lo > 0 else lo + (hi - lo) * x
        out[f] = float(f"{v:.3g}")
    return out


def _violation(row: dict, spec: TuneSpec) -> float:
    """0 for a feasible run, else its summed relative violations (≥ 1 for a failed one)."""
    if row["status"] != "ok" or row.get("faults"):
        return 1.0 + len(row.get("faults") or [])
    f = row["figures"]
    he, hr = f.get("hold_error_rad"), f.get("hold_ripple_rad")
    if he is None or hr is None or not all(map(math.isfinite, (he, hr, f["rho_s"]))):
        return 1.0
    v = max(0.0, f["max_torque_ratio"] / spec.max_torque_ratio - 1.0)
    v += max(0.0, he / spec.settle_error - 1.0) + max(0.0, hr / spec.ripple - 1.0)
    # a saturated command counts even at the bound's edge
    return v + (1e-3 if f["max_torque_ratio"] >= spec.max_torque_ratio else 0.0)


def objective(rows: list[dict], spec: TuneSpec) -> tuple[float, bool]:
    """(objective, feasible) of one evaluation's runs (the module docstring)."""
    viol = [_violation(r, spec) for r in rows]
    if any(v > 0 for v in viol) or not rows:
        return PENALTY + float(min(sum(viol), 1e3)), False
    return float(np.mean([math.log10(r["figures"]["rho_s"]) for r in rows])), True


class _Budget(Exception):
    pass


def _sweep_spec(spec: TuneSpec, controller: str, gains: dict, k: int):
    from mrm_cosim.cosim.sweep import SweepSpec

    axes = tuple((f, (v,)) for f, v in gains.items())
    axes += (("trajectory.amplitude", spec.amplitudes),)
    return SweepSpec(f"{spec.name}-{controller}-e{k:02d}", spec.config, spec.config_path,
                     (controller,), (spec.backend,), spec.seeds, axes)


def tune_controller(spec: TuneSpec, controller: str, out: Path, executor, log=None) -> dict:
    """Tune one controller (the procedure of the module docstring); returns its record:
    every evaluation (gains, objective, feasible, runs) and the chosen one."""
    from scipy.optimize import minimize
    from scipy.stats import qmc

    from mrm_cosim.cosim.sweep import run_sweep

    space = spec.space[controller]
    evals: list[dict] = []
    cache: dict[tuple, float] = {}

    def evaluate(u) -> float:
        gains = _to_gains(space, u)
        key = tuple(gains.values())
        if key in cache:
            return cache[key]
        if len(evals) >= spec.budget:
            raise _Budget
        k = len(evals)
        outcome = run_sweep(_sweep_spec(spec, controller, gains, k), out / controller /
                            f"e{k:02d}", executor, resume=True, plots=False)
        value, feasible = objective(outcome["rows"], spec)
        rows = [{"seed": r["seed"], "amplitude": r["params"]["trajectory.amplitude"],
                 "status": r["status"], "faults": r.get("faults", []),
                 **{n: r.get("figures", {}).get(n) for n in
                    ("rho_s", "max_torque_ratio", "hold_error_rad", "hold_ripple_rad")}}
                for r in outcome["rows"]]
        evals.append({"k": k, "stage": "lhs" if k < spec.initial else "nelder-mead",
                      "gains": gains, "objective": value, "feasible": feasible, "runs": rows})
        cache[key] = value
        if log is not None:
            log(f"tune {controller} e{k:02d} {gains}: objective {value:.4g}"
                f"{'' if feasible else ' (infeasible)'}")
        return value

    d = len(space)
    lhs = qmc.LatinHypercube(d=d, seed=spec.seed).random(spec.initial)
    for u in lhs:
        evaluate(u)
    best = min(range(len(evals)), key=lambda i: evals[i]["objective"])
    start = lhs[best]
    if spec.budget > len(evals):
        step = 0.5 / max(spec.initial, 1) ** (1 / d)   # about one hypercube stratum
        simplex = [start] + [np.clip(start + step * np.eye(d)[i] * (1 if start[i] < 0.5 else -1),
                                     0, 1) for i in range(d)]
        try:
            minimize(evaluate, start, method="Nelder-Mead", bounds=[(0.0, 1.0)] * d,
                     options={"initial_simplex": np.array(simplex), "maxfev": 10 * spec.budget,
                              "xatol": 1e-3, "fatol": 1e-4})
        except _Budget:
            pass
    chosen = min(evals, key=lambda e: (e["objective"], e["k"]))
    return {"controller": controller, "evaluations": evals, "chosen": chosen,
            "stable": chosen["feasible"]}


def _git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], capture_output=True,
                             text=True, cwd=Path(__file__).resolve().parent, timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10,
                               cwd=Path(__file__).resolve().parent).stdout.strip()
        return out.stdout.strip() + ("-dirty" if dirty else "") if out.returncode == 0 \
            else "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def run_tuning(spec: TuneSpec, out, executor, log=None) -> dict:
    """Tune every controller of ``spec``; write ``OUT/tune.json`` (every evaluation),
    ``OUT/tune.md`` and ``OUT/tuned_gains.toml`` (the chosen gains with their provenance).
    Returns the record written to tune.json."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for c in spec.controllers:
        results[c] = tune_controller(spec, c, out, executor, log)
        # each finished controller is kept (tune.json) before the next one starts
        partial = _record(spec, results)
        (out / "tune.json").write_text(json.dumps(partial, indent=2) + "\n")
        (out / "tune.md").write_text(tune_markdown(partial))
    record = _record(spec, results)
    (out / "tune.json").write_text(json.dumps(record, indent=2) + "\n")
    (out / "tune.md").write_text(tune_markdown(record))
    (out / "tuned_gains.toml").write_text(provenance_block(record) + "[gains]\n" + "".join(
        f"{f.split('.', 1)[1]} = {v!r}\n" for c in spec.controllers
        for f, v in results[c]["chosen"]["gains"].items()))
    return record


def _record(spec: TuneSpec, results: dict) -> dict:
    return {
        "spec": spec.name, "spec_path": spec.path, "config": spec.config_path,
        "set": spec.set_fields, "seeds": list(spec.seeds),
        "held_out_seeds": list(spec.held_out_seeds), "amplitudes": list(spec.amplitudes),
        "trajectory_duration": spec.trajectory_duration, "hold": spec.hold,
        "budget": spec.budget, "initial": spec.initial, "seed": spec.seed,
        "constraints": {"max_torque_ratio": spec.max_torque_ratio,
                        "settle_error_rad": spec.settle_error, "ripple_rad": spec.ripple},
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "commit": _git_commit(), "controllers": dict(results),
        "complete": len(results) == len(spec.controllers),
    }


def tune_markdown(record: dict) -> str:
    lines = [f"# Tuning {record['spec']}", "",
             f"Plants {record['seeds']} (held out: {len(record['held_out_seeds'])} test "
             f"seeds), quintics of {record['amplitudes']} rad in {record['trajectory_duration']}"
             f" s + {record['hold']} s hold, budget {record['budget']} evaluations per "
             f"controller ({record['initial']} Latin hypercube, then Nelder–Mead), constraints "
             f"{record['constraints']}; {record['date']}, commit {record['commit']}.", "",
             "| controller | evaluation | stage | gains | objective (mean log10 ρ) | feasible |",
             "|---|---|---|---|---|---|"]
    for c, r in record["controllers"].items():
        for e in r["evaluations"]:
            mark = " **chosen**" if e is r["chosen"] or e["k"] == r["chosen"]["k"] else ""
            lines.append(f"| {c} | e{e['k']:02d}{mark} | {e['stage']} | "
                         f"{', '.join(f'{k} = {v:g}' for k, v in e['gains'].items())} | "
                         f"{e['objective']:.4f} | {'yes' if e['feasible'] else 'no'} |")
    return "\n".join(lines) + "\n"


def _repo_path(path: str) -> str:
    """``path`` relative to the repository (the package's parent) when inside it."""
    p = Path(path).resolve()
    try:
        return str(p.relative_to(Path(__file__).resolve().parents[1]))
    except ValueError:
        return str(p)


def provenance_block(record: dict) -> str:
    """The comment block :func:`apply_gains` puts above ``[gains]``."""
    lines = [f"{PROVENANCE_MARK} {_repo_path(record['spec_path'])} (spec {record['spec']!r}), "
             f"{record['date']}, commit {record['commit']}:",
             f"#   tuning set: plant seeds {record['seeds']} (held out: the test's "
             f"{len(record['held_out_seeds'])} seeds), quintics {record['amplitudes']} rad in "
             f"{record['trajectory_duration']} s + {record['hold']} s hold, with {record['set']};",
             f"#   budget {record['budget']} evaluations per controller ({record['initial']} "
             f"Latin hypercube + Nelder-Mead); constraints {record['constraints']};"]
    for c, r in record["controllers"].items():
        ch = r["chosen"]
        lines.append(f"#   {c}: {', '.join(f'{k} = {v:g}' for k, v in ch['gains'].items())}"
                     f", objective {ch['objective']:.4f} (mean log10 rho)"
                     f"{'' if ch['feasible'] else ': NO FEASIBLE POINT, gains not written'}")
    return "\n".join(lines) + "\n"


def apply_gains(record: dict, config_path) -> str:
    """Write the chosen gains of ``record`` into the config file ``config_path`` (its
    ``[gains]`` lines, comments kept; a controller without a feasible point keeps its gains,
    and the provenance says so) with the provenance block above ``[gains]`` (an older
    block replaced). The new text is validated before the file is replaced (atomically).
    Returns the new text."""
    import os
    import re

    from mrm_cosim.cosim.experiment_config import loads

    path = Path(config_path)
    text = path.read_text()
    gains = {}
    for r in record["controllers"].values():
        if not r["chosen"]["feasible"]:      # no feasible point: its gains stay as they are
            continue
        for f, v in r["chosen"]["gains"].items():
            table, key = f.split(".", 1)
            if table != "gains":
                raise InputError(f, "only [gains] fields are written into a config")
            gains[key] = v
    lines = text.splitlines(keepends=True)
    # drop an older provenance block
    out, skip = [], False
    for line in lines:
        if line.startswith(PROVENANCE_MARK):
            skip = True
            continue
        if skip and line.startswith("#   "):
            continue
        skip = False
        out.append(line)
    try:
        start = next(i for i, line in enumerate(out) if line.strip() == "[gains]")
    except StopIteration:
        out.append("\n[gains]\n")
        start = len(out) - 1
    end = next((i for i in range(start + 1, len(out)) if out[i].lstrip().startswith("[")),
               len(out))
    done = set()
    for i in range(start + 1, end):
        # a key may hold digits (pid_1khz_hz): without them the line was missed and the
        # key appended a second time, which the TOML check refused
        m = re.match(r"^(\s*)([A-Za-z_][A-Za-z0-9_]*)(\s*=\s*)([^#\n]*?)(\s*)(#.*)?$",
                     out[i].rstrip("\n"))
        if m and m.group(2) in gains:
            value = repr(float(gains[m.group(2)]))
            comment = m.group(6) or ""
            pad = " " * max(1, len(m.group(4)) + len(m.group(5)) - len(value)) if comment else ""
            out[i] = f"{m.group(1)}{m.group(2)}{m.group(3)}{value}{pad}{comment}\n"
            done.add(m.group(2))
    extra = [f"{k} = {float(v)!r}\n" for k, v in gains.items() if k not in done]
    out[end:end] = extra
    out.insert(start, provenance_block(record))
    new = "".join(out)
    loads(new, base_dir=path.resolve().parent)          # refuse to write a bad config
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(new)
    os.replace(tmp, path)
    return new
