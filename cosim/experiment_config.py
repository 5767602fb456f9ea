"""Experiment configurations as TOML: load, validate, resolve, and write back exactly.

A configuration names everything a closed-loop experiment depends on, so that a result
folder plus its ``config.toml`` reproduces the run bit for bit::

    [experiment]   name, robot, controllers, backend, seed, duration (s, optional)
    [trajectory]   the paper's quintic test: amplitude (rad, joint 1; joint i moves i times
                   as far), duration (s, t_f), hold (s, after t_f)
    [plant]        models.plant.PlantConfig: dt, friction, springs, current_loop,
                   current_bandwidth (Hz, optional), [plant.perturbation] links,
                   rotor_inertia, friction, spring (relative half-widths)
    [gains]        cosim.closed_loop.Gains: lam, k_j, K, adapt, pid_fpga_hz, pid_1khz_hz,
                   friction_comp, pid_fpga_base_hz, pid_1khz_base_hz, vdc_base_fb
    [timing]       master.cycle.MasterTiming: period_cycles, kinematics_cycles, force_cycles
    [clocks]       cosim.clocks.ClockConfig: mode ("common", "list", "drawn"), ppm, phase,
                   master_ppm, master_phase (mode "list"), range_ppm (mode "drawn"),
                   discipline, kp, ki (docs/clocks.md)

Every key is optional (defaults are the dataclasses' own); an unknown key, a wrong type or an
out-of-range value raises :class:`mrm_cosim.errors.InputError` naming the dotted field
(``gains.lam``). :meth:`ExperimentConfig.to_toml` writes the resolved configuration (every
default filled in) and :func:`loads` of that text gives back an equal configuration.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

from mrm_cosim import configs
from mrm_cosim.cosim.clocks import ClockConfig
from mrm_cosim.errors import (
    InputError,
    reject_control_characters,
    reject_strings,
    require_finite,
    require_nonnegative,
    require_positive,
)
from mrm_cosim.master.cycle import CONTROLLERS, MasterTiming
from mrm_cosim.master.uploads import PID_DESIGN_HZ, Gains
from mrm_cosim.models.brake import BrakeConfig
from mrm_cosim.protocol.safe_stop import SafeStopParams, safe_stop_config
from mrm_cosim.models.gear import GearConfig
from mrm_cosim.models.plant import JOINTS, Perturbation, PlantConfig
from mrm_cosim.tomlfile import parse_toml, read_toml

__all__ = ["ExperimentConfig", "TrajectoryConfig", "load", "loads", "from_dict", "DEFAULT_CONFIG",
           "LINE_CONFIG",
           "PAPER_AMPLITUDE", "PAPER_DURATION"]

DEFAULT_CONFIG = Path(configs.__file__).resolve().parent / "table2.toml"
#: What ``mrm run line`` reads by default: mrm6 and gains chosen for it.
LINE_CONFIG = Path(configs.__file__).resolve().parent / "line.toml"
PAPER_AMPLITUDE = 0.1571      # rad, p_f − p_0 of the MRM paper's eq. (4) (20,000 counts)
PAPER_DURATION = 1.0          # s, t_f of eq. (4)
MAX_DURATION = 60.0           # s of simulated time per controller


@dataclass(frozen=True)
class TrajectoryConfig:
    """The quintic test q_i = i·q_d(t) (paper eqs. 1–4), then a hold at the goal.

    Attributes
    ----------
    amplitude : float, rad
        p_f − p_0 of joint 1.
    duration : float, s
        t_f, the time of the quintic.
    hold : float, s
        Time simulated after t_f (the goal is held).
    """

    amplitude: float = PAPER_AMPLITUDE
    duration: float = PAPER_DURATION
    hold: float = 0.2


@dataclass(frozen=True)
class FaultsConfig:
    """Faults injected into a run and what the master does when a node trips (``[safety]``;
    docs/faults.md "Safe stop" and "Recovery").

    Attributes
    ----------
    lines : tuple of str
        Line faults, as ``mrm run track --line-fault`` takes them
        (``KIND:DIRECTION:NODE@TIME[+DURATION]``, ``+inf``: to the end of the run).
    on_trip : str
        ``"rearm"``: when every node answers again, re-synchronise, check the uploads, re-arm
        and blend back to the trajectory; ``"end"``: stop sending, leave the nodes holding on
        their brakes and end the run (:data:`master.cycle.ON_TRIP`).
    rearm_blend : float, s
        Shortest duration of the quintic blend from the held position back to the trajectory
        (lengthened where it would ask a joint for more than half its peak torque:
        :func:`master.recovery.fit_blend`).
    safe_stop : protocol.safe_stop.SafeStopParams
        The nodes' safe stop, uploaded by the master (``stop_s``, ``brake_s``, ``hold_hz``,
        ``standstill``, ``standstill_s``, ``stop_trail`` in mrad; docs/node.md "Safe stop").
    """

    lines: tuple = ()
    on_trip: str = "rearm"
    rearm_blend: float = 0.2
    safe_stop: SafeStopParams = field(default_factory=SafeStopParams)
    parsed: tuple = field(default=(), compare=False, repr=False)

    def __post_init__(self):
        from mrm_cosim.master.cycle import ON_TRIP

        if self.on_trip not in ON_TRIP:
            raise InputError("safety.on_trip", f"must be one of {', '.join(map(repr, ON_TRIP))}"
                             f", not {self.on_trip!r}")


@dataclass(frozen=True)
class ExperimentConfig:
    """A resolved experiment: every field has its value, validated.

    Attributes
    ----------
    name : str
    robot : str
        Built-in robot name or a path to an assembly TOML (absolute once resolved).
    controllers : tuple of str
        Subset of ``master.cycle.CONTROLLERS`` in the order they are run.
    backend : str
        A name ``cosim.track.run_track`` accepts (``cosim.track.BACKENDS``).
    seed : int
        Seed of the plant's true-versus-nominal perturbation (same plant for every controller).
    duration : float, s
        Simulated time per controller, from period 0.
    trajectory : TrajectoryConfig
    plant : models.plant.PlantConfig
    gains : cosim.closed_loop.Gains
    timing : master.cycle.MasterTiming
    faults : FaultsConfig
    clocks : cosim.clocks.ClockConfig
        A clock per node (default: one common clock) and the nodes' time-code discipline.
    """

    name: str = "table2"
    robot: str = "mrm3"
    controllers: tuple[str, ...] = ("pid-1khz", "pid-fpga", "vdc")
    backend: str = "compiled"
    seed: int = 0
    duration: float = 1.2
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    plant: PlantConfig = field(default_factory=PlantConfig)
    gains: Gains = field(default_factory=Gains)
    timing: MasterTiming = field(default_factory=MasterTiming)
    faults: FaultsConfig = field(default_factory=FaultsConfig)
    clocks: ClockConfig = field(default_factory=ClockConfig)

    def with_overrides(self, *, backend: str | None = None, seed: int | None = None,
                       duration: float | None = None, field_prefix: str = ""
                       ) -> ExperimentConfig:
        """A copy with command-line overrides applied and validated (errors name the flag)."""
        cfg = self
        if backend is not None:
            cfg = replace(cfg, backend=_backend(backend, f"{field_prefix}backend"))
        if seed is not None:
            cfg = replace(cfg, seed=_seed(seed, f"{field_prefix}seed"))
        if duration is not None:
            cfg = replace(cfg, duration=_duration(duration, f"{field_prefix}duration"))
            check_duration_covers_periods(cfg.duration, cfg.timing.period_cycles,
                                          f"{field_prefix}duration")
        return cfg

    def to_dict(self) -> dict:
        """The resolved configuration as plain data (the TOML layout; JSON-ready)."""
        plant = {k: v for k, v in asdict(self.plant).items() if k != "cycle"}
        if plant["current_bandwidth"] is None:
            del plant["current_bandwidth"]
        if plant["brake"]["holding_torque"] is None:
            del plant["brake"]["holding_torque"]
        return {
            "experiment": {"name": self.name, "robot": self.robot,
                           "controllers": list(self.controllers), "backend": self.backend,
                           "seed": self.seed, "duration": self.duration},
            "trajectory": asdict(self.trajectory),
            "plant": plant,
            "gains": asdict(self.gains),
            "timing": asdict(self.timing),
            "safety": {"line_faults": list(self.faults.lines),
                       "on_trip": self.faults.on_trip, "rearm_blend": self.faults.rearm_blend,
                       **asdict(self.faults.safe_stop)},
            **({} if self.clocks == ClockConfig() else {"clocks": _clocks_dict(self.clocks)}),
        }

    def to_toml(self) -> str:
        """The resolved configuration as TOML text that :func:`loads` reads back equal."""
        return _dump_toml(self.to_dict())


# --- loading ---------------------------------------------------------------------------------
def load(path=None) -> ExperimentConfig:
    """Read and validate an experiment TOML (default: ``configs/table2.toml``).

    Raises
    ------
    InputError
        The file cannot be read or parsed (field ``--config``), or a value is bad (its
        dotted field).
    """
    path = Path(DEFAULT_CONFIG if path is None else path)
    return from_dict(read_toml(path, "config"), base_dir=path.resolve().parent)


def loads(text: str, base_dir=None) -> ExperimentConfig:
    """Validate TOML text; relative robot paths are taken from ``base_dir``."""
    return from_dict(parse_toml(text, "config"), base_dir=base_dir)


def from_dict(data: dict, base_dir=None) -> ExperimentConfig:
    """Validate a parsed configuration (the TOML layout)."""
    _keys(data, "", {"experiment", "trajectory", "plant", "gains", "timing", "safety",
                     "clocks"})
    exp = _table(data, "experiment")
    _keys(exp, "experiment.", {"name", "robot", "controllers", "backend", "seed", "duration"})
    d = ExperimentConfig()
    name = _string(exp.get("name", d.name), "experiment.name")
    robot = _robot(exp.get("robot", d.robot), base_dir)
    controllers = _controllers(exp.get("controllers", list(d.controllers)))
    backend = _backend(exp.get("backend", d.backend), "experiment.backend")
    seed = _seed(exp.get("seed", d.seed), "experiment.seed")

    tr = _table(data, "trajectory")
    _keys(tr, "trajectory.", {f.name for f in fields(TrajectoryConfig)})
    td = TrajectoryConfig()
    amplitude = require_finite(_number(tr.get("amplitude", td.amplitude), "trajectory.amplitude"),
                               "trajectory.amplitude")
    if amplitude == 0.0 or abs(amplitude) > 1.0:
        raise InputError("trajectory.amplitude",
                         f"must be non-zero and at most 1 rad in size, not {amplitude!r}")
    trajectory = TrajectoryConfig(
        amplitude,
        _duration(tr.get("duration", td.duration), "trajectory.duration"),
        require_nonnegative(_number(tr.get("hold", td.hold), "trajectory.hold"), "trajectory.hold"))
    default_duration = trajectory.duration + trajectory.hold
    duration = _duration(exp.get("duration", default_duration), "experiment.duration")

    gains = _gains(_table(data, "gains"))
    plant = _plant(_table(data, "plant"))
    timing = _timing(_table(data, "timing"))
    check_duration_covers_periods(duration, timing.period_cycles, "experiment.duration")
    check_period_on_plant_grid(timing.period_cycles, plant,
                               "plant.dt" if plant.dt != PlantConfig().dt
                               else "timing.period_cycles")
    _gains_fit_the_nodes(robot, controllers, gains, timing.period_cycles)
    if plant.joints == "compliant":
        _gears_fit_the_step(robot, plant, seed)
    faults = _safety(_table(data, "safety"))
    clocks = _clocks(_table(data, "clocks"), robot)
    return ExperimentConfig(name, robot, controllers, backend, seed, duration, trajectory,
                            plant, gains, timing, faults, clocks)


def _clocks(table: dict, robot: str) -> ClockConfig:
    """``[clocks]``: a :class:`ClockConfig`, every field checked by name (``clocks.ppm[2]``),
    the lists one value per module of ``robot``."""
    from mrm_cosim.models.robot import load_robot

    _keys(table, "clocks.", {f.name for f in fields(ClockConfig)})
    values = {}
    for f in fields(ClockConfig):
        if f.name not in table:
            continue
        v = table[f.name]
        if f.name in ("ppm", "phase"):
            if not isinstance(v, list):
                raise InputError(f"clocks.{f.name}", f"must be a list, one value per node, "
                                 f"not {v!r}")
            v = tuple(v)
        values[f.name] = v
    clocks = ClockConfig(**values)
    clocks.check(load_robot(robot).n)
    return clocks


def _clocks_dict(clocks: ClockConfig) -> dict:
    out = {f.name: getattr(clocks, f.name) for f in fields(ClockConfig)}
    out["ppm"], out["phase"] = list(clocks.ppm), list(clocks.phase)
    if clocks.mode != "list":
        for name in ("ppm", "phase", "master_ppm", "master_phase"):
            del out[name]
    return out


#: The shortest run: one master period (half a period ran "clean" with the tip at rest, a
#: tip speed of 0 and a ρ of 0/0). Short runs are useful (a few periods of the compiled
#: gateware), so a run that ends before the motion shows is flagged in its table instead.
MIN_PERIODS = 1

#: The slowest current loop accepted, Hz: the nodes update the torque every microsecond and the
#: master every millisecond; a current loop slower than this turns every controller into the
#: same amplifier (1e-9 Hz gave three equal ρ), and real servo amplifiers close theirs at
#: 1–5 kHz (docs/experiments.md "Plausibility").
MIN_CURRENT_BANDWIDTH = 100.0

#: The coarsest plant step, s: the plant samples the nodes' torque words (updated every 1 µs)
#: once a step, and the loop's start-up (link up about 22 µs after reset) needs steps well
#: inside a period; a 1 ms step failed at run time as 'start_cycle'.
MAX_PLANT_DT = 1e-4


def check_duration_covers_periods(duration: float, period_cycles: int, field: str) -> None:
    """:class:`InputError` naming ``field`` when a run of ``duration`` seconds is shorter
    than :data:`MIN_PERIODS` master period."""
    from mrm_cosim.units import CLOCK_HZ

    shortest = MIN_PERIODS * period_cycles / CLOCK_HZ
    if duration < shortest:
        raise InputError(field, f"{duration:g} s is shorter than the master's period "
                         f"({shortest:g} s): no exchange completes in it")


def _table(data: dict, name: str) -> dict:
    value = data.get(name, {})
    if not isinstance(value, dict):
        raise InputError(name, f"must be a table ([{name}]), not {value!r}")
    return value


def _keys(table: dict, prefix: str, known: set) -> None:
    for key in table:
        if key not in known:
            raise InputError(f"{prefix}{key}", f"unknown key; known: {', '.join(sorted(known))}")


def _string(value, name: str) -> str:
    if not isinstance(value, str) or not value:
        raise InputError(name, f"must be a non-empty string, not {value!r}")
    return reject_control_characters(value, name)


def _robot(value, base_dir) -> str:
    from mrm_cosim.models.robot import load_robot

    value = _string(value, "experiment.robot")
    if value.endswith(".toml"):
        path = Path(value)
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        value = str(path.resolve())
    from mrm_cosim.cosim.track import check_robot_fits

    try:
        check_robot_fits(load_robot(value), "experiment.robot")
    except InputError as exc:
        if exc.field == "experiment.robot":
            raise
        raise InputError("experiment.robot", f"{exc.field}: {exc.message}") from None
    return value


def _controllers(value) -> tuple[str, ...]:
    if not isinstance(value, list) or not value:
        raise InputError("experiment.controllers",
                         f"must be a non-empty list of {', '.join(CONTROLLERS)}, not {value!r}")
    for i, c in enumerate(value):
        if c not in CONTROLLERS:
            raise InputError(f"experiment.controllers[{i}]",
                             f"must be one of {', '.join(CONTROLLERS)}, not {c!r}")
    if len(set(value)) != len(value):
        raise InputError("experiment.controllers", f"lists a controller twice: {value!r}")
    return tuple(value)


def _backend(value, name: str) -> str:
    from mrm_cosim.cosim.track import BACKENDS

    if value not in BACKENDS:
        raise InputError(name, f"must be one of {', '.join(BACKENDS)}, not {value!r}")
    return value


def _seed(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 2**63:
        raise InputError(name, f"must be a non-negative integer, not {value!r}")
    return value


def _number(value, name: str):
    """A number of the file, not a string that reads as one (``duration = "1.5"``)."""
    return reject_strings(value, name)


def _duration(value, name: str) -> float:
    x = require_positive(_number(value, name), name)
    if x > MAX_DURATION:
        raise InputError(name, f"must be at most {MAX_DURATION} s, not {value!r}")
    return x


def _bool(value, name: str) -> bool:
    if not isinstance(value, bool):
        raise InputError(name, f"must be true or false, not {value!r}")
    return value


def _plant(table: dict) -> PlantConfig:
    known = {"dt", "friction", "springs", "current_loop", "current_bandwidth", "perturbation",
             "joints", "gear", "brake"}
    _keys(table, "plant.", known)
    d = PlantConfig()
    pert = table.get("perturbation", {})
    if isinstance(pert, dict):
        _keys(pert, "plant.perturbation.", {f.name for f in fields(Perturbation)})
        dp = Perturbation()
        perturbation = Perturbation(**{
            f.name: require_finite(_number(pert.get(f.name, getattr(dp, f.name)),
                                           f"plant.perturbation.{f.name}"),
                                   f"plant.perturbation.{f.name}")
            for f in fields(Perturbation)})
    else:
        perturbation = require_finite(_number(pert, "plant.perturbation"), "plant.perturbation")
    bw = table.get("current_bandwidth")
    dt = require_positive(_number(table.get("dt", d.dt), "plant.dt"), "plant.dt")
    if dt > MAX_PLANT_DT:
        raise InputError("plant.dt", f"{dt:g} s is too coarse a plant step: the plant samples "
                         f"the nodes' torque once a step and the link comes up 22 µs after "
                         f"reset (at most {MAX_PLANT_DT:g} s)")
    return PlantConfig(
        dt=dt,
        perturbation=perturbation,
        friction=_bool(table.get("friction", d.friction), "plant.friction"),
        springs=_bool(table.get("springs", d.springs), "plant.springs"),
        current_loop=_bool(table.get("current_loop", d.current_loop), "plant.current_loop"),
        current_bandwidth=None if bw is None else _current_bandwidth(bw),
        joints=_joints(table.get("joints", d.joints)),
        gear=_gear(table.get("gear", {})),
        brake=_brake(table.get("brake", {})))


def _brake(table) -> BrakeConfig:
    return _section(table, "plant.brake", BrakeConfig,
                    lambda v, name: None if v is None else require_finite(_number(v, name), name))


def _section(table, prefix: str, cls, value):
    """A TOML table of ``cls``'s fields (a dataclass): unknown keys refused, each given value
    through ``value(v, field)``, the class's defaults for the others."""
    if not isinstance(table, dict):
        raise InputError(prefix, f"must be a table, not {table!r}")
    _keys(table, f"{prefix}.", {f.name for f in fields(cls)})
    d = cls()
    return cls(**{f.name: value(table.get(f.name, getattr(d, f.name)), f"{prefix}.{f.name}")
                  for f in fields(cls)})


