"""Where independent runs execute: one seam for sweeps and for ``mrm run table2``.

A run ("point") is ``fn(item, report)``: a picklable top-level function (or a
:func:`functools.partial` of one) and a picklable item; ``report(*message)`` sends a progress
message to the caller (dropped where an executor cannot carry it). Every executor gives back,
for each item, as runs finish::

    (index, "ok", value)            the function's return value
    (index, "input", (field, msg))  it raised InputError (bad input, named)
    (index, "error", text)          it raised anything else (the traceback), or its worker died

so a failed point never stops the others. Executors:

* :class:`SerialExecutor` — in this process, one after the other (``workers = 1``);
* :class:`LocalExecutor` — the standard library's :class:`~concurrent.futures.
  ProcessPoolExecutor` on this machine's cores (forked workers; each leads a process group of
  its own, ignores Ctrl-C and dies with its parent, and the executor kills the groups when it
  closes, so nothing a run started — Verilator, a compiled model — outlives it);
* :class:`DaskExecutor` — a Dask distributed cluster (``tcp://HOST:PORT``) or a
  ``LocalCluster`` (``local-dask``); optional (``pip install 'mrm-cosim[sweep]'``).

Results do not depend on the executor: a run is a pure function of its item (tests run the
same points on all three and compare trace hashes).
"""

from __future__ import annotations

import collections
import os
import signal
import time
import traceback
import urllib.parse
from collections.abc import Callable, Iterator

from mrm_cosim.errors import InputError

__all__ = ["Executor", "SerialExecutor", "LocalExecutor", "DaskExecutor", "make_executor",
           "check_executor_args", "default_workers"]


def default_workers() -> int:
    """The cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:                  # not Linux
        return max(1, os.cpu_count() or 1)


def _call(fn, index: int, item, report) -> tuple:
    """Run one point and turn its outcome into a message (never raises but for Ctrl-C)."""
    try:
        return index, "ok", fn(item, report)
    except InputError as exc:
        return index, "input", (exc.field, exc.message)
    except KeyboardInterrupt:
        raise
    except BaseException:
        return index, "error", traceback.format_exc()


class Executor:
    """Runs points; a context manager (``close`` on exit). See the module docstring."""

    name = "executor"
    workers = 1

    def run(self, fn: Callable, items: list, on_message: Callable | None = None
            ) -> Iterator[tuple[int, str, object]]:
        raise NotImplementedError

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class SerialExecutor(Executor):
    """In this process, one point after the other."""

    name = "serial"

    def run(self, fn, items, on_message=None):
        def report(*message):
            if on_message is not None:
                on_message(*message)

        for index, item in enumerate(items):
            yield _call(fn, index, item, report)


# --- local processes ---------------------------------------------------------------------
_REPORTS = None                 # the worker's queue back to its parent (set by _worker_init)


def _worker_init(parent: int, reports, cores: int = 1) -> None:
    global _REPORTS
    _REPORTS = reports
    _worker_setup(parent)
    _share_threads(cores)


def _share_threads(cores: int) -> None:
    """A worker's share of the machine: the compiled backend's threads
    (``$MRM_COMPILED_THREADS``, :func:`cosim.track.compiled_threads`) lowered to ``cores``
    (the cores over the workers running side by side, at least 1); more threads than cores
    would make the threads wait for each other's turn on a core every cycle."""
    from mrm_cosim.cosim.track import THREADS_ENV

    raw = os.environ.get(THREADS_ENV, "")
    if raw.isdigit() and int(raw) > cores:
        os.environ[THREADS_ENV] = str(max(1, cores))


def _report(*message) -> None:
    if _REPORTS is not None:
        _REPORTS.put(message)


def _call_in_worker(fn, index, item):
    return _call(fn, index, item, _report)


