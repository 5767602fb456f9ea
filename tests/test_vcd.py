# amaranth: UnusedElaboratable=no
"""Waveforms of a chosen window and signal set, from the pysim and compiled backends (issue 6)."""

import numpy as np
import pytest
from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out
from vcd.reader import TokenKind, tokenize

from mrm_cosim.cosim.backends import CompiledBackend, PysimBackend, VcdWindow, drive
from mrm_cosim.errors import InputError

PERIOD_PS = 20_000


class Counter(wiring.Component):
    """Counts the cycles in which ``inc`` was high."""

    inc:   In(1)
    count: Out(8)

    def elaborate(self, platform):
        m = Module()
        with m.If(self.inc):
            m.d.sync += self.count.eq(self.count + 1)
        return m


class Demo(wiring.Component):
    """Two levels of hierarchy, a registered and a combinational output, a signed port."""

    inc:   In(1)
    total: Out(8)
    odd:   Out(1)
    neg:   Out(signed(6))

    def elaborate(self, platform):
        m = Module()
        m.submodules.counter = counter = Counter()
        seen = Signal(4)                    # internal register of the top
        m.d.sync += seen.eq(seen + self.inc)
        m.d.comb += [
            counter.inc.eq(self.inc),
            self.total.eq(counter.count),
            self.odd.eq(counter.count[0] ^ seen[0]),
            self.neg.eq(-counter.count[:5]),
        ]
        return m


N = 120
INC = (np.random.default_rng(6).random(N) < 0.6).astype(np.int64)


def _vcd(path):
    """{dotted name: [(time_ps, value), ...]}, read with pyvcd's tokenizer."""
    scope, ids, changes, t = [], {}, {}, None
    with open(path, "rb") as f:
        for tok in tokenize(f):
            if tok.kind is TokenKind.SCOPE:
                scope.append(tok.scope.ident)
            elif tok.kind is TokenKind.UPSCOPE:
                scope.pop()
            elif tok.kind is TokenKind.VAR:
                name = ".".join([*scope[1:], tok.var.reference])
                ids.setdefault(tok.var.id_code, []).append(name)
                changes[name] = []
            elif tok.kind is TokenKind.CHANGE_TIME:
                t = tok.time_change
            elif tok.kind in (TokenKind.CHANGE_SCALAR, TokenKind.CHANGE_VECTOR):
                v = tok.data.value if tok.kind is TokenKind.CHANGE_VECTOR else tok.data.value
                v = int(v, 2) if isinstance(v, str) else int(v)
                for name in ids[tok.data.id_code]:
                    changes[name].append((t, v))
    return changes


def _values(changes, start, stop):
    """Per-cycle values from value changes, cycles ``start..stop-1``."""
    out, it, cur = [], iter(changes), None
    pending = next(it, None)
    for c in range(start, stop):
        while pending is not None and pending[0] <= c * PERIOD_PS:
            cur = pending[1]
            pending = next(it, None)
        out.append(cur)
    return out


def _expected_total():
    return np.concatenate([[0], np.cumsum(INC)[:-1]]) & 0xFF


def _run_compiled(window):
    be = CompiledBackend(Demo, "vcd-demo", vcd=window)
    parts = []
    for lo in range(0, N, 25):           # chunks that straddle both ends of the window
        hi = min(N, lo + 25)
        parts.append(drive(be.run(hi - lo, {"inc": INC[lo:hi]}, ["total"]))["total"])
    return np.concatenate(parts)


def _run_pysim(window):
    be = PysimBackend(Demo(), vcd=window)
    sim = be.simulator()
    box = {}

    async def bench(ctx):
        be.bind(ctx)
        parts = []
        for lo in range(0, N, 25):
            hi = min(N, lo + 25)
            parts.append((await be.run(hi - lo, {"inc": INC[lo:hi]}, ["total"]))["total"])
        box["total"] = np.concatenate(parts)

    sim.add_testbench(bench)
    sim.run()
    return box["total"]