def _safety(table: dict) -> FaultsConfig:
    stop_keys = {f.name for f in fields(SafeStopParams)}
    _keys(table, "safety.", {"line_faults", "on_trip", "rearm_blend"} | stop_keys)
    d = FaultsConfig()
    lines = table.get("line_faults", [])
    if not isinstance(lines, list) or not all(isinstance(x, str) for x in lines):
        raise InputError("safety.line_faults", f"must be a list of fault strings "
                         f"(KIND:DIRECTION:NODE@TIME[+DURATION]), not {lines!r}")
    from mrm_cosim.cosim.closed_loop import LineFault

    parsed = tuple(LineFault.parse(x, "safety.line_faults") for x in lines)
    on_trip = table.get("on_trip", d.on_trip)
    blend = require_positive(_number(table.get("rearm_blend", d.rearm_blend),
                                     "safety.rearm_blend"), "safety.rearm_blend")
    ds = SafeStopParams()
    values = {k: _number(table.get(k, getattr(ds, k)), f"safety.{k}") for k in stop_keys}
    try:
        stop = SafeStopParams(**values)
        safe_stop_config(stop)          # the words fit the nodes' registers (50-cycle tick)
    except InputError as e:
        raise InputError(e.field.replace("safe_stop.", "safety."), e.message) from None
    return FaultsConfig(tuple(lines), on_trip, blend, stop, parsed)


