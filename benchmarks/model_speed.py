"""The ``model`` backend's speed, compiled inner loop against pure Python, side by side.

    python benchmarks/model_speed.py [--robot mrm3 --robot mrm6] [--cycles 2500000] [--rounds 3]
                                     [--joints rigid|compliant]
                                     [--pin | --calls | --steps | --master | --against PY]

For each robot, ``mrm bench``'s window (the VDC loop on the paper's quintic, after start-up)
runs alternately with ``kernel="numba"`` and ``kernel="python"``; it prints the real-time factor
of each (CPU time of this process over simulated time: the machine is shared, wall time is
noisier), best and median of the rounds, their ratio, and that the two trace hashes are equal.
Then one more run of each with the loop's parts timed (on by default, ``--no-breakdown``):
CPU µs per simulated 1 ms period spent in the fast steps (the compiled path's plain plant
steps, plant and nodes together: :meth:`cosim.model.ModelBackend.fast_path`), the general
steps' plant step, the master, the general steps' gateware side (nodes, encoders, link) and
the rest of the loop. The timers add a little to each part. ``--joints compliant`` runs the
same window on Table 2's compliant plant (its own fast path, ``fast_step_compliant``).

``--master`` times the master alone instead: the window's calls into it (``poll``,
``on_packet``, ``on_node_events``, ``next_due``, ``quiet_end``, ``stale``) recorded once, then
replayed on fresh masters with nothing else running between them; CPU µs per period, best of
the rounds, and whether every call returned what it returned in the loop (the packets it
sends, bit for bit).

``--pin`` measures pinocchio from compiled code (:mod:`cosim.pin_shim`: the kernel runs plant
steps on through ``aba``, ``nonLinearEffects`` and ``crba`` itself) against the kernel
returning to Python for ``pin`` every step, in one process: the compiled path's windows
alternate between the two, ABBA, and it prints each side's CPU RTF (best, median), the ratio
of the medians, the fast-step part of each (the breakdown's, median) and whether the trace
hashes are equal.

``--calls`` times the window function by function instead (the compiled path): every Python
call into the backend's fast runs and event loop, the nodes (packets by type, time-codes,
``run``), the kernel's entry points and the master, each with its own time (its callees among
them taken out), calls and µs a period, largest first — where a period's time goes, for the
next piece of work (the wrappers add ≈ 0.3 µs a call to the total).

``--steps`` times the window by the period's plant steps instead (the compiled path): the
time from the start of each fast run to the next, given to the step of the period where the
run began, with what crossed in that step (packets and time-codes reaching nodes, replies
reaching the master) — which steps of a period hold its time (µs a period, and their share).

``--against PYTHON`` measures this tree against another one, side by side in one run: the
other tree's interpreter (its venv's ``python``, whose ``mrm_cosim`` is that tree) runs this
script as a worker, and the windows alternate between the two processes, ABBA, so both see
the same load; it prints each side's CPU RTF (best, median) and the median of the ratios pair
by pair, with both trace hashes — on a shared machine the steadiest before/after figure. With
``--joints compliant`` both sides run the compliant plant (the worker is given ``--joints``).
"""

from __future__ import annotations

import argparse
import pickle
import statistics
import subprocess
import sys
import time

from mrm_cosim.cosim.closed_loop import ClosedLoop
from mrm_cosim.cosim.model import ModelBackend
from mrm_cosim.master.uploads import Gains, node_uploads, pid_shifts
from mrm_cosim.models.robot import load_robot
from mrm_cosim.units import CLOCK_HZ

START = 50_000          # period 0, as mrm bench


#: the plant's joints (``--joints``): ``mrm bench``'s rigid plant, or Table 2's compliant one
_JOINTS = "rigid"


def _loop(robot, kernel: str):
    from mrm_cosim.cosim.bench import bench_master_and_plant

    master, plant = bench_master_and_plant(robot)
    if _JOINTS != "rigid":
        from mrm_cosim.models.plant import PlantConfig, make_plant

        plant = make_plant(robot, PlantConfig(joints=_JOINTS), seed=0)
        plant.reset(robot.home)
    backend = ModelBackend(kernel=kernel, pid_shift=pid_shifts(robot))
    return ClosedLoop(robot, backend, master, plant, START, node_uploads(robot, "vdc", Gains()))


