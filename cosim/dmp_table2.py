"""``mrm run dmp-table2``: the motion-primitive paper's Table 2 in closed loop (Liu et al.,
seeds/000 §4).

For each path of the configuration (``configs/dmp_table2.toml``): the planar Cartesian path
(:class:`master.paths.PathPlan`) through IK to joint references at 1 ms
(:func:`master.cartesian.joint_reference`); one DMP per joint learned from them
(:func:`master.dmp.learn_dmp`); then closed-loop runs of the six-module arm, the joints in the
node's PID mode (its own 1 MHz position loop, "the same joint PID parameters"):

* ``traditional`` at each slow master period P: every period the master sends the joints their
  position reference at the period start and the joint holds it (``references="hold"``);
* ``feedforward`` at the same P: the master sends ``q_d, q̇_d, q̈_d`` at the period start and
  the joint extrapolates them over the period (``references="full"``, the node's own
  interpolation) — what any velocity and acceleration feedforward buys without a primitive;
* ``modularized`` at the same P: the primitives are deployed to the nodes before the run and
  started by the master; every joint generates its position, velocity and acceleration
  references itself, one generator step every millisecond (``references="dmp"``);
* ``reference``: the 1 ms master sending ``q_d, q̇_d, q̈_d`` every period (today's mode).

Every run's trajectory starts at period 1 (the primitives are started only after period 0's
Comm A has confirmed their deployment), so the desired trajectory of a run with period P is the
reference delayed by P. Errors are taken every millisecond over the motion and the hold:

* the paper's eq. (10), ``e = ‖log(T_d)^∨ − log(T_g)^∨‖`` (a difference of two matrix
  logarithms in the base frame: not a distance between the poses, it depends on where the base
  frame is), and its RMSE, eq. (11);
* the logarithm of the relative transform, ``‖log(T_d⁻¹ T_g)‖``, its RMSE;
* the tool's position error (mm).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mrm_cosim import configs
from mrm_cosim.errors import InputError, require_positive
from mrm_cosim.master.cartesian import JointReference, joint_reference, se3_log, tool_errors
from mrm_cosim.master.cycle import MasterTiming
from mrm_cosim.master.dmp import Dmp, learn_dmp
from mrm_cosim.master.paths import SHAPES, SIZES, PathPlan
from mrm_cosim.master.uploads import Gains
from mrm_cosim.models.plant import PlantConfig
from mrm_cosim.models.robot import load_robot
from mrm_cosim.units import CLOCK_HZ

__all__ = ["DMP_CONFIG", "PAPER_RMSE", "DmpTableConfig", "PathSpec", "PathResult", "Run",
           "load_dmp_config", "loads_dmp_config", "prepare_path", "run_dmp_table2",
           "paper_error", "table_markdown", "ARCHITECTURES"]

DMP_CONFIG = Path(configs.__file__).resolve().parent / "dmp_table2.toml"
#: The paper's Table 2: RMSE of eq. (11), (traditional, modularized), 50 ms master period.
PAPER_RMSE = {"half8": (0.0154, 0.0084), "circle": (0.0112, 0.0091), "line": (0.0070, 0.0068),
              "sinusoid": (0.0115, 0.0100)}
ARCHITECTURES = ("traditional", "feedforward", "modularized")
#: Which column of :data:`PAPER_RMSE` each architecture compares with.
PAPER_COLUMN = {"traditional": 0, "modularized": 1}
ERROR_STEP = 1e-3           # s between the error samples


@dataclass(frozen=True)
class PathSpec:
    """One path of the comparison (:class:`master.paths.PathPlan` without its start pose)."""

    name: str
    shape: str
    size: dict
    duration: float


@dataclass(frozen=True)
class DmpTableConfig:
    """``configs/dmp_table2.toml`` resolved (see that file for every key)."""

    robot: str = "mrm6"
    backend: str = "model"
    seed: int = 0
    controller: str = "pid-fpga"
    periods_ms: tuple = (50, 10)
    hold: float = 0.2
    basis: int = 30
    alpha: float = 25.0
    alpha_s: float = 4.0
    scaling_min: float = 0.2
    step_cycles: int = 50_000
    e1: tuple = (-1.0, 0.0, 0.0)
    e2: tuple = (0.0, 1.0, 0.0)
    paths: tuple = ()
    plant: PlantConfig = field(default_factory=PlantConfig)
    gains: Gains = field(default_factory=Gains)


def load_dmp_config(path=None) -> DmpTableConfig:
    """Read and check a configuration (default :data:`DMP_CONFIG`)."""
    from mrm_cosim.tomlfile import read_toml

    path = Path(path) if path is not None else DMP_CONFIG
    return _from_dict(read_toml(path, "config"), path.parent)


def loads_dmp_config(text: str, base_dir=None) -> DmpTableConfig:
    """:func:`load_dmp_config` from TOML text."""
    from mrm_cosim.tomlfile import parse_toml

    return _from_dict(parse_toml(text, "config"), base_dir)


def _from_dict(data: dict, base_dir) -> DmpTableConfig:
    from mrm_cosim.cosim import experiment_config as ec

    ec._keys(data, "", {"experiment", "dmp", "plane", "path", "plant", "gains"})
    exp = ec._table(data, "experiment")
    ec._keys(exp, "experiment.", {"name", "robot", "backend", "seed", "controller",
                                 "periods_ms", "hold"})
    out = {}
    if "robot" in exp:
        out["robot"] = ec._robot(exp["robot"], base_dir)
    if "backend" in exp:
        out["backend"] = ec._backend(exp["backend"], "experiment.backend")
    if "seed" in exp:
        out["seed"] = ec._seed(exp["seed"], "experiment.seed")
    if "controller" in exp and exp["controller"] != "pid-fpga":
        raise InputError("experiment.controller", "the comparison runs the joints' own PID "
                         f"(\"pid-fpga\"), not {exp['controller']!r}")
    if "periods_ms" in exp:
        periods = exp["periods_ms"]
        if (not isinstance(periods, list) or not periods
                or any(isinstance(p, bool) or not isinstance(p, int) or not 1 <= p <= 100
                       for p in periods) or len(set(periods)) != len(periods)):
            raise InputError("experiment.periods_ms", "must be a list of distinct integers "
                             f"1..100 (ms), not {periods!r}")
        out["periods_ms"] = tuple(periods)
    if "hold" in exp:
        out["hold"] = ec._duration(exp["hold"], "experiment.hold")
    dmp = ec._table(data, "dmp")
    ec._keys(dmp, "dmp.", {"basis", "alpha", "alpha_s", "scaling_min", "step_cycles"})
    if "basis" in dmp:
        b = dmp["basis"]
        if isinstance(b, bool) or not isinstance(b, int) or not 2 <= b:
            raise InputError("dmp.basis", f"must be an integer >= 2, not {b!r}")
        out["basis"] = b
    for k in ("alpha", "alpha_s"):
        if k in dmp:
            out[k] = require_positive(ec._number(dmp[k], f"dmp.{k}"), f"dmp.{k}")
    if "scaling_min" in dmp:
        v = ec._number(dmp["scaling_min"], "dmp.scaling_min")
        if not 0.0 <= v < 1.0:
            raise InputError("dmp.scaling_min", f"must be in [0, 1), not {v!r}")
        out["scaling_min"] = float(v)
    if "step_cycles" in dmp:
        s = dmp["step_cycles"]
        if isinstance(s, bool) or not isinstance(s, int) or not 1_000 <= s <= 1_000_000:
            raise InputError("dmp.step_cycles", f"must be an integer 1000..1000000, not {s!r}")
        out["step_cycles"] = s
    plane = ec._table(data, "plane")
    ec._keys(plane, "plane.", {"e1", "e2"})
    for k in ("e1", "e2"):
        if k in plane:
            v = plane[k]
            if not isinstance(v, list) or len(v) != 3:
                raise InputError(f"plane.{k}", f"must be 3 numbers, not {v!r}")
            out[k] = tuple(ec._number(x, f"plane.{k}") for x in v)
    paths = data.get("path", [])
    if not isinstance(paths, list) or not paths:
        raise InputError("path", "at least one [[path]] is needed")
    specs, names = [], set()
    for i, p in enumerate(paths):
        name = f"path[{i}]"
        if not isinstance(p, dict):
            raise InputError(name, "must be a table")
        shape = p.get("shape")
        if shape not in SHAPES:
            raise InputError(f"{name}.shape", f"must be one of {', '.join(SHAPES)}, "
                                              f"not {shape!r}")
        ec._keys(p, f"{name}.", {"name", "shape", "duration", *SIZES[shape]})
        label = ec._string(p.get("name", shape), f"{name}.name")
        if label in names:
            raise InputError(f"{name}.name", f"{label!r} is used by another path")
        names.add(label)
        size = {k: ec._number(p[k], f"{name}.{k}") for k in SIZES[shape] if k in p}
        duration = ec._duration(p.get("duration", 2.0), f"{name}.duration")
        specs.append(PathSpec(label, shape, size, duration))
    out["paths"] = tuple(specs)
    plant = data.get("plant")
    if plant is not None:
        out["plant"] = ec._plant(plant)
    gains = data.get("gains")
    if gains is not None:
        out["gains"] = ec._gains(gains)
    return DmpTableConfig(**out)


@dataclass
class Run:
    """One closed-loop run of a path.

    Attributes
    ----------
    architecture : str
        ``"traditional"``, ``"modularized"`` or ``"reference"``.
    period_ms : int
        The master's period.
    t : ndarray, shape (k,), s
        Error sample times from the motion's start.
    paper, relative, position_mm : ndarray, shape (k,)
        Eq. (10), ``‖log(T_d⁻¹ T_g)‖`` and the tool position error.
    tool_desired, tool_actual : ndarray, shape (k, 3), m
    summary : dict
        :func:`cosim.track.run_track`'s summary.
    """

    architecture: str
    period_ms: int
    t: np.ndarray
    paper: np.ndarray
    relative: np.ndarray
    position_mm: np.ndarray
    tool_desired: np.ndarray
    tool_actual: np.ndarray
    summary: dict

    def rmse(self) -> dict:
        """RMSE of eq. (11) over the paper's error and over the relative one, and the
        position error's RMS and maximum (mm)."""
        return {"paper": float(np.sqrt(np.mean(self.paper**2))),
                "relative": float(np.sqrt(np.mean(self.relative**2))),
                "rms_position_mm": float(np.sqrt(np.mean(self.position_mm**2))),
                "max_position_mm": float(self.position_mm.max())}