def _joints(value) -> str:
    if value not in JOINTS:
        raise InputError("plant.joints", f"must be one of {', '.join(map(repr, JOINTS))}, "
                         f"not {value!r}")
    return value


def _gear(table) -> GearConfig:
    return _section(table, "plant.gear", GearConfig,
                    lambda v, name: v if name == "plant.gear.hysteresis" else
                    require_finite(_number(v, name), name))


def _current_bandwidth(value) -> float:
    x = require_positive(_number(value, "plant.current_bandwidth"), "plant.current_bandwidth")
    if x < MIN_CURRENT_BANDWIDTH:
        raise InputError("plant.current_bandwidth", f"{value!r} Hz cannot follow the torque "
                         f"the controllers command (at least {MIN_CURRENT_BANDWIDTH:g} Hz; "
                         "servo amplifiers close their current loop at 1–5 kHz)")
    return x


# Upper bounds keep every gain inside the node's fixed-point registers with margin.
_GAIN_LIMITS = {"lam": (False, 1000.0), "k_j": (True, 500.0), "K": (True, 5000.0),
                "adapt": (True, 100.0), "pid_fpga_hz": (False, PID_DESIGN_HZ),
                "pid_1khz_hz": (False, 100.0), "friction_comp": (True, 2.0),
                # the base joint's own PID poles (0: the others' pole) and the VDC link level's
                # share of joint 1's velocity error (docs/experiments.md "Tuning")
                "pid_fpga_base_hz": (True, PID_DESIGN_HZ), "pid_1khz_base_hz": (True, 100.0),
                "vdc_base_fb": (True, 1.0)}


