"""``mrm run track``: the paper's quintic test in closed loop on a chosen backend."""

from __future__ import annotations

import contextlib
import os
import time

import numpy as np

from mrm_cosim.cosim.backends import CompiledBackend, PysimBackend
from mrm_cosim.cosim.closed_loop import ClosedLoop
from mrm_cosim.cosim.experiment_config import MAX_DURATION, check_period_on_plant_grid
from mrm_cosim.cosim.preview import paper_test_profile
from mrm_cosim.cosim.skew import period_skew
from mrm_cosim.master.cycle import Master, MasterTiming
from mrm_cosim.master.kinematics import tip_points
from mrm_cosim.master.uploads import Gains, node_uploads, pid_gains, pid_shifts
from mrm_cosim.models.plant import PlantConfig, make_plant
from mrm_cosim.models.robot import load_robot
from mrm_cosim.errors import InputError, require_positive
from mrm_cosim.units import CLOCK_HZ

__all__ = ["run_track", "BACKENDS", "link_errors_detail", "link_fault_places", "run_loop",
           "loop_backend", "loop_system", "loop_system_key", "check_robot_fits",
           "node_encoders", "node_counts_range", "run_faults"]

BACKENDS = ("compiled", "pysim", "model")
START_CYCLE = 50_000          # period 0 at 1 ms: links up (21 µs) and uploads done well before


def check_robot_fits(robot, field: str) -> None:
    """``InputError`` naming ``field`` when the gateware cannot run ``robot``: more modules
    than the system has nodes (:data:`hdl.system.MAX_NODES`), or a module whose encoder counts
    per joint revolution the node's fixed-point formats cannot hold (:func:`node_counts_range`).
    Every backend runs the same system."""
    from mrm_cosim.hdl.system import MAX_NODES

    if robot.n > MAX_NODES:
        raise InputError(field, f"{robot.name!r} has {robot.n} modules; the co-simulated system "
                                f"has at most {MAX_NODES} slave nodes, one per module")
    lo, hi = node_counts_range()
    for k, mod in enumerate(robot.modules):
        cpr = mod.type.counts_per_rev
        if not lo <= cpr <= hi:
            raise InputError(field, f"module {k + 1} of {robot.name!r} (type {mod.type.name!r}) "
                                    f"has {cpr:,} encoder counts per joint revolution (4 × "
                                    f"encoder_lines × gear_ratio); the node's fixed-point "
                                    f"formats hold {lo:,} to {hi:,} (docs/node.md, Encoder "
                                    f"interface)")


def node_counts_range() -> tuple[int, int]:
    """The encoder counts per joint revolution a node can be built for: the velocity constant
    ``K_v`` must fit its 17-bit Q8 word (the low end) and the counts per radian the joint
    program's ``KC`` word (the high end)."""
    import math

    from mrm_cosim.protocol.encoder import EncoderParams
    from mrm_cosim.protocol.fixed import KC

    lo, hi = EncoderParams().counts_per_rev_range()

    def kc_fits(cpr: int) -> bool:
        try:
            KC.encode_checked(cpr / (2 * math.pi), "Kc")
        except InputError:
            return False
        return True

    top = math.floor(2 * math.pi * KC.max)
    while not kc_fits(top):
        top -= 1
    while kc_fits(top + 1):
        top += 1
    return lo, min(hi, top)


def node_encoders(robot) -> list:
    """The encoder interface of each module's node, built for that module's counts per
    revolution (the node's velocity constant and its angle scale depend on them)."""
    from mrm_cosim.protocol.encoder import EncoderParams

    return [EncoderParams(counts_per_rev=mod.type.counts_per_rev) for mod in robot.modules]