def _timed(obj, name: str, acc: dict, key: str) -> None:
    """Wrap ``obj.name`` to add its CPU time to ``acc[key]``."""
    f = getattr(obj, name)
    clock = time.process_time

    if name == "advance":                       # a coroutine function
        async def wrapped(*a, **kw):
            t = clock()
            out = await f(*a, **kw)
            acc[key] += clock() - t
            return out
    else:
        def wrapped(*a, **kw):
            t = clock()
            out = f(*a, **kw)
            acc[key] += clock() - t
            return out
    setattr(obj, name, wrapped)


def _at_period_0(loop, then) -> None:
    """``then()`` when the loop reaches period 0 (the master's ``begin``): a window's timers
    start there, after start-up."""
    begin = loop.master.begin

    def mark(cycle):
        then()
        return begin(cycle)

    loop.master.begin = mark


def run(robot_name: str, kernel: str, cycles: int, breakdown: bool = False):
    """One window; returns ``(rtf, trace hash, parts)`` (CPU s per part if ``breakdown``)."""
    robot = load_robot(robot_name)
    loop = _loop(robot, kernel)
    acc = dict.fromkeys(("fast steps", "plant", "master", "gateware side"), 0.0)
    if breakdown:
        _timed(loop.plant, "step", acc, "plant")
        _timed(loop.plant, "encoder_changes", acc, "plant")
        for name in ("poll", "on_packet", "on_node_events", "next_due", "quiet_end"):
            _timed(loop.master, name, acc, "master")
        _timed(loop.backend, "advance", acc, "gateware side")
        fast_path = loop.backend.fast_path

        def timed_fast_path(plant, rec):
            fast = fast_path(plant, rec)
            if fast is None:
                return None
            clock = time.process_time

            def timed(*a):
                t = clock()
                k = fast(*a)
                acc["fast steps"] += clock() - t
                return k

            return timed

        loop.backend.fast_path = timed_fast_path
    # the loop's own window timer is wall time: time the CPU from period 0 to the end instead
    marks = {}
    _at_period_0(loop, lambda: marks.update(t0=time.process_time()))
    result = loop.run(cycles)
    cpu = time.process_time() - marks["t0"]
    if breakdown:
        acc["loop and the rest"] = cpu - sum(acc.values())
    return cpu / (cycles / CLOCK_HZ), result.trace_sha256, acc, result.violations


_MASTER_CALLS = ("poll", "on_packet", "on_node_events", "next_due", "quiet_end", "stale")


def master_alone(robot_name: str, cycles: int, rounds: int):
    """The master's calls of one window replayed alone: ``(CPU s per round, best first; all
    replies equal)``."""
    from mrm_cosim.cosim.bench import bench_master_and_plant

    robot = load_robot(robot_name)
    loop = _loop(robot, "numba")
    master = loop.master
    log, state = [], {}
    begin = master.begin

    def mark(cycle):                # the master as period 0 finds it, and its calls from then
        out = begin(cycle)
        state["s"] = pickle.dumps({k: v for k, v in master.__dict__.items()
                                   if k not in ("robot", "trajectory", "begin")})
        depth = [0]                 # (the harness's calls only, not the master's own)
        for name in _MASTER_CALLS:
            f = getattr(master, name)

            def logged(*a, _f=f, _name=name):
                depth[0] += 1
                try:
                    out = _f(*a)
                finally:
                    depth[0] -= 1
                if not depth[0]:
                    log.append((_name, a, out))
                return out
            setattr(master, name, logged)
        return out

    master.begin = mark
    loop.run(cycles)
    times, same = [], True
    for _ in range(rounds):
        fresh, _ = bench_master_and_plant(robot)
        fresh.__dict__.update(pickle.loads(state["s"]))
        calls = [(getattr(fresh, name), a) for name, a, _ in log]
        t = time.process_time()
        outs = [f(*a) for f, a in calls]
        times.append(time.process_time() - t)
        same = same and all(o == e for o, (_, _, e) in zip(outs, log, strict=True))
    return sorted(times), same


def _worker() -> int:
    """``--worker``: warm up, say ``ready``, then one window per robot name read from stdin."""
    for robot in ("mrm3", "mrm6"):
        run(robot, "numba", 100_000)
    print("ready", flush=True)
    for line in sys.stdin:
        if not line.strip():
            break
        robot, cycles = line.split()
        rtf, digest, _, _ = run(robot, "numba", int(cycles))
        print(f"{rtf!r} {digest}", flush=True)
    return 0