def _gains(table: dict) -> Gains:
    _keys(table, "gains.", set(_GAIN_LIMITS))
    d = Gains()
    values = {}
    for name, (zero_ok, top) in _GAIN_LIMITS.items():
        field_name = f"gains.{name}"
        raw = table.get(name, getattr(d, name))
        x = (require_nonnegative if zero_ok else require_positive)(_number(raw, field_name),
                                                                   field_name)
        if x > top:
            raise InputError(field_name, f"must be at most {top}, not {raw!r}")
        values[name] = x
    return Gains(**values)


def _gears_fit_the_step(robot: str, plant: PlantConfig, seed: int) -> None:
    """Build the compliant plant once: a gear the step cannot integrate stably is refused
    here, naming the field and the largest step it allows, before anything runs."""
    from mrm_cosim.models.compliant import CompliantPlant
    from mrm_cosim.models.robot import load_robot

    CompliantPlant(load_robot(robot), plant, seed)


def _gains_fit_the_nodes(robot: str, controllers, gains: Gains, period_cycles: int) -> None:
    """Encode the uploads each controller needs: every gain must fit its fixed-point word
    (the adaptation step ρ·T is the period's)."""
    from mrm_cosim.master.uploads import node_uploads
    from mrm_cosim.models.robot import load_robot

    r = load_robot(robot)
    for c in controllers:
        try:
            node_uploads(r, c, gains, period_cycles=period_cycles)
        except InputError as exc:
            if exc.field in ("period_cycles", "commit_cycles", "sync_window"):
                raise InputError("timing.period_cycles", f"the nodes' period timer cannot "
                                 f"run it ({exc.field}: {exc.message})") from None
            raise InputError(_gain_field(exc.field), f"does not fit the node's registers "
                             f"for {c} ({exc.field}: {exc.message})") from None


