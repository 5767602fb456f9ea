"""``mrm dmp``: learn a discrete DMP from a demo and roll it out (master/dmp.py).

``mrm dmp learn TRAJ.csv --basis N --out dmp.toml``: a joint trajectory (or, with
``--cartesian``, a Cartesian path solved through the robot's IK) → a primitive in a TOML file
(master/dmp_file.py), with a summary of the fit.
``mrm dmp rollout dmp.toml [--goal …] [--tau T]``: the primitive run by its recurrence at
``--dt``, aimed at a new goal or stretched in time; summary, samples CSV, plot.
Outputs are checked before anything is computed and written atomically.
"""

from __future__ import annotations

import io
import json
import os

import numpy as np

from mrm_cosim.errors import InputError, require_positive
from mrm_cosim.mrm.flags import DMP_LEARN, DMP_ROLLOUT, named_by_flags
from mrm_cosim.results import check_output_file

# Defaults of master.dmp.learn_dmp, as the help shows them.
ALPHA, ALPHA_S, OVERLAP = "25", "2", "0.2"


def register(subparsers) -> None:
    p = subparsers.add_parser("dmp", help="learn a DMP from a demo, roll it out",
                              epilog="example:\n  mrm dmp learn demo.csv --basis 10 --out "
                              "dmp.toml\n  mrm dmp rollout dmp.toml --tau 2 --samples out.csv")
    sub = p.add_subparsers(dest="dmp_command", required=True)

    ln = sub.add_parser(
        "learn", help="learn a DMP from a joint trajectory or a Cartesian path (CSV)",
        epilog="CSV: a header row, then one row per sample at a uniform step. Joint "
        "trajectory:\n  t (or t_s, s) and one column per joint (rad).\nCartesian path "
        "(--cartesian): t, x, y, z (m), qw, qx, qy, qz (unit quaternion,\n  w first), "
        "solved by the robot's IK from its home posture on one branch.\nexample:\n"
        "  mrm dmp learn demo.csv --basis 10 --out dmp.toml\n"
        "  mrm plan line examples/line.toml --samples line.csv --dt 0.005\n"
        "  mrm dmp learn line.csv --cartesian --robot mrm6 --basis 20 --out line_dmp.toml")
    ln.add_argument("traj", metavar="TRAJ.csv", help="the demo (see below)")
    ln.add_argument("--basis", required=True, metavar="N",
                    help="Gaussian basis functions per DOF (integer >= 2)")
    ln.add_argument("--out", required=True, metavar="DMP.toml", help="the primitive's file")
    ln.add_argument("--alpha", default=ALPHA, metavar="A", help="spring gain α (β = α/4)")
    ln.add_argument("--alpha-s", default=ALPHA_S, metavar="AS",
                    help="phase decay α_s (phase exp(-α_s) at the demo's end)")
    ln.add_argument("--overlap", default=OVERLAP, metavar="O",
                    help="each Gaussian's value halfway to its neighbour, in (0, 1)")
    ln.add_argument("--columns", metavar="C1,C2,…",
                    help="joint columns to learn (default: every column but t)")
    ln.add_argument("--cartesian", action="store_true",
                    help="TRAJ is a Cartesian path: convert it to joints through --robot's IK")
    ln.add_argument("--robot", default=None,
                    help="six-joint robot for --cartesian: built-in name or assembly .toml "
                    "(default: mrm6)")
    ln.add_argument("--json", action="store_true", help="machine-readable summary")
    ln.set_defaults(func=_learn)

    ro = sub.add_parser(
        "rollout", help="run a learned DMP (new goal, new τ); summary, samples, plot",
        epilog="example:\n  mrm dmp rollout dmp.toml --goal 0.5,0.2 --tau 2 --dt 0.001 "
        "--samples out.csv --plot out.png\n  mrm dmp rollout dmp.toml --duration 3 --json")
    ro.add_argument("dmp", metavar="DMP.toml", help="a file written by mrm dmp learn")
    ro.add_argument("--goal", metavar="G1,G2,…", help="new goal, one value per DOF "
                    "(default: the demo's)")
    ro.add_argument("--tau", metavar="T", help="time constant, s: the rollout lasts τ "
                    "(default: the demo's duration)")
    ro.add_argument("--duration", metavar="S", help="length of the rollout, s; longer than "
                    "τ lets the phase die out at the goal (default: τ)")
    ro.add_argument("--dt", default="0.001", metavar="S", help="integration step, s")
    ro.add_argument("--samples", metavar="OUT.csv",
                    help="write t, x_i, xd_i, xdd_i at every step")
    ro.add_argument("--plot", metavar="OUT.png", help="plot x_i(t) with the goal")
    ro.add_argument("--json", action="store_true", help="machine-readable summary")
    ro.set_defaults(func=_rollout)


