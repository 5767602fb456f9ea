"""``mrm plan``: plan a trajectory and print its figures (optionally write its samples).

``mrm plan quintic``: rest-to-rest quintic (the MRM paper's eq. 4), exact peaks.
``mrm plan line FILE.toml``: straight-line Cartesian move with quaternion orientation, the
trigonometric jerk-continuous profile (default) or Ruckig's time-optimal one.
"""

from __future__ import annotations

import json
import sys

import numpy as np

from mrm_cosim.errors import InputError, require_finite, require_positive
from mrm_cosim.results import atomic_write_text, check_output_file
from mrm_cosim.master.line_file import load_line_file



def register(subparsers) -> None:
    p = subparsers.add_parser("plan", help="plan a trajectory (quintic, Cartesian line)",
                              epilog="example:\n  mrm plan quintic --q0 0 --qf 0.1571 --tf 1")
    sub = p.add_subparsers(dest="plan_command", required=True)

    q = sub.add_parser("quintic", help="rest-to-rest quintic point-to-point, exact peaks",
                       epilog="example:\n  mrm plan quintic --q0 0 0 --qf 0.1571 0.3142 --tf 1 "
                       "--samples q.csv --dt 0.001")
    q.add_argument("--q0", nargs="+", required=True, metavar="RAD",
                   help="start position(s), rad (one per joint)")
    q.add_argument("--qf", nargs="+", required=True, metavar="RAD",
                   help="end position(s), rad (one per joint)")
    q.add_argument("--tf", required=True, metavar="S", help="duration, s")
    q.add_argument("--json", action="store_true", help="machine-readable output")
    q.add_argument("--samples", metavar="OUT.csv", help="write q, q', q'', q''' at every --dt")
    q.add_argument("--dt", default="0.001", metavar="S", help="sample period, s")
    q.set_defaults(func=_quintic)

    ln = sub.add_parser("line", help="straight-line Cartesian move with quaternion orientation",
                        epilog="example:\n  mrm plan line examples/line.toml --json --samples "
                        "line.csv")
    ln.add_argument("file", metavar="FILE.toml", help="start/end poses and limits")
    ln.add_argument("--profile", choices=("trig", "ruckig"), default="trig",
                    help="trigonometric jerk-continuous or Ruckig time-optimal")
    ln.add_argument("--json", action="store_true", help="machine-readable output")
    ln.add_argument("--samples", metavar="OUT.csv",
                    help="write pose, velocity, acceleration, jerk at every --dt")
    ln.add_argument("--dt", default="0.001", metavar="S", help="sample period, s")
    ln.set_defaults(func=_line)


# ---------------------------------------------------------------------------------- output


def write_csv_atomic(path: str, header: list[str] | tuple[str, ...], table: np.ndarray) -> None:
    """Write ``table`` (shape (n, len(header))) as CSV with a header row, atomically.

    The rows go to a temporary file beside ``path`` that replaces it only once complete.
    Numbers are written in Python's shortest round-trip form, so they read back bit for bit.
    """
    rows = (np.asarray(table, dtype=float) + 0.0).tolist()   # + 0.0: no "-0"
    atomic_write_text(path, "".join([",".join(header) + "\n"]
                                    + [",".join(map(repr, row)) + "\n" for row in rows]),
                      "--samples")


def _print_json(figures: dict) -> None:
    print(json.dumps(figures, indent=2))


def _print_table(title: str, figures: dict) -> None:
    print(title)
    width = max(len(k) for k in figures)
    for key, value in figures.items():
        shown = (", ".join(f"{v:.9g}" for v in value) if isinstance(value, list)
                 else f"{value:.9g}" if isinstance(value, float) else str(value))
        print(f"  {key:<{width}}  {shown}")


# ---------------------------------------------------------------------------------- quintic


def _numbers(values: list[str], field: str) -> list[float]:
    if len(values) == 1:
        return [require_finite(_parse_float(values[0], field), field)]
    return [require_finite(_parse_float(v, f"{field}[{i}]"), f"{field}[{i}]")
            for i, v in enumerate(values)]


def _parse_float(text: str, field: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise InputError(field, f"must be a number, not {text!r}") from None


def quintic_figures(q0: list[float], qf: list[float], tf: float) -> dict:
    """Closed-form figures of the quintic; scalars for one joint, lists for several."""
    from mrm_cosim.master.quintic import QuinticProfile

    if len(q0) not in (1, len(qf)):
        raise InputError("--qf", f"has {len(qf)} joints but --q0 has {len(q0)}")
    try:
        summary = QuinticProfile(q0, qf, tf).summary()
    except InputError as e:       # the profile names its own fields: q0, qf, tf
        raise InputError(f"--{e.field}", e.message) from None
    if len(qf) == 1:
        summary = {k: (v[0] if isinstance(v, list) else v) for k, v in summary.items()}
    return summary


def _sample_times(duration: float, dt: float):
    """:func:`master.trig_planner.sample_times`, its errors naming the flag ``--dt``."""
    from mrm_cosim.master.trig_planner import sample_times

    try:
        return sample_times(duration, dt)
    except InputError as e:
        raise InputError("--dt", e.message) from None


def _quintic(args) -> int:
    from mrm_cosim.master.quintic import QuinticProfile

    if args.samples:
        check_output_file(args.samples, "--samples")     # before anything is computed
    q0 = _numbers(args.q0, "--q0")
    qf = _numbers(args.qf, "--qf")
    tf = require_positive(_parse_float(args.tf, "--tf"), "--tf")
    figures = quintic_figures(q0, qf, tf)
    if args.samples:
        dt = require_positive(_parse_float(args.dt, "--dt"), "--dt")
        profile = QuinticProfile(q0, qf, tf)
        t = _sample_times(tf, dt)
        q, qd, qdd, qddd = profile.evaluate(t)
        n = profile.n_dof
        header = (["t_s"] + [f"q{i}_rad" for i in range(1, n + 1)]
                  + [f"qd{i}_rad_s" for i in range(1, n + 1)]
                  + [f"qdd{i}_rad_s2" for i in range(1, n + 1)]
                  + [f"qddd{i}_rad_s3" for i in range(1, n + 1)])
        write_csv_atomic(args.samples, header, np.column_stack([t, q, qd, qdd, qddd]))
    if args.json:
        _print_json(figures)
    else:
        _print_table("quintic rest-to-rest (exact peaks; rad, s)", figures)
    return 0


# ---------------------------------------------------------------------------------- line


def _line(args) -> int:
    from mrm_cosim.master.trig_planner import plan_line

    if args.samples:
        check_output_file(args.samples, "--samples")     # before anything is computed
    dt = require_positive(_parse_float(args.dt, "--dt"), "--dt") if args.samples else None
    start, end, limits = load_line_file(args.file)
    plan = plan_line(start, end, limits)
    if args.profile == "ruckig":
        from mrm_cosim.master.ruckig_profile import plan_line_ruckig

        plan = plan_line_ruckig(plan)
    for note in plan.notes:
        sys.stderr.write(f"mrm plan line: note: {note}\n")
    if args.samples:
        samples = plan.sample(_sample_times(plan.duration, dt))
        write_csv_atomic(args.samples, samples.COLUMNS, samples.table())
    figures = plan.summary()
    if args.json:
        _print_json(figures)
    else:
        title = ("Ruckig time-optimal jerk-limited line (m, rad, s)" if args.profile == "ruckig"
                 else "trigonometric jerk-continuous line (m, rad, s)")
        _print_table(title, figures)
    return 0