def _gain_field(word: str) -> str:
    """The configuration field behind a node register word named in an upload error."""
    leaf = word.rsplit(".", 1)[-1].split("[", 1)[0]
    return "gains." + {"kp": "pid_fpga_hz", "ki": "pid_fpga_hz", "kd": "pid_fpga_hz",
                       "ilo": "pid_fpga_hz", "ihi": "pid_fpga_hz", "K": "K", "rho": "adapt",
                       "kj": "k_j", "lam": "lam", "lamc": "lam", "ivlc": "lam"}.get(leaf, "*")


def check_period_on_plant_grid(period_cycles: int, plant: PlantConfig, field: str) -> None:
    """``InputError`` naming ``field`` unless the period is a whole number of plant steps: the
    loops poll the master and step the plant on the plant's grid, so a period boundary inside
    a step would send its time-code up to a step late."""
    step = plant.cycles_per_step
    if period_cycles % step:
        raise InputError(field, f"the master's period ({period_cycles:,} cycles) must be a "
                         f"whole number of plant steps ({step:,} cycles = {plant.dt:g} s)")


def _timing(table: dict) -> MasterTiming:
    _keys(table, "timing.", {f.name for f in fields(MasterTiming)})
    d = MasterTiming()
    values = {}
    for f in fields(MasterTiming):
        raw = table.get(f.name, getattr(d, f.name))
        if isinstance(raw, bool) or not isinstance(raw, int) or raw < 1:
            raise InputError(f"timing.{f.name}", f"must be a positive whole number of 20 ns "
                             f"cycles, not {raw!r}")
        values[f.name] = raw
    if values["kinematics_cycles"] + values["force_cycles"] >= values["period_cycles"]:
        raise InputError("timing.kinematics_cycles", "the master's compute time "
                         "(kinematics + force) must be shorter than the period")
    return MasterTiming(**values)


# --- writing ---------------------------------------------------------------------------------
def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"cannot write {v!r} to TOML")
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _dump_toml(data: dict, prefix: str = "") -> str:
    lines, tables = [], []
    for key, value in data.items():
        if isinstance(value, dict):
            tables.append((key, value))
        else:
            lines.append(f"{key} = {_toml_value(value)}")
    out = "\n".join(lines)
    for key, value in tables:
        name = f"{prefix}{key}"
        body = _dump_toml(value, f"{name}.")
        out += ("\n\n" if out else "") + f"[{name}]\n" + body
    return out + ("\n" if not prefix else "")
