# amaranth: UnusedElaboratable=no
"""FST waveforms and GTKWave save files (issue 23, item 4): the FST of a window reads back
(pylibfst) with the VCD's signals and values, on pysim (converted through the library) and
compiled (Verilator's own FST writer); a .gtkw beside each names only signals the waveform has."""

import re
import sys

import numpy as np
import pytest

from mrm_cosim.cosim.backends import CompiledBackend, PysimBackend, VcdWindow, drive
from mrm_cosim.cosim.compiled import fst_headers_missing
from mrm_cosim.cosim.waves import key_signals, read_fst, write_gtkw
from tests.test_vcd import INC, N, Demo, _expected_total, _values, _vcd

SIGNALS = "total,counter.*,neg"
NATIVE_FST = not fst_headers_missing()


def _compiled(window):
    be = CompiledBackend(Demo, "vcd-demo", vcd=window)
    for lo in range(0, N, 25):
        drive(be.run(min(N, lo + 25) - lo, {"inc": INC[lo:min(N, lo + 25)]}, ["total"]))


def _pysim(window):
    be = PysimBackend(Demo(), vcd=window)
    sim = be.simulator()

    async def bench(ctx):
        be.bind(ctx)
        for lo in range(0, N, 25):
            await be.run(min(N, lo + 25) - lo, {"inc": INC[lo:min(N, lo + 25)]}, ["total"])

    sim.add_testbench(bench)
    sim.run()


@pytest.fixture(scope="module")
def waves(tmp_path_factory):
    out = tmp_path_factory.mktemp("waves")
    runs = {"pysim": _pysim, **({"compiled": _compiled} if NATIVE_FST else {})}
    files = {}
    for backend, run in runs.items():
        for fmt in ("vcd", "fst"):
            files[backend, fmt] = out / backend / fmt / f"waves.{fmt}"
            run(VcdWindow(30, 70, files[backend, fmt], SIGNALS))
    return files


BACKENDS = ["pysim", pytest.param("compiled", marks=pytest.mark.skipif(
    not NATIVE_FST, reason="Verilator's FST writer needs lz4.h (Debian: liblz4-dev)"))]


@pytest.mark.parametrize("backend", BACKENDS)
def test_fst_reads_back_with_the_vcds_signals_and_values(waves, backend):
    fst, vcd = read_fst(waves[backend, "fst"]), _vcd(waves[backend, "vcd"])
    assert set(fst) == set(vcd) == {"total", "neg", "counter.inc", "counter.count"}
    for name in vcd:
        assert _values(fst[name], 30, 70) == _values(vcd[name], 30, 70), name
    assert _values(fst["total"], 30, 70) == list(_expected_total()[30:70])
    times = [t for ch in fst.values() for t, _ in ch]
    assert min(times) == 30 * 20_000 and max(times) <= 69 * 20_000     # ps, the window only
    assert not [p for p in waves[backend, "fst"].parent.iterdir() if p.name.startswith(".")]


@pytest.mark.skipif(not NATIVE_FST, reason="Verilator's FST writer needs lz4.h")
def test_compiled_fst_is_verilators_and_equals_pysims(waves):
    assert waves["compiled", "fst"].read_bytes()[:1] != b"$"          # binary, not a VCD
    a, b = read_fst(waves["compiled", "fst"]), read_fst(waves["pysim", "fst"])
    for name in a:
        assert _values(a[name], 30, 70) == _values(b[name], 30, 70), name


@pytest.mark.parametrize("fmt", ["vcd", "fst"])
@pytest.mark.parametrize("backend", BACKENDS)
def test_a_gtkw_lies_beside_each_waveform(waves, backend, fmt):
    gtkw = waves[backend, fmt].with_suffix(".gtkw").read_text()
    assert f'[dumpfile] "waves.{fmt}"' in gtkw


def _gtkw_traces(text):
    """(group, trace name) of a .gtkw: groups open with '-NAME' after a '@...' flag line."""
    out, group = [], None
    for line in text.splitlines():
        if line.startswith("-"):
            group = line[1:] or None
        elif line and not line.startswith(("[", "@", "*")):
            out.append((group, re.sub(r"^\+\{[^}]*\} ", "", line)))    # "+{alias} name"
    return out


def test_gtkw_of_the_whole_system_groups_its_key_signals(tmp_path):
    """pysim, the three-node system, 12 cycles of every signal: each node's link state, D/S
    lines, time-code, events, torque and count in its group, each name one the FST has."""
    from mrm_cosim.cosim.track import loop_system
    from mrm_cosim.models.robot import load_robot

    path = tmp_path / "waves.fst"
    be = PysimBackend(loop_system(load_robot("mrm3")), vcd=VcdWindow(0, 12, path))
    sim = be.simulator()

    async def bench(ctx):
        be.bind(ctx)
        await be.run(12, {}, [])

    sim.add_testbench(bench)
    sim.run()
    have = {"system." + n for n in read_fst(path)}
    traces = _gtkw_traces(path.with_suffix(".gtkw").read_text())
    assert traces and all(name in have for _, name in traces), \
        [n for _, n in traces if n not in have]
    groups = {g for g, _ in traces}
    assert groups == {"master port", "node1", "node2", "node3"}
    node2 = [n for g, n in traces if g == "node2"]
    for want in ("node2.link.up_codec.state", "node2.link.up_codec.d_in",
                 "node2.link.up_codec.s_out", "node2.link.tc_time", "events2", "torque2",
                 "count2"):
        assert "system." + want in node2, want


def test_gtkw_names_no_signal_the_waveform_lacks(tmp_path):
    names = ["node1.link.up_codec.fsm.state", "torque1", "node1.core.torque", "cycle"]
    assert key_signals(names) == [("node1", [("link state", "node1.link.up_codec.fsm.state"),
                                             ("torque", "torque1")])]
    text = write_gtkw(tmp_path / "w.vcd", names).read_text()
    assert [n for _, n in _gtkw_traces(text)] == ["system.node1.link.up_codec.fsm.state",
                                                  "system.torque1"]
    assert key_signals(["total", "counter.count"]) == []


def test_fst_without_pylibfst_is_refused_naming_the_flag(tmp_path, capsys, monkeypatch):
    from mrm_cosim.mrm.cli import main

    monkeypatch.setitem(sys.modules, "pylibfst", None)        # as if the extra were missing
    out = tmp_path / "out"
    assert main(["run", "track", "--backend", "pysim", "--fst", "0:1us", "--out",
                 str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--fst" in err[0] and "mrm-cosim[fst]" in err[0]
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_the_vcd_and_fst_windows_hold_the_same_cycles(waves):
    """The FST adds no cycle before or after the VCD's window."""
    fst, vcd = read_fst(waves["pysim", "fst"]), _vcd(waves["pysim", "vcd"])
    assert np.array_equal([t for t, _ in fst["total"]], [t for t, _ in vcd["total"]])