@pytest.fixture(scope="module")
def windows(tmp_path_factory):
    out = tmp_path_factory.mktemp("vcd")
    w = {name: VcdWindow(30, 70, out / f"{name}.vcd", "total,counter.*,neg")
         for name in ("compiled", "pysim")}
    totals = {"compiled": _run_compiled(w["compiled"]), "pysim": _run_pysim(w["pysim"])}
    return w, totals


@pytest.mark.parametrize("backend", ["compiled", "pysim"])
def test_window_holds_only_the_selected_signals_and_cycles(windows, backend):
    w, totals = windows
    np.testing.assert_array_equal(totals[backend], _expected_total())
    changes = _vcd(w[backend].path)
    assert set(changes) == {"total", "neg", "counter.inc", "counter.count"}
    times = [t for ch in changes.values() for t, _ in ch]
    assert min(times) == 30 * PERIOD_PS and max(times) <= 69 * PERIOD_PS
    assert [p.name for p in w[backend].path.parent.iterdir()
            if p.name.startswith(".")] == [], "no temporary file left behind"


@pytest.mark.parametrize("backend", ["compiled", "pysim"])
def test_window_values_are_the_design_values_cycle_by_cycle(windows, backend):
    w, _ = windows
    changes = _vcd(w[backend].path)
    total = _expected_total()[30:70]
    assert _values(changes["total"], 30, 70) == list(total)
    assert _values(changes["counter.count"], 30, 70) == list(total)
    assert _values(changes["counter.inc"], 30, 70) == list(INC[30:70])
    assert _values(changes["neg"], 30, 70) == list((-(total & 31)) & 63)   # two's complement


def test_pysim_and_compiled_windows_agree(windows):
    w, _ = windows
    a, b = _vcd(w["compiled"].path), _vcd(w["pysim"].path)
    for name in a:
        assert _values(a[name], 30, 70) == _values(b[name], 30, 70), name


@pytest.mark.parametrize("spec, start, stop", [
    ("0:1e-6", 0, 50),
    ("1ms:1.0002ms", 50_000, 50_010),
    ("20us:30us", 1_000, 1_500),
    ("100ns:101ns", 5, 6),               # at least one cycle
])
def test_window_spec_in_seconds_or_units(spec, start, stop, tmp_path):
    w = VcdWindow.parse(spec, tmp_path / "x.vcd", "node1.*")
    assert (w.start, w.stop) == (start, stop)
    assert w.matches("node1.link.state") and not w.matches("node2.link.state")


def test_window_offset_moves_both_ends(tmp_path):
    w = VcdWindow.parse("0:2us", tmp_path / "x.vcd", offset=1e-3)
    assert (w.start, w.stop) == (50_000, 50_100)
    assert w.matches("anything.at.all")


@pytest.mark.parametrize("spec", ["", "5", "1:2:3", "2ms:1ms", "-1:2", "a:b", "1ms:1ms",
                                  "1h:2h"])
def test_bad_window_names_the_field(spec, tmp_path):
    with pytest.raises(InputError) as err:
        VcdWindow.parse(spec, tmp_path / "x.vcd")
    assert err.value.field == "vcd"


def test_empty_signal_pattern_names_the_field(tmp_path):
    with pytest.raises(InputError) as err:
        VcdWindow(0, 10, tmp_path / "x.vcd", " , ")
    assert err.value.field == "signals"


def test_pysim_vcd_needs_the_backends_simulator(tmp_path):
    be = PysimBackend(Demo(), vcd=VcdWindow(0, 5, tmp_path / "x.vcd"))
    with pytest.raises(RuntimeError, match="simulator"):
        be.bind(object())


@pytest.mark.parametrize("argv, field", [
    (["--backend", "model", "--vcd", "0:1ms"], "--vcd"),
    (["--backend", "compiled", "--vcd", "5:3"], "--vcd"),
    (["--backend", "pysim", "--vcd", "1ms:2ms", "--signals", "torque*,,"], "--signals"),
    (["--backend", "compiled", "--signals", "torque*"], "--signals"),
])
def test_track_refuses_bad_waveform_requests_before_running(tmp_path, capsys, argv, field):
    from mrm_cosim.mrm.cli import main

    out = tmp_path / "out"
    assert main(["run", "track", "--quiet", "--out", str(out), *argv]) == 2
    assert field in capsys.readouterr().err
    assert not out.exists()