# ---------------------------------------------------------------------------------- parsing


def _number(text: str, field: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise InputError(field, f"must be a number, not {text!r}") from None


def _integer(text: str, field: str) -> int:
    try:
        return int(text.strip())
    except ValueError:
        raise InputError(field, f"must be an integer >= 2, not {text!r}") from None


def _list(text: str, field: str) -> list[str]:
    items = [item.strip() for item in text.split(",")]
    if any(not item for item in items):
        raise InputError(field, f"must be a comma-separated list without empty items, not "
                         f"{text!r}")
    return items


def _distinct(paths: dict[str, str]) -> None:
    """Refuse two outputs (or an output and an input) that are the same file."""
    seen: dict[str, str] = {}
    for flag, path in paths.items():
        if path is None:
            continue
        key = os.path.realpath(path)
        if key in seen:
            raise InputError(flag, f"{path!r} is also {seen[key]}; it would be overwritten")
        seen[key] = flag


def _print_table(title: str, figures: dict) -> None:
    print(title)
    width = max(len(k) for k in figures)
    for key, value in figures.items():
        shown = (", ".join(f"{v:.6g}" if isinstance(v, float) else str(v) for v in value)
                 if isinstance(value, list)
                 else f"{value:.6g}" if isinstance(value, float) else str(value))
        print(f"  {key:<{width}}  {shown}")


# ---------------------------------------------------------------------------------- learn


@named_by_flags(DMP_LEARN)
def _learn(args) -> int:
    from mrm_cosim.master.dmp import learn_dmp
    from mrm_cosim.master.dmp_demo import joints_from_poses, read_demo
    from mrm_cosim.master.dmp_file import write_dmp

    check_output_file(args.out, "out")                  # before anything is computed
    _distinct({"TRAJ": args.traj, "--out": args.out})
    n_basis = _integer(args.basis, "n_basis")
    alpha = _number(args.alpha, "alpha")
    alpha_s = _number(args.alpha_s, "alpha_s")
    overlap = _number(args.overlap, "overlap")
    if args.robot is not None and not args.cartesian:
        raise InputError("robot", "is for a Cartesian path (--cartesian); a joint trajectory "
                         "needs no robot")
    columns = None if args.columns is None else _list(args.columns, "columns")
    if args.cartesian:
        from mrm_cosim.models.robot import load_robot

        robot = load_robot(args.robot or "mrm6")
    demo = read_demo(args.traj, columns=columns, cartesian=args.cartesian, field="TRAJ")
    if args.cartesian:
        y = joints_from_poses(robot, demo, field="TRAJ")
        names = [f"q{i + 1}" for i in range(y.shape[1])]
    else:
        y, names = demo.values, list(demo.names)
    dmp = learn_dmp(y, demo.dt, n_basis, alpha=alpha, alpha_s=alpha_s, overlap=overlap)
    try:
        dmp.check_step(demo.dt)
    except InputError as exc:
        raise InputError("TRAJ", f"its sample step {demo.dt:.9g} s: {exc.message}") from None
    fit = dmp.rollout(demo.dt)
    n = min(len(fit.t), len(y))
    err = fit.x[:n] - y[:n]
    rmse = np.sqrt(np.mean(err**2, axis=0))
    meta = {"source": os.path.abspath(args.traj), "kind": "cartesian" if args.cartesian
            else "joint", "columns": names, "basis": n_basis, "alpha": alpha,
            "alpha_s": alpha_s, "overlap": overlap, "dt": demo.dt, "samples": len(y),
            "fit_rmse": rmse.tolist()}
    if args.cartesian:
        meta["robot"] = robot.name
    write_dmp(args.out, dmp, meta, "out")
    figures = {"n_dof": dmp.n_dof, "basis": dmp.n_basis, "tau_s": dmp.tau,
               "sample_step_s": demo.dt, "samples": len(y), "columns": names,
               "fit_rmse": rmse.tolist(), "fit_max_error": np.abs(err).max(axis=0).tolist(),
               "out": args.out}
    if args.json:
        print(json.dumps(figures, indent=2))
    elif not args.quiet:
        _print_table("DMP learned (fit: rollout at the demo's step vs the demo, per DOF)",
                     figures)
    return 0


# ---------------------------------------------------------------------------------- rollout


@named_by_flags(DMP_ROLLOUT)
def _rollout(args) -> int:
    from mrm_cosim.master.dmp_file import read_dmp

    for path, field in ((args.samples, "out"), (args.plot, "plot")):
        if path is not None:
            check_output_file(path, field)              # before anything is computed
    _distinct({"DMP": args.dmp, "--samples": args.samples, "--plot": args.plot})
    dt = require_positive(_number(args.dt, "dt"), "dt")
    tau = None if args.tau is None else require_positive(_number(args.tau, "tau"), "tau")
    duration = (None if args.duration is None
                else require_positive(_number(args.duration, "duration"), "duration"))
    goal = None
    if args.goal is not None:
        goal = [_number(v, f"g[{i}]") for i, v in enumerate(_list(args.goal, "g"))]
    dmp = read_dmp(args.dmp, "DMP")
    if goal is not None:
        if len(goal) != dmp.n_dof:
            raise InputError("g", f"gives {len(goal)} goal values; the DMP has "
                             f"{dmp.n_dof} DOF")
        dmp = dmp.with_goal(goal)
    if tau is not None:
        dmp = dmp.with_tau(tau)
    run = dmp.rollout(dt, duration)
    n = dmp.n_dof
    if args.samples is not None:
        from mrm_cosim.mrm.commands.plan import write_csv_atomic

        header = (["t_s"] + [f"x{i}" for i in range(1, n + 1)]
                  + [f"xd{i}" for i in range(1, n + 1)]
                  + [f"xdd{i}" for i in range(1, n + 1)])
        write_csv_atomic(args.samples, header, np.column_stack([run.t, run.x, run.xd,
                                                                run.xdd]))
    if args.plot is not None:
        _plot(args.plot, run, dmp)
    end = run.x[-1]
    figures = {"n_dof": n, "tau_s": dmp.tau, "dt_s": dt, "steps": len(run.t) - 1,
               "duration_s": float(run.t[-1]), "start": dmp.x0.tolist(), "goal": dmp.g.tolist(),
               "end": end.tolist(), "end_minus_goal": (end - dmp.g).tolist(),
               "phase_at_end": float(run.s[-1])}
    if args.json:
        print(json.dumps(figures, indent=2))
    elif not args.quiet:
        _print_table("DMP rollout (semi-implicit Euler, docs/trajectories.md §4.2)", figures)
    return 0


def _plot(path: str, run, dmp) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mrm_cosim.results import atomic_write_bytes

    fig, ax = plt.subplots(figsize=(7, 4), layout="constrained")
    for i in range(dmp.n_dof):
        line, = ax.plot(run.t, run.x[:, i], label=f"x{i + 1}")
        ax.axhline(dmp.g[i], color=line.get_color(), linestyle=":", linewidth=0.8)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("x (units of the demo: rad for joints)")
    ax.set_title(f"DMP rollout, τ = {dmp.tau:.4g} s (dotted: goal)")
    ax.legend(loc="best", fontsize="small")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue(), "plot")