@dataclass
class PathResult:
    """A path's reference, its primitive and its runs (key ``(architecture, period_ms)``);
    the plane it lies in (``plane_e1, plane_e2``)."""

    spec: PathSpec
    reference: JointReference
    dmp: Dmp
    dmp_fit_rad: float
    runs: dict
    plane_e1: np.ndarray
    plane_e2: np.ndarray


def paper_error(T_desired, T_actual) -> float:
    """The paper's eq. (10): ``‖log(T_d)^∨ − log(T_g)^∨‖₂`` of two poses (4×4)."""
    return float(np.linalg.norm(se3_log(T_desired) - se3_log(T_actual)))


def prepare_path(cfg: DmpTableConfig, spec: PathSpec, robot=None):
    """The path's plan, joint reference (IK at 1 ms from the robot's home posture) and the
    primitive learned from it; plus the primitive's worst joint error (rad) rolled out at the
    generator's step against the reference."""
    robot = load_robot(robot or cfg.robot)
    T0 = robot.tip_pose(robot.home)
    plan = PathPlan.build(spec.shape, T0, cfg.e1, cfg.e2, spec.size, spec.duration,
                          field=f"path {spec.name}")
    try:
        ref = joint_reference(robot, plan, 1e-3, q_seed=robot.home)
    except InputError as exc:           # the path leaves the arm's workspace, limits, ...
        raise InputError(f"path {spec.name}", f"{exc.field}: {exc.message}") from None
    dmp = learn_dmp(ref.q, float(ref.t[1] - ref.t[0]), cfg.basis, alpha=cfg.alpha,
                    alpha_s=cfg.alpha_s, scaling_min=cfg.scaling_min)
    step = cfg.step_cycles / CLOCK_HZ
    try:
        dmp.check_step(step)
    except InputError as exc:
        raise InputError("dmp.alpha", f"{cfg.alpha!r}: {exc.message}") from None
    # what the nodes must hold: the deploy's checks (word formats, limits, the period grid)
    from mrm_cosim.master.uploads import dmp_uploads

    for period_ms in cfg.periods_ms:
        dmp_uploads(robot, dmp, cfg.step_cycles, period_ms * (CLOCK_HZ // 1000))
    roll = dmp.rollout(step, duration=float(ref.t[-1]))
    fit = float(np.abs(roll.x - ref.evaluate(roll.t)[0]).max())
    return plan, ref, dmp, fit


class _Delayed:
    """A joint reference that starts ``delay`` seconds late (resting at its start before)."""

    def __init__(self, ref: JointReference, delay: float):
        self.ref, self.delay = ref, delay

    def evaluate(self, t):
        return self.ref.evaluate(np.asarray(t, dtype=float) - self.delay)


def run_architecture(cfg: DmpTableConfig, robot, ref: JointReference, dmp: Dmp,
                     architecture: str, period_ms: int, backend: str | None = None,
                     progress=None) -> Run:
    """One closed-loop run (module docstring)."""
    from mrm_cosim.cosim.line import robot_at
    from mrm_cosim.cosim.track import run_track

    robot = load_robot(robot)
    references = {"traditional": "hold", "feedforward": "full", "modularized": "dmp",
                  "reference": "full"}
    if architecture not in references:
        raise InputError("architecture", f"must be one of {', '.join(references)}, "
                                         f"not {architecture!r}")
    period_cycles = period_ms * (CLOCK_HZ // 1000)
    delay = period_cycles / CLOCK_HZ
    duration = delay + float(ref.duration) + cfg.hold
    timing = MasterTiming(period_cycles=period_cycles)
    start_robot = robot_at(robot, ref.q[0])
    result, summary = run_track(
        start_robot, cfg.controller, backend or cfg.backend, duration, cfg.seed,
        gains=cfg.gains, timing=timing, plant_config=cfg.plant, progress=progress,
        profile=_Delayed(ref, delay), references=references[architecture], dmp=dmp,
        dmp_step_cycles=cfg.step_cycles, commit_cycles=min(10_000, period_cycles // 5))
    # error samples every ERROR_STEP over the motion and the hold
    stride = max(1, int(round(ERROR_STEP / (result.t[1] - result.t[0]))))
    sel = np.nonzero(result.t >= delay - 1e-12)[0][::stride]
    t = result.t[sel] - delay
    q_d = ref.evaluate(t)[0]
    q_a = result.q[sel]
    errs = tool_errors(start_robot, q_d, q_a)
    poses_d = [start_robot.tip_pose(q) for q in q_d]
    poses_a = [start_robot.tip_pose(q) for q in q_a]
    paper = np.array([paper_error(a, b) for a, b in zip(poses_d, poses_a, strict=True)])
    return Run(architecture, period_ms, t, paper, errs.se3, errs.position_mm,
               errs.tool_desired, errs.tool_actual, summary)


def _point(ctx, item, report) -> Run:
    """One run of :func:`run_dmp_table2` in an executor's process."""
    cfg, prepared, backend = ctx
    name, arch, period = item
    _, ref, dmp, _ = prepared[name]
    t0 = time.perf_counter()
    run = run_architecture(cfg, cfg.robot, ref, dmp, arch, period, backend)
    run.summary["wall_s"] = time.perf_counter() - t0
    return run


def run_dmp_table2(cfg: DmpTableConfig, backend: str | None = None, paths=None,
                   progress=None, jobs: int = 1) -> dict:
    """Every path × architecture × period of ``cfg`` (and the 1 ms reference), ``jobs`` runs
    at a time on this machine's processes (:class:`cosim.executors.LocalExecutor`; each run
    is independent, the results do not depend on ``jobs``).

    ``paths``: names to run (default all). ``progress(text)``: called as each run ends.

    Returns
    -------
    dict of str to PathResult
    """
    from functools import partial

    from mrm_cosim.cosim.executors import LocalExecutor, SerialExecutor

    robot = load_robot(cfg.robot)
    if robot.n != 6:
        raise InputError("robot", f"the paths fix the tool's pose: {robot.name} has {robot.n} "
                                  "joints, the comparison needs 6")
    if paths is not None:
        unknown = sorted(set(paths) - {p.name for p in cfg.paths})
        if unknown:
            raise InputError("paths", f"{unknown[0]!r} is not a path of the configuration "
                             f"({', '.join(p.name for p in cfg.paths)})")
    chosen = cfg.paths if paths is None else [p for p in cfg.paths if p.name in paths]
    # every reference and primitive is computed and checked before any run
    prepared = {spec.name: prepare_path(cfg, spec, robot) for spec in chosen}
    plan = [(a, p) for p in cfg.periods_ms for a in ARCHITECTURES] + [("reference", 1)]
    items = [(spec.name, a, p) for spec in chosen for a, p in plan]
    runs = {}
    executor = LocalExecutor(jobs) if jobs > 1 else SerialExecutor()
    with executor as ex:
        for i, status, value in ex.run(partial(_point, (cfg, prepared, backend)), items):
            name, arch, period = items[i]
            if status == "input":
                raise InputError(*value)
            if status == "error":
                raise RuntimeError(f"the {name} {arch} {period} ms run failed:\n{value}")
            runs[items[i]] = value
            if progress is not None:
                progress(f"{name}: {arch} at {period} ms done ({len(runs)}/{len(items)}, "
                         f"{value.summary['wall_s']:.0f} s)")
    out = {}
    for spec in chosen:
        plan_, ref, dmp, fit = prepared[spec.name]
        out[spec.name] = PathResult(spec, ref, dmp, fit,
                                    {(a, p): runs[(spec.name, a, p)] for a, p in plan},
                                    plan_.e1, plan_.e2)
    return out


def table_markdown(results: dict, cfg: DmpTableConfig) -> str:
    """Table 2 beside the paper's: RMSE of eq. (11) on the paper's error and on the relative
    one, and the RMS tool position error, per path and architecture."""
    lines = ["| path | architecture | period | RMSE eq. (11) | paper | RMSE ‖log(T_d⁻¹T_g)‖ "
             "| RMS / max position error (mm) |", "|---|---|---|---|---|---|---|"]
    for name, res in results.items():
        paper = PAPER_RMSE.get(name)
        for (arch, period), run in res.runs.items():
            r = run.rmse()
            printed = "—"
            if paper is not None and period == 50 and arch in PAPER_COLUMN:
                printed = f"{paper[PAPER_COLUMN[arch]]:.4f}"
            lines.append(f"| {name} | {arch} | {period} ms | {r['paper']:.2e} | {printed} "
                         f"| {r['relative']:.2e} | {r['rms_position_mm']:.3f} / "
                         f"{r['max_position_mm']:.3f} |")
    return "\n".join(lines)


def summary_dict(results: dict) -> dict:
    """JSON-ready figures of every run."""
    out = {}
    for name, res in results.items():
        out[name] = {"dmp_fit_rad": res.dmp_fit_rad, "basis": res.dmp.n_basis,
                     "duration_s": res.spec.duration, "runs": []}
        for (arch, period), run in res.runs.items():
            s = run.summary
            out[name]["runs"].append({
                "architecture": arch, "period_ms": period, **run.rmse(),
                "trace_sha256": s["trace_sha256"], "dmp_errors": s["dmp_errors"],
                "node_counters": s["node_counters"], "wall_s": s.get("wall_s"),
                "upload_errors": s["upload_errors"]})
    return out