def run_track(robot="mrm3", controller="vdc", backend="compiled", duration: float = 1.5,
              seed: int = 0, gains: Gains | None = None, timing: MasterTiming | None = None,
              plant_config: PlantConfig | None = None, progress=None, profile=None,
              vcd: str | None = None, signals: str | None = None, vcd_path=None, faults=(),
              references: str = "full", dmp=None, dmp_step_cycles: int = 50_000,
              commit_cycles: int | None = None, on_trip: str | None = "rearm",
              rearm_blend: float = 0.2, safe_stop=None, clocks=None):
    """Run the quintic test (q_i = i·q_d, 0.1571 rad in 1 s, then hold) in closed loop.

    Parameters
    ----------
    progress : callable ``(t_sim, t_total)``, optional
        Called about every simulated millisecond with the simulated seconds done and to do
        (it decides itself how often to print); ``None``: quiet.
    profile : JointProfile, optional
        The test trajectory (default: the paper's, :func:`cosim.preview.paper_test_profile`).
    vcd, signals, vcd_path : str, str, path, optional
        Waveforms: the window ``"T0:T1"`` (seconds from period 0, units ``s``/``ms``/``us``/``ns``
        allowed) and fnmatch patterns of the signals to record into ``vcd_path``
        (pysim and compiled only).
    faults : sequence of cosim.closed_loop.LineFault
        Line faults to inject (pysim and compiled); the summary's ``link_errors`` and
        ``link_error_detail`` say where they were counted.
    references : str
        What the master's Comm D references are (:data:`master.cycle.REFERENCES`).
    dmp : master.dmp.Dmp, optional
        With ``references="dmp"``: one primitive per joint, deployed to the nodes with the
        uploads (:func:`master.uploads.dmp_uploads`) and started by the master at period 0;
        the joints generate their references from period 1's boundary on, one step every
        ``dmp_step_cycles``.
    commit_cycles : int, optional
        Comm D's commit phase (default: a fifth of the period, :func:`node_uploads`).
    on_trip, rearm_blend : str, float
        What the master does when nodes trip or stop answering, and the shortest blend back to
        the trajectory after a re-arm (:mod:`master.recovery`, ``[safety]``).
    safe_stop : protocol.safe_stop.SafeStopParams, optional
        The nodes' safe stop the master uploads (default: its defaults).
    clocks : cosim.clocks.ClockConfig, optional
        A clock per node and for the master port, and the nodes' time-code discipline
        (``[clocks]``, docs/clocks.md; default: one common clock, no discipline). The
        summary's ``clocks`` says what ran.

    Returns
    -------
    (LoopResult, summary dict)
    """
    robot = load_robot(robot)
    check_robot_fits(robot, "robot")
    gains = gains or Gains()
    timing = timing or MasterTiming()
    if backend not in BACKENDS:
        raise InputError("backend", f"must be one of {', '.join(BACKENDS)}, not {backend!r}")
    duration = require_positive(duration, "duration")
    if duration > MAX_DURATION:
        raise InputError("duration", f"must be at most {MAX_DURATION} s, not {duration!r}")
    step = (plant_config or PlantConfig()).dt
    check_period_on_plant_grid(timing.period_cycles, plant_config or PlantConfig(), "plant.dt")
    if duration < step:
        raise InputError("duration", f"must be at least one plant step ({step * 1e6:g} µs), "
                         f"not {duration!r}")
    profile = profile or paper_test_profile(robot)
    trajectory = _trajectory(robot, profile)
    from mrm_cosim.cosim.clocks import ClockConfig, plan_clocks
    from mrm_cosim.protocol.link import DEFAULT_SLOTS

    clocks = clocks or ClockConfig()
    clocks.check(robot.n)
    plan = plan_clocks(clocks, robot.n, seed, DEFAULT_SLOTS)
    uploads = node_uploads(robot, controller, gains, period_cycles=timing.period_cycles,
                           commit_cycles=commit_cycles, safe_stop=safe_stop,
                           discipline=(clocks.kp, clocks.ki) if clocks.discipline else None)
    if references == "dmp":
        from mrm_cosim.master.uploads import dmp_uploads

        if dmp is None:
            raise InputError("dmp", "references 'dmp' needs a primitive per joint")
        uploads += dmp_uploads(robot, dmp, dmp_step_cycles, timing.period_cycles)
    # the master checks every Comm A against the uploads (CRC and count per node)
    master = Master(robot, controller, trajectory, robot.counts_per_rev, timing, lam=gains.lam,
                    pid=pid_gains(robot, gains.pid_1khz_hz, gains.pid_1khz_base_hz),
                    base_fb=gains.vdc_base_fb, uploads=uploads,
                    references=references, on_trip=on_trip, rearm_blend=rearm_blend)
    plant = make_plant(robot, plant_config or PlantConfig(), seed=seed)
    plant.reset(robot.home)
    duration_cycles = int(round(duration * CLOCK_HZ))
    for f in faults:
        if f.cycle >= duration_cycles:
            raise InputError("faults", f"a fault at {f.cycle / CLOCK_HZ:g} s from period 0 "
                             f"is after the run's end ({duration:g} s): it would never happen")
    t0 = time.perf_counter()
    # period 0 on the nodes' timer grid (a multiple of the period from reset), after start-up
    start = -(-START_CYCLE // timing.period_cycles) * timing.period_cycles
    window = None
    if vcd is not None:
        from mrm_cosim.cosim.backends import VcdWindow

        if backend == "model":
            raise InputError("vcd", "the model backend has no signals; use pysim or compiled")
        if vcd_path is None:
            raise InputError("vcd", "needs an output file")
        window = VcdWindow.parse(vcd, vcd_path, signals=signals, offset=start / CLOCK_HZ)
    result, be = run_loop(robot, backend, master, plant, start, uploads, duration_cycles,
                          quiet=progress is None, vcd=window, progress=progress, faults=faults,
                          clocks=plan, keep=True, discipline=clocks.discipline)
    wall = time.perf_counter() - t0
    q_d, qd_d, _, _ = profile.evaluate(result.t)
    tip_d, speed = tip_points(robot, q_d[::10], qd_d[::10])
    tip = tip_points(robot, result.q[::10])
    err = np.linalg.norm(tip_d - tip, axis=1)
    phases = _phases_us(master)
    link_detail = link_errors_detail(result)
    link_total = (link_detail["master_rx_dropped"] + link_detail["master_port"]
                  + sum(link_detail["nodes"].values()))
    summary = {
        "controller": controller, "backend": backend, "robot": robot.name, "seed": seed,
        "duration_s": duration,
        "rho_s": float(err.max() / max(speed.max(), 1e-12)),
        "max_tip_error_m": float(err.max()),
        "max_tip_speed_m_s": float(speed.max()),
        "max_joint_error_rad": float(np.abs(q_d - result.q).max()),
        **hold_figures(robot, result.t, q_d - result.q, result.tau,
                       getattr(profile, "tf", None)),
        "overruns": master.overruns, "missing_replies": master.missing,
        "unexpected_replies": master.unexpected, "late_replies": master.late,
        "upload_errors": master.upload_error_total(),
        "upload_errors_per_node": [master.upload_errors[k] for k in range(1, robot.n + 1)],
        "tripped_nodes": sorted(master.tripped),
        "lost_nodes": sorted(master.lost),
        "ended": master.ended,
        "rearms": master.rearms,
        "recovery": [{"t_s": (c - start) / CLOCK_HZ, "event": e}
                     for c, e in master.recovery_log],
        "references": references,
        "dmp_errors": int(sum(master.dmp_errors.values())),
        "node_counters": master.node_totals(),
        "model_violations": list(getattr(result, "violations", [])),
        "link_errors": link_total,
        "link_error_detail": link_detail,
        "phases_us": phases,
        "period_skew": period_skew(master.records, robot.n, timing.period_cycles,
                                   strobes=master.boundary_strobes),
        "trace_sha256": result.trace_sha256,
        "clocks": clocks_summary(clocks, robot.n, seed, be),
        "wall_s": wall,
        "rtf": wall / (duration + start / CLOCK_HZ),
    }
    return result, summary


#: The window at the end of a run over which :func:`hold_figures` judges the hold, s.
HOLD_WINDOW = 0.1


def hold_figures(robot, t, error, tau, t_motion_end) -> dict:
    """Figures of a run's robustness (the tuning's constraints, cosim/tune.py):

    ``max_torque_ratio``, the largest torque command of any joint over its actuator's peak
    torque (1.0: saturated); over the last :data:`HOLD_WINDOW` s of the run, if that window
    lies after the motion ends (``t_motion_end``), ``hold_error_rad``, the largest joint error
    in it, and ``hold_ripple_rad``, the largest peak-to-peak joint error in it (a limit cycle
    or a growing oscillation). Without such a window both are ``None``."""
    from mrm_cosim.models.actuators import ACTUATORS

    peak = np.array([ACTUATORS[m.type.actuator].peak_torque for m in robot.modules])
    out = {"max_torque_ratio": float((np.abs(tau).max(axis=0) / peak).max()) if len(tau) else 0.0,
           "hold_error_rad": None, "hold_ripple_rad": None}
    if t_motion_end is not None and len(t) and t[-1] - HOLD_WINDOW >= t_motion_end:
        win = error[t >= t[-1] - HOLD_WINDOW]
        out["hold_error_rad"] = float(np.abs(win).max())
        out["hold_ripple_rad"] = float((win.max(axis=0) - win.min(axis=0)).max())
    return out


#: What each node counter of a summary's ``node_counters`` counts (Comm A, docs/node.md).
NODE_COUNTER_NAMES = {"overruns": "skipped control ticks", "sync_errors": "time-codes out of "
                      "the sync window", "late_d": "late Comm D", "errors": "illegal encoder "
                      "steps", "dmp_overruns": "primitive steps not ready"}


def run_faults(summary: dict) -> list[str]:
    """Everything a run's ``summary`` counted that a clean run does not have, one phrase each
    (empty for a clean run): the master's overruns and bad replies, upload and link errors,
    tripped nodes, the nodes' own counters, the model backend's violated assumptions."""
    out = []
    for key, text in (("overruns", "periods overrun"), ("missing_replies", "missing replies"),
                      ("unexpected_replies", "unexpected replies"),
                      ("late_replies", "late replies"), ("upload_errors", "upload errors"),
                      ("dmp_errors", "primitive errors (deploy not confirmed, or not running)"),
                      ("link_errors", "link errors")):
        if summary.get(key):
            out.append(f"{summary[key]} {text}")
    if summary.get("tripped_nodes"):
        out.append("watchdog tripped on node " + ", ".join(map(str, summary["tripped_nodes"])))
    lost = [k for k in summary.get("lost_nodes", []) if k not in summary.get("tripped_nodes", [])]
    if lost:
        out.append("no Comm A from node " + ", ".join(map(str, lost)) + " in some period (the "
                   "link lost: silent beyond their watchdog's timeout, nodes trip)")
    if summary.get("ended"):
        out.append(f"the master ended the run: {summary['ended']}")
    for key, value in summary.get("node_counters", {}).items():
        if value:
            out.append(f"{value} {NODE_COUNTER_NAMES.get(key, key)} (nodes' {key})")
    if summary.get("model_violations"):
        out.append(f"{len(summary['model_violations'])} model backend assumptions violated")
    return out


def link_errors_detail(result) -> dict:
    """Where the link faults of a run were counted.

    ``master_rx_dropped``: frames the master dropped (CRC, length, EEP); ``master_port``: the
    master port codec's errors (five classes summed); ``nodes``: each of
    :data:`protocol.regs.LINK_HEALTH` summed over the nodes, as last reported in Comm A;
    ``per_node``: the same per node (keys "1".."N"). The summary's ``link_errors`` is the sum
    of all of them (0: no fault anywhere on the chain).
    """
    m = result.master
    return {"master_rx_dropped": int(result.crc_errors),
            "master_port": int(result.link_errors),
            "nodes": m.link_totals(),
            "per_node": {str(k): dict(v) for k, v in sorted(m.node_link.items())}}


def link_fault_places(detail: dict) -> str:
    """Where a run's link faults were counted, in words (``summary["link_error_detail"]``)."""
    places = []
    if detail["master_rx_dropped"]:
        places.append(f"master dropped {detail['master_rx_dropped']} frame(s)")
    if detail["master_port"]:
        places.append(f"master port codec {detail['master_port']}")
    names = {"up_link_errors": "upstream codec", "down_link_errors": "downstream codec",
             "rx_dropped": "frames dropped", "router_dropped": "router discards"}
    for node, counters in detail["per_node"].items():
        for key, n in counters.items():
            if n:
                places.append(f"node {node} {names[key]} {n}")
    return ", ".join(places)


def _trajectory(robot, profile=None):
    """``t -> (q_d, q̇_d, q̈_d)`` of the paper's quintic test for ``robot``."""
    profile = profile or paper_test_profile(robot)

    if hasattr(profile, "at"):                  # a quintic: one time, without the arrays
        def trajectory(t):
            q, qd, qdd, _ = profile.at(t)       # = profile.evaluate([t])[k][0], cheaper
            return q, qd, qdd
    else:                                       # any other profile (a line, a delayed one)
        def trajectory(t):
            q, qd, qdd, _ = profile.evaluate(np.array([t]))
            return q[0], qd[0], qdd[0]

    return trajectory


def clocks_summary(clocks, n: int, seed: int, backend=None) -> dict:
    """What ran of ``[clocks]`` (:class:`cosim.clocks.ClockConfig`), for a summary: the mode,
    every clock's offset (ppm) and phase (cycles), master port first, whether the nodes'
    timers were disciplined, and the node strobes the per-node-clock harness merged
    (docs/clocks.md; 0 on a common clock)."""
    ppm, phase = clocks.resolve(n, seed)
    return {"mode": clocks.mode, "discipline": clocks.discipline,
            "master_ppm": ppm[0], "master_phase": phase[0],
            "ppm": list(ppm[1:]), "phase": list(phase[1:]),
            "merged_strobes": int(getattr(backend, "merged_strobes", 0))}


def run_loop(robot, backend: str, master, plant, start_cycle: int, uploads,
             duration_cycles: int, record: bool = False, quiet: bool = True, vcd=None,
             progress=None, faults=(), clocks=None, keep: bool = False,
             discipline: bool = False):
    """Run the closed loop of ``robot`` on the backend named ``backend``: this picks the
    gateware side (:func:`loop_backend`); :class:`cosim.closed_loop.ClosedLoop` runs it.

    ``vcd``: a :class:`cosim.backends.VcdWindow` to record (pysim, compiled); ``progress``:
    ``progress(t_sim, t_total)`` about every simulated millisecond; ``faults``: line faults
    to inject (:class:`cosim.closed_loop.LineFault`; pysim and compiled); ``clocks``: a
    :class:`cosim.clocks.ClockPlan` (a clock per node; None: one clock); ``discipline``: the
    master uploads CONFIG TC_DISCIPLINE (the model backend then runs its pure-Python path).

    Returns
    -------
    (LoopResult, GatewareSide or None)
        With ``record`` (or ``keep``), the backend, which holds every per-cycle output the loop
        sampled (:meth:`cosim.backends.LineSide.trace`).
    """
    be = loop_backend(robot, backend, record=record, quiet=quiet, vcd=vcd, faults=faults,
                      clocks=clocks, discipline=discipline)
    loop = ClosedLoop(robot, be, master, plant, start_cycle, uploads)
    return loop.run(duration_cycles, progress=progress), (be if record or keep else None)


def loop_backend(robot, backend: str, record: bool = False, quiet: bool = True, vcd=None,
                 faults=(), clocks=None, discipline: bool = False):
    """The gateware side of ``robot``'s loop on the backend named ``backend``
    (:data:`BACKENDS`): :func:`loop_system` simulated (pysim) or compiled, or the nodes'
    references (model, which has no signals to record and a link at packet level: it takes
    line cuts, :mod:`cosim.model_link`). ``clocks``: a :class:`cosim.clocks.ClockPlan` runs
    each node on a clock of its own (the model: each node's reference in cycles of its own
    clock, docs/clocks.md); ``discipline``: the nodes' timers will be disciplined (CONFIG
    TC_DISCIPLINE), which the model's compiled kernel does not model: its pure-Python path
    runs."""
    if backend == "model":
        from mrm_cosim.cosim.model import ModelBackend

        if record or vcd is not None:
            raise InputError("vcd" if vcd is not None else "record",
                             "the model backend has no signals; use pysim or compiled")
        return ModelBackend(encoder=node_encoders(robot), pid_shift=pid_shifts(robot),
                            faults=faults, clocks=clocks,
                            kernel="python" if discipline else None)
    node = "common" if clocks is None else "node"
    if backend == "compiled":
        return CompiledBackend(lambda: loop_system(robot, node), loop_system_key(robot, node),
                               quiet=quiet, vcd=vcd, faults=faults, record=record,
                               clocks=clocks, threads=compiled_threads(),
                               segment=(robot.n, lambda k: loop_segment(robot, k)))
    if backend == "pysim":
        return PysimBackend(loop_system(robot, node), vcd=vcd, faults=faults, record=record,
                            clocks=clocks)
    raise InputError("backend", f"must be one of {', '.join(BACKENDS)}, not {backend!r}")


def loop_system(robot, clocks: str = "common"):
    """The design every closed-loop run of ``robot`` simulates: :class:`hdl.system.System`
    with a node per module, each built for its module's encoder (:func:`node_encoders`) and
    PID gains (:func:`master.uploads.pid_shifts`), and the line-fault inputs (held at zero
    unless a run injects faults); ``clocks``: :class:`hdl.system.System`'s (``"node"``: a
    clock domain per node)."""
    from mrm_cosim.hdl.system import System

    if clocks == "common":
        return System(robot.n, encoder=node_encoders(robot), pid_shift=pid_shifts(robot),
                      line_faults=True)
    return System(robot.n, encoder=node_encoders(robot), pid_shift=pid_shifts(robot),
                  line_faults=True, clocks=clocks)


def loop_system_key(robot, clocks: str = "common") -> str:
    """The compiled-model cache key of :func:`loop_system`: the number of nodes, the nodes'
    PID gain shifts and, where they are not the gateware's default, their counts per
    revolution."""
    from mrm_cosim.protocol.encoder import EncoderParams

    cprs = [e.counts_per_rev for e in node_encoders(robot)]
    key = f"system{robot.n}-faults-pid" + "-".join(str(s) for s in pid_shifts(robot))
    if any(c != EncoderParams().counts_per_rev for c in cprs):
        key += "-cpr" + "-".join(str(c) for c in cprs)
    if clocks != "common":
        key += f"-clocks-{clocks}"
    return key


#: the environment variable that sets the compiled backend's threads (``mrm … --threads``)
THREADS_ENV = "MRM_COMPILED_THREADS"


def compiled_threads() -> int:
    """The compiled backend's threads: ``$MRM_COMPILED_THREADS`` (an integer ≥ 1; ``mrm run``
    and ``mrm bench`` set it from ``--threads``, and the processes they start inherit it),
    default 1 (the whole system's model). More than one runs the system as a model per node
    on that many threads, at most one a node (:class:`cosim.compiled.SplitModel`): the same
    results bit for bit, faster on wall time where the cores are free."""
    raw = os.environ.get(THREADS_ENV, "1")
    try:
        threads = int(raw)
    except ValueError:
        threads = 0
    if threads < 1:
        raise InputError(THREADS_ENV, f"must be an integer >= 1, not {raw!r}")
    return threads


@contextlib.contextmanager
def compiled_threads_env(threads=None):
    """``$MRM_COMPILED_THREADS`` set to ``threads`` (unless None) inside the block, and the
    environment as it was after it (whatever the block set it to meanwhile)."""
    before = os.environ.get(THREADS_ENV)
    if threads is not None:
        os.environ[THREADS_ENV] = str(threads)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(THREADS_ENV, None)
        else:
            os.environ[THREADS_ENV] = before


def loop_segment(robot, first: int, count: int = 1):
    """Nodes ``first … first + count − 1`` of :func:`loop_system` (one clock) as a design of
    their own (:class:`hdl.system.Segment`; :class:`cosim.compiled.SplitModel` runs the
    system as such parts). A part of one node is named apart from its place (``local``), so
    nodes alike share one build and one copy of its code."""
    from mrm_cosim.hdl.system import Segment

    return Segment(robot.n, first, count, encoder=node_encoders(robot),
                   pid_shift=pid_shifts(robot), line_faults=True, local=count == 1)


def _phases_us(master) -> dict:
    """Mean over complete periods of when each phase ends, µs from the period start.

    ``A``, ``B``, ``C``, ``D``: last Comm A in, Comm B sent, last Comm C in, Comm D sent;
    ``cycle``: the last reply in. Per node (lists, node 1 first; None where a node never
    reported the events, e.g. no VDC in the PID modes), from the nodes' observation ports:
    ``node_compute`` the VDC's duration (``VDC_START`` → ``VDC_DONE``, µs), ``commit`` the
    phase at which Comm D took effect (``COMMIT``, µs from the period start).
    """
    recs = [r for r in master.records if r.complete]
    if not recs:
        return {}

    def mean(f):
        vals = [f(r) for r in recs]
        vals = [v for v in vals if v is not None]
        return float(np.mean(vals)) / 50.0 if vals else None

    def node(k, first, last):
        def span(r):
            ne = r.node_events
            if (last, k) not in ne or (first is not None and (first, k) not in ne):
                return None
            return ne[(last, k)] - (r.start if first is None else ne[(first, k)])
        return mean(span)

    nodes = range(1, master.n + 1)
    return {
        "A": mean(lambda r: r.events["A_done"] - r.start if "A_done" in r.events else None),
        "B": mean(lambda r: r.events["B_sent"] - r.start if "B_sent" in r.events else None),
        "C": mean(lambda r: r.events["C_done"] - r.start if "C_done" in r.events else None),
        "D": mean(lambda r: r.events["D_sent"] - r.start if "D_sent" in r.events else None),
        "cycle": mean(lambda r: max(r.arrivals.values(), default=r.start) - r.start),
        "node_compute": [node(k, "VDC_START", "VDC_DONE") for k in nodes],
        "commit": [node(k, None, "COMMIT") for k in nodes],
    }