class TwoClocks(wiring.Component):
    """A counter on the master's clock (``sync``) and one on a node's (``n1``)."""

    inc:    In(8)
    total:  Out(8)
    count1: Out(8)

    def __init__(self):
        super().__init__()
        self.n1 = ClockDomain("n1")

    def elaborate(self, platform):
        m = Module()
        m.domains += self.n1
        m.d.sync += self.total.eq(self.total + self.inc)
        m.d.n1 += self.count1.eq(self.count1 + 1)
        return m


def _native_fst() -> bool:
    from mrm_cosim.cosim.compiled import fst_headers_missing

    return not fst_headers_missing()


@pytest.mark.parametrize("fmt", ["vcd", pytest.param("fst", marks=pytest.mark.skipif(
    not _native_fst(), reason="Verilator's FST writer needs lz4.h (Debian: liblz4-dev)"))])
def test_a_clock_per_domain_traces_every_edge_at_its_time(tmp_path, fmt):
    """A per-node-clock model's waveform (docs/clocks.md): each domain's signals change at
    that domain's rising edges, stamped in femtoseconds (``$timescale 1fs``), a 1,000 ppm
    faster node drifting against the master; the domains' clock ports are not kept."""
    from amaranth.back import verilog

    from mrm_cosim.cosim.clocks import ClockPlan
    from mrm_cosim.cosim.compiled import CompiledModel, filter_vcd

    d = TwoClocks()
    # (named ports, directions from the drivers: no name from amaranth's private hdl._ir)
    ports = {"inc": (d.inc, None), "total": (d.total, None), "count1": (d.count1, None),
             "n1_clk": (d.n1.clk, None)}
    text = verilog.convert(d, name="two_clocks", emit_src=False, ports=ports)
    model = CompiledModel(d, "two_clocks", verilog_text=text, trace=fmt)
    plan = ClockPlan.from_ppm([0, 1000], [0.25, 0.5], 6)
    model.setup_clocks(plan, [], [("total", 0, False), ("count1", 1, False)])
    model.run_clocked(5, {"inc": 1}, ["total"])
    model.trace_open(tmp_path / f"raw.{fmt}")
    out = model.run_clocked(600, {"inc": 1}, ["total", "count1"])
    model.trace_close()
    if fmt == "vcd":
        names = filter_vcd(tmp_path / "raw.vcd", tmp_path / "two.vcd", "two_clocks",
                           lambda n: True, fs=True)
        text = (tmp_path / "two.vcd").read_text()
        assert "$timescale 1fs $end" in text and "clk" not in text
        ch = _vcd(tmp_path / "two.vcd")
    else:
        from mrm_cosim.cosim.waves import filter_fst, read_fst

        names = filter_fst(tmp_path / "raw.fst", tmp_path / "two.fst", "two_clocks",
                           lambda n: True, fs=True)
        ch = read_fst(tmp_path / "two.fst")
        assert not any("clk" in n for n in ch)
    assert sorted(names) == ["count1", "inc", "total"]
    (p0, p1), (f0, f1) = plan.periods, plan.phases
    # total: +1 at every master edge, count1: +1 at every node edge, each at its edge's time
    for name, phase, period in (("total", f0, p0), ("count1", f1, p1)):
        times = [t for t, _ in ch[name][1:]]
        assert len(times) >= 599, name
        assert all((t - phase) % period == 0 for t in times), name
        assert set(np.diff(times)) == {period}, name
        assert set(np.diff([v for _, v in ch[name]]) % 256) == {1}, name      # (8 bits)
    # a 1,000 ppm faster node fits 600.6 cycles into 600 master cycles
    assert (out["count1"][-1] - out["count1"][0]) % 256 == 600 % 256
    # the simultaneous edges (node and master at one instant, once here) dumped once, after
    # both: total changed there too
    both = set(t for t, _ in ch["total"][1:]) & set(t for t, _ in ch["count1"][1:])
    assert len(both) >= 1