def against(python: str, robots, cycles: int, pairs: int) -> None:
    """This tree and the one of interpreter ``python``, windows alternated ABBA (numba path)."""
    other = subprocess.Popen([python, __file__, "--worker", "--joints", _JOINTS],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    if other.stdout.readline().strip() != "ready":
        raise SystemExit(f"{python}: the worker did not start")
    for robot in ("mrm3", "mrm6"):
        run(robot, "numba", 100_000)

    def theirs(robot):
        other.stdin.write(f"{robot} {cycles}\n")
        other.stdin.flush()
        rtf, digest = other.stdout.readline().split()
        return float(rtf), digest

    def ours(robot):
        rtf, digest, _, _ = run(robot, "numba", cycles)
        return rtf, digest

    try:
        for robot in robots:
            rtf = {"this": [], "other": []}
            hashes = {"this": set(), "other": set()}
            ratios = []
            for i in range(pairs):
                got = {}
                for side in (("other", "this") if i % 2 == 0 else ("this", "other")):
                    got[side], h = (ours if side == "this" else theirs)(robot)
                    rtf[side].append(got[side])
                    hashes[side].add(h[:16])
                ratios.append(got["this"] / got["other"])
            q1, _, q3 = statistics.quantiles(ratios, n=4)
            print(f"{robot}: {pairs} pairs of windows, CPU RTF best / median: other "
                  f"{min(rtf['other']):.3f} / {statistics.median(rtf['other']):.3f}, this "
                  f"{min(rtf['this']):.3f} / {statistics.median(rtf['this']):.3f}; this / other "
                  f"pair by pair: median {statistics.median(ratios):.3f} (quartiles {q1:.3f}–"
                  f"{q3:.3f}); trace hashes {sorted(hashes['other'])} / {sorted(hashes['this'])}")
    finally:
        other.stdin.write("\n")
        other.stdin.flush()
        other.wait()


def calls(robot_name: str, cycles: int) -> None:
    """``--calls``: one window of the compiled path with its functions timed (self time)."""
    from mrm_cosim.protocol.packet import PacketType

    robot = load_robot(robot_name)
    run(robot_name, "numba", 100_000)
    loop = _loop(robot, "numba")
    own, count, stack = {}, {}, []
    clock = time.perf_counter_ns

    def timed(name, f, key=None):
        def wrapped(*a, **kw):
            t = clock()
            stack.append(0)
            try:
                return f(*a, **kw)
            finally:
                d = clock() - t
                inner = stack.pop()
                k = name if key is None else key(*a)
                own[k] = own.get(k, 0) + d - inner
                count[k] = count.get(k, 0) + 1
                if stack:
                    stack[-1] += d
        return wrapped

    be = loop.backend
    for name in ("_fast", "_fast_compliant", "_horizon", "_fast_begin", "_fast_end_run",
                 "_end_commits", "_event_step", "_run_kernel_nodes", "_run_kernel"):
        setattr(be, name, timed(f"backend.{name}", getattr(be, name)))
    for node in be.nodes:
        node.packet = timed("", node.packet, lambda now, ptype, *a, **kw:
                            f"node.packet {PacketType(ptype).name}")
        for name in ("timecode", "run", "run_torque", "push", "pull"):
            setattr(node, name, timed(f"node.{name}", getattr(node, name)))
    for name in ("poll", "on_packet", "on_node_events", "next_due", "quiet_end"):
        setattr(loop.master, name, timed(f"master.{name}", getattr(loop.master, name)))
    for name in ("step", "encoder_changes"):
        setattr(loop.plant, name, timed(f"plant.{name}", getattr(loop.plant, name)))

    class Kernel:                   # the kernel's entry points called from Python
        def __init__(self, k):
            self._k = k

        def __getattr__(self, name):
            f = getattr(self._k, name)
            return timed(f"kernel.{name}", f) if callable(f) else f

    be._kern = Kernel(be._kern)
    marks = {}

    def start():
        marks["t0"] = clock()
        own.clear()
        count.clear()

    _at_period_0(loop, start)
    loop.run(cycles)
    total = clock() - marks["t0"]
    periods = cycles / (CLOCK_HZ / 1000)
    print(f"{robot_name} ({_JOINTS}): {cycles:,} cycles, wall µs a period "
          f"{total / periods / 1e3:,.0f} (with the wrappers)")
    print(f"  {'function':32s} {'calls a period':>15s} {'µs a period':>12s} {'µs a call':>10s}")
    for k in sorted(own, key=lambda k: -own[k]):
        print(f"  {k:32s} {count[k] / periods:15.1f} {own[k] / periods / 1e3:12.1f} "
              f"{own[k] / count[k] / 1e3:10.2f}")
    rest = total - sum(own.values())
    print(f"  {'(the loop and the rest)':32s} {'':15s} {rest / periods / 1e3:12.1f}")


def steps(robot_name: str, cycles: int) -> None:
    """``--steps``: one window of the compiled path, its time by the period's plant steps."""
    from mrm_cosim.protocol.packet import PacketType

    robot = load_robot(robot_name)
    run(robot_name, "numba", 100_000)
    loop = _loop(robot, "numba")
    be = loop.backend
    per = round(loop.master.timing.period_cycles / loop.step_cycles)     # steps a period
    clock = time.perf_counter_ns
    spent, runs, seen, last = {}, {}, {}, [None, 0]

    def timed(fast):                # a fast run's start: the time since the last one, given
        def timed_fast(plant, pk, rec, s, i, stop, cycle, lim):     # to where that one began
            t = clock()
            if last[0] is not None:
                spent[last[1]] = spent.get(last[1], 0) + t - last[0]
            last[0], last[1] = t, i % per
            runs[i % per] = runs.get(i % per, 0) + 1
            return fast(plant, pk, rec, s, i, stop, cycle, lim)
        return timed_fast

    def note(what):
        k = last[1]
        seen.setdefault(k, {})
        seen[k][what] = seen[k].get(what, 0) + 1

    be._fast, be._fast_compliant = timed(be._fast), timed(be._fast_compliant)   # (the plant's)
    for node in be.nodes:
        def packet(now, ptype, *a, _f=node.packet, **kw):
            note(f"{PacketType(ptype).name} in")
            return _f(now, ptype, *a, **kw)

        def timecode(now, *a, _f=node.timecode, **kw):
            note("time-code in")
            return _f(now, *a, **kw)

        node.packet, node.timecode = packet, timecode
    on_packet = loop.master.on_packet

    def master_packet(c, src, ptype, payload):
        note(f"{PacketType(ptype).name} reply")
        return on_packet(c, src, ptype, payload)

    loop.master.on_packet = master_packet
    def start():
        for d in (spent, runs, seen):
            d.clear()
        last[0] = None

    _at_period_0(loop, start)
    loop.run(cycles)
    if last[0] is not None:
        spent[last[1]] = spent.get(last[1], 0) + clock() - last[0]
    total = sum(spent.values())
    periods = cycles / (CLOCK_HZ / 1000)
    print(f"{robot_name} ({_JOINTS}): {cycles:,} cycles, wall µs a period "
          f"{total / periods / 1e3:,.0f} from the first fast run; by the step of the period "
          "where a run began")
    print(f"  {'step':>4s} {'runs a period':>14s} {'µs a period':>12s} {'share':>6s}  what crossed "
          "in it (a period)")
    for k in sorted(spent):
        what = ", ".join(f"{n / periods:g} {w}" for w, n in sorted(seen.get(k, {}).items()))
        print(f"  {k:4d} {runs.get(k, 0) / periods:14.1f} {spent[k] / periods / 1e3:12.1f} "
              f"{spent[k] / total:6.1%}  {what}")


def pin_ab(robots, cycles: int, rounds: int) -> None:
    """``--pin``: the kernel with pinocchio from compiled code and without, windows ABBA."""
    from mrm_cosim.cosim import pin_shim

    dyn = pin_shim.load()
    if dyn is None:
        raise SystemExit("pinocchio from compiled code is unavailable here (see the warning)")
    periods = cycles / (CLOCK_HZ / 1000)
    for robot in robots:
        run(robot, "numba", 100_000)
        rtf, fast, hashes = {0: [], 1: []}, {0: [], 1: []}, {0: set(), 1: set()}
        for r in range(rounds):
            for use in ((1, 0) if r % 2 == 0 else (0, 1)):
                pin_shim._loaded = dyn if use else False
                x, h, _, _ = run(robot, "numba", cycles)
                rtf[use].append(x)
                hashes[use].add(h)
                fast[use].append(run(robot, "numba", cycles, breakdown=True)[2]["fast steps"])
        pin_shim._loaded = dyn
        same = "same" if len(hashes[0] | hashes[1]) == 1 else "DIFFERENT"
        print(f"{robot} ({_JOINTS}): {cycles:,} cycles, CPU RTF best / median of {rounds}, "
              "fast steps CPU µs a period (median)")
        for use, name in ((0, "pin from Python"), (1, "pin from the kernel")):
            print(f"  {name:20s} {min(rtf[use]):6.3f} / {statistics.median(rtf[use]):6.3f}   "
                  f"{statistics.median(fast[use]) / periods * 1e6:6.0f}")
        print(f"  ratio of medians x{statistics.median(rtf[0]) / statistics.median(rtf[1]):.3f}"
              f", trace hashes {same} ({min(hashes[1])[:16]})")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", action="append", help="robot(s) (default mrm3 and mrm6)")
    ap.add_argument("--cycles", type=int, default=2_500_000, help="window after period 0")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--no-breakdown", action="store_true")
    ap.add_argument("--master", action="store_true", help="time the master alone")
    ap.add_argument("--against", metavar="PYTHON",
                    help="side by side with the tree of this interpreter (its venv's python)")
    ap.add_argument("--joints", choices=("rigid", "compliant"), default="rigid",
                    help="the plant's joints (default rigid, as mrm bench; compliant: Table "
                    "2's plant, two-inertia joints with the encoder on the motor)")
    ap.add_argument("--pin", action="store_true",
                    help="pinocchio from compiled code against pin from Python, side by side")
    ap.add_argument("--calls", action="store_true",
                    help="one window, its functions timed one by one (the compiled path)")
    ap.add_argument("--steps", action="store_true",
                    help="one window, its time by the period's plant steps (the compiled path)")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    global _JOINTS
    _JOINTS = args.joints
    if args.joints != "rigid" and args.master:
        ap.error("--joints compliant times the loop only (not with --master)")
    if args.worker:
        return _worker()
    robots = args.robot or ["mrm3", "mrm6"]
    periods = args.cycles / (CLOCK_HZ / 1000)
    if args.against:
        against(args.against, robots, args.cycles, max(args.rounds, 2))
        return 0
    if args.pin:
        pin_ab(robots, args.cycles, max(args.rounds, 2))
        return 0
    if args.calls:
        for robot in robots:
            calls(robot, args.cycles)
        return 0
    if args.steps:
        for robot in robots:
            steps(robot, args.cycles)
        return 0
    if args.master:
        for robot in robots:
            times, same = master_alone(robot, args.cycles, max(args.rounds, 3))
            print(f"{robot}: the master alone, CPU µs per period: best "
                  f"{times[0] / periods * 1e6:.1f}, median "
                  f"{statistics.median(times) / periods * 1e6:.1f} "
                  f"({len(times)} replays; replies {'equal' if same else 'DIFFERENT'})")
        return 0
    for robot in robots:                        # compile / load the kernel, warm caches
        run(robot, "numba", 100_000)
        run(robot, "python", 100_000)
    for robot in robots:
        rtf = {"numba": [], "python": []}
        hashes = {}
        for _ in range(args.rounds):
            for kernel in ("numba", "python"):
                r, h, _, v = run(robot, kernel, args.cycles)
                rtf[kernel].append(r)
                hashes[kernel] = h
                if v:
                    print(f"  ({kernel}: violations {v[:2]})")
        same = "same" if hashes["numba"] == hashes["python"] else "DIFFERENT"
        print(f"{robot}: {args.cycles:,} cycles ({periods:.0f} periods), CPU RTF best / median "
              f"of {args.rounds}")
        for kernel in ("numba", "python"):
            print(f"  {kernel:7s} {min(rtf[kernel]):6.2f} / {statistics.median(rtf[kernel]):6.2f}")
        print(f"  python / numba: x{min(rtf['python']) / min(rtf['numba']):.2f} (best), "
              f"trace hashes {same} ({hashes['numba'][:16]})")
        if not args.no_breakdown:
            print("  CPU µs per simulated 1 ms period:")
            parts = {k: run(robot, k, args.cycles, breakdown=True)[2]
                     for k in ("numba", "python")}
            for name in parts["numba"]:
                print(f"    {name:20s} numba {parts['numba'][name] / periods * 1e6:8.0f}   "
                      f"python {parts['python'][name] / periods * 1e6:8.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