class LocalExecutor(Executor):
    """A :class:`~concurrent.futures.ProcessPoolExecutor` of ``workers`` forked processes."""

    name = "local"

    def __init__(self, workers: int | None = None):
        import multiprocessing as mp

        self.workers = default_workers() if workers is None else int(workers)
        if self.workers < 1:
            raise InputError("workers", f"must be a whole number ≥ 1, not {workers!r}")
        self._ctx = mp.get_context("fork")
        self._reports = None
        self._pool = None
        self._pids: set[int] = set()

    def _new_pool(self):
        from concurrent.futures import ProcessPoolExecutor

        # A SimpleQueue's put writes into the pipe before it returns, so a run's last progress
        # message is there before its result is (a Queue's feeder thread could lag behind).
        # A fresh one per pool: a worker killed inside a put would leave the old one locked.
        if self._reports is not None:
            self._reports.close()
        self._reports = self._ctx.SimpleQueue()
        return ProcessPoolExecutor(self.workers, mp_context=self._ctx, initializer=_worker_init,
                                   initargs=(os.getpid(), self._reports,
                                             max(1, default_workers() // self.workers)))

    def _drain(self, on_message) -> None:
        while self._reports is not None and not self._reports.empty():
            message = self._reports.get()
            if on_message is not None:
                on_message(*message)

    def run(self, fn, items, on_message=None):
        from concurrent.futures import FIRST_COMPLETED, wait
        from concurrent.futures.process import BrokenProcessPool

        todo = list(range(len(items)))
        running = {}
        while todo or running:
            if self._pool is None:
                self._pool = self._new_pool()
            while todo and len(running) < 2 * self.workers:
                i = todo.pop(0)
                running[self._pool.submit(_call_in_worker, fn, i, items[i])] = i
            self._pids |= set(getattr(self._pool, "_processes", {}) or {})
            done, _ = wait(list(running), timeout=0.2, return_when=FIRST_COMPLETED)
            self._drain(on_message)
            broken = False
            for fut in done:
                i = running.pop(fut)
                try:
                    yield fut.result()
                except BrokenProcessPool:
                    broken = True
                    yield i, "error", ("its worker process died (killed, out of memory or a "
                                       "crash in compiled code)")
            if broken:                      # every run in flight went with the pool
                for fut, i in list(running.items()):
                    running.pop(fut)
                    yield i, "error", "its worker process died with another run's"
                self._kill_pool()
        self._drain(on_message)

    def _kill_pool(self) -> None:
        pool, self._pool = self._pool, None
        if pool is None:
            return
        self._pids |= set(getattr(pool, "_processes", {}) or {})
        for pid in self._pids:
            _kill_group(pid)
        pool.shutdown(wait=True, cancel_futures=True)
        self._pids.clear()

    def close(self) -> None:
        self._kill_pool()
        if self._reports is not None:
            self._reports.close()
            self._reports = None


# --- Dask --------------------------------------------------------------------------------
def _host(address: str) -> str:
    return urllib.parse.urlsplit(address).hostname or address


def _call_sharing(fn, index, item, hosts: dict, threads: str | None = None) -> tuple:
    """A point as a Dask task: the compiled backend's threads the client asked for
    (``threads``, its ``$MRM_COMPILED_THREADS``; else the worker's own) lowered to the
    worker's share of its machine (its cores over the workers on its host, as
    :func:`_worker_init` gives a local worker), then :func:`_call`; the worker's environment
    is restored after the point (a worker serves other clients too)."""
    from distributed import get_worker

    from mrm_cosim.cosim.track import compiled_threads_env

    with compiled_threads_env(threads):
        _share_threads(default_workers() // max(1, hosts.get(_host(get_worker().address), 1)))
        return _call(fn, index, item, None)


class DaskExecutor(Executor):
    """Points as Dask tasks: on the cluster whose scheduler listens at ``address``
    (``tcp://HOST:8786``) or on a ``LocalCluster`` of ``workers`` single-threaded processes
    (``address = "local-dask"``). Progress messages are not carried (Dask's dashboard shows
    the tasks)."""

    name = "dask"

    def __init__(self, address: str, workers: int | None = None):
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise InputError("scheduler", "needs Dask: pip install 'mrm-cosim[sweep]'") from None
        self.address = address
        self._cluster = None
        try:
            if address == "local-dask":
                self.workers = default_workers() if workers is None else int(workers)
                self._cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1,
                                             processes=True, dashboard_address=None)
                self._client = Client(self._cluster)
            else:
                self._client = Client(address, timeout="10s")
                self.workers = max(1, len(self._client.scheduler_info().get("workers", {})))
        except (OSError, TimeoutError) as exc:
            self.close()
            raise InputError("scheduler", f"cannot reach the Dask scheduler at {address!r} "
                             f"({exc})") from None

    def run(self, fn, items, on_message=None):
        from distributed import as_completed

        from mrm_cosim.cosim.track import THREADS_ENV

        hosts = self.workers_per_host()
        threads = os.environ.get(THREADS_ENV)              # the client's, with every point
        futures = [self._client.submit(_call_sharing, fn, i, item, hosts, threads, pure=False,
                                       key=f"mrm-point-{i}-{time.time_ns()}")
                   for i, item in enumerate(items)]
        index = {f.key: i for i, f in enumerate(futures)}
        for fut in as_completed(futures):
            try:
                yield fut.result()
            except Exception:                       # the worker died, or the task was lost
                yield index[fut.key], "error", traceback.format_exc()

    def workers_per_host(self) -> dict:
        """How many of the cluster's workers run on each host (by the host of their
        address): they share its cores."""
        return dict(collections.Counter(_host(address) for address in
                                        self._client.scheduler_info().get("workers", {})))

    def close(self) -> None:
        client = getattr(self, "_client", None)
        if client is not None:
            client.close()
        if self._cluster is not None:
            self._cluster.close()


def check_executor_args(workers: int | None = None, scheduler: str | None = None) -> None:
    """Refuse (naming the argument) what :func:`make_executor` cannot make, before anything
    else happens."""
    if scheduler is not None and not (scheduler == "local-dask"
                                      or scheduler.startswith(("tcp://", "tls://"))):
        raise InputError("scheduler", f"must be 'local-dask' or a Dask scheduler address "
                         f"like tcp://HOST:8786, not {scheduler!r}")
    if workers is not None and (isinstance(workers, bool) or int(workers) < 1):
        raise InputError("workers", f"must be a whole number ≥ 1, not {workers!r}")


def make_executor(workers: int | None = None, scheduler: str | None = None) -> Executor:
    """The executor for ``--workers`` / ``--scheduler``: Dask when a scheduler is named,
    else this machine's processes (``workers`` of them, default all cores; 1: in this
    process)."""
    check_executor_args(workers, scheduler)
    if scheduler is not None:
        return DaskExecutor(scheduler, workers)
    if workers == 1:
        return SerialExecutor()
    return LocalExecutor(workers)


# --- worker hygiene (local processes) -----------------------------------------------------
def _set_group(pid: int) -> None:
    """Make ``pid`` the leader of its own process group."""
    try:
        os.setpgid(pid, pid)
    except OSError:          # done already, or the process has exited
        pass


def _kill_group(pid: int) -> None:
    """SIGKILL the process group ``pid`` leads (the worker and everything it started)."""
    try:
        os.killpg(pid, signal.SIGKILL)
    except OSError:          # gone already
        pass


def _worker_setup(parent: int) -> None:
    """In a forked worker: lead a process group of its own; ignore Ctrl-C (the parent, which
    the terminal's SIGINT reaches, stops the workers); on SIGTERM kill the whole group; die
    with the parent (:func:`_die_with_parent`)."""
    _set_group(0)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, lambda signum, frame: os.killpg(0, signal.SIGKILL))
    _die_with_parent(parent)


def _die_with_parent(parent: int) -> None:
    """Ask the kernel (Linux ``prctl(PR_SET_PDEATHSIG)``) to send this process SIGTERM when
    its parent dies, SIGKILL included; if the parent is already gone, exit now. Elsewhere, a
    thread polls the parent's pid every half second."""
    import ctypes
    import ctypes.util
    import threading

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        armed = libc.prctl(1, int(signal.SIGTERM), 0, 0, 0) == 0    # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        armed = False
    if os.getppid() != parent:
        os.killpg(0, signal.SIGKILL)
    if not armed:
        def watch():
            while os.getppid() == parent:
                time.sleep(0.5)
            os.killpg(0, signal.SIGKILL)

        threading.Thread(target=watch, daemon=True).start()
