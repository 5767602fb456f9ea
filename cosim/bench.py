"""``mrm bench``: simulated cycles per second and real-time factor of each backend, measured
side by side in one process on the same closed-loop window (3-module VDC loop by default)."""

from __future__ import annotations


from mrm_cosim.master.uploads import Gains, node_uploads, pid_gains
from mrm_cosim.cosim.preview import paper_test_profile
from mrm_cosim.cosim.track import check_robot_fits, run_loop
from mrm_cosim.master.cycle import Master, MasterTiming
from mrm_cosim.models.plant import Plant
from mrm_cosim.models.robot import load_robot
from mrm_cosim.units import CLOCK_HZ

__all__ = ["bench_backend", "bench_master_and_plant", "WINDOWS"]

#: Closed-loop cycles measured per backend (pysim is ~400× slower than compiled).
WINDOWS = {"compiled": 250_000, "pysim": 2_000, "model": 2_500_000}
#: Cycle of period 0: on the nodes' timer grid after the uploads (as ``mrm run track``) for the
#: model and compiled backends; pysim starts early (off the grid: the nodes resynchronise to
#: the first time-code) because its start-up alone would take minutes.
STARTS = {"compiled": 50_000, "pysim": 2_000, "model": 50_000}


def bench_master_and_plant(robot):
    """The master and plant every speed measurement runs (``mrm bench``, the benchmarks'
    model and compiled loops): ``robot``'s VDC master on the paper's quintic test, its 1 kHz
    PID gains for 5 Hz, and plant seed 0 resting at home."""
    from mrm_cosim.cosim.track import _trajectory

    master = Master(robot, "vdc", _trajectory(robot, paper_test_profile(robot)),
                    robot.counts_per_rev, MasterTiming(), pid=pid_gains(robot, 5.0))
    plant = Plant(robot, seed=0)
    plant.reset(robot.home)
    return master, plant


def bench_backend(backend: str, robot="mrm3", cycles: int | None = None) -> dict:
    """Run ``cycles`` of the VDC loop after the start-up; time only the loop. Returns the
    wall-clock real-time factor ``rtf`` and the CPU one ``cpu_rtf`` (this process's CPU time
    over the same window: on a shared machine the steadier of the two).

    The loop times its own window, from period 0 to its end
    (:attr:`cosim.closed_loop.LoopResult.window_wall_s`): the start-up (link, uploads:
    ``STARTS[backend]`` cycles) and, for ``compiled``, the one-off build are not in it. (It
    used to be a run minus a run of zero length, which a busy machine could make negative.)
    """
    robot = load_robot(robot)
    check_robot_fits(robot, "robot")
    cycles = WINDOWS[backend] if cycles is None else cycles

    def once(n: int):
        master, plant = bench_master_and_plant(robot)
        result, be = run_loop(robot, backend, master, plant, STARTS[backend],
                              node_uploads(robot, "vdc", Gains()), n, keep=True)
        return result.window_wall_s, result.window_cpu_s, getattr(be, "threads", 1)

    once(0)                              # build (compiled) and warm caches
    wall, cpu, threads = once(cycles)
    return {"robot": robot.name, "cycles": cycles, "wall_s": wall, "cpu_s": cpu,
            "cycles_per_s": cycles / wall, "rtf": wall / (cycles / CLOCK_HZ),
            "cpu_rtf": cpu / (cycles / CLOCK_HZ), "threads": threads}
