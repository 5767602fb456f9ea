# amaranth: UnusedElaboratable=no
"""The compiled backend's engine: a Verilator build equals Amaranth's simulator cycle for cycle."""

import numpy as np
import pytest
from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out
from amaranth.sim import Simulator

from mrm_cosim.cosim.compiled import BuildError, CompiledModel


class MacDemo(wiring.Component):
    """A small design with signed arithmetic, a registered and a combinational output."""

    a:      In(signed(12))
    b:      In(signed(12))
    clear:  In(1)
    acc:    Out(signed(40))
    prod:   Out(signed(24))
    parity: Out(1)
    big:    Out(100)

    def elaborate(self, platform):
        m = Module()
        m.d.comb += [self.prod.eq(self.a * self.b), self.parity.eq(self.acc.xor()),
                     self.big.eq(Cat(self.acc, self.prod, self.a, self.b, C(0b101, 3)))]
        with m.If(self.clear):
            m.d.sync += self.acc.eq(0)
        with m.Else():
            m.d.sync += self.acc.eq(self.acc + self.prod)
        return m


def pysim_trace(n, a, b, clear):
    dut = MacDemo()
    out = {"acc": [], "prod": [], "parity": []}

    async def tb(ctx):
        for i in range(n):
            ctx.set(dut.a, int(a[i]))
            ctx.set(dut.b, int(b[i]))
            ctx.set(dut.clear, int(clear[i]))
            for k in out:
                out[k].append(ctx.get(getattr(dut, k)))
            await ctx.tick()

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(tb)
    sim.run()
    return {k: np.array(v, dtype=np.int64) for k, v in out.items()}


@pytest.fixture(scope="module")
def model():
    return CompiledModel(MacDemo(), "mac_demo")


def test_compiled_equals_pysim_cycle_for_cycle(model):
    rng = np.random.default_rng(0)
    n = 400
    a = rng.integers(-2048, 2048, n)
    b = rng.integers(-2048, 2048, n)
    clear = (rng.random(n) < 0.05).astype(int)
    clear[0] = 1
    ref = pysim_trace(n, a, b, clear)
    got = model.run(n, {"a": a, "b": b, "clear": clear}, ["acc", "prod", "parity"])
    for k in ref:
        np.testing.assert_array_equal(got[k], ref[k], err_msg=k)


def test_chunking_does_not_change_the_trace():
    rng = np.random.default_rng(1)
    n = 300
    a, b = rng.integers(-2048, 2048, n), rng.integers(-2048, 2048, n)
    clear = np.zeros(n, dtype=int)
    clear[0] = 1
    whole = CompiledModel(MacDemo(), "mac_demo").run(n, {"a": a, "b": b, "clear": clear},
                                                      ["acc"])["acc"]
    model = CompiledModel(MacDemo(), "mac_demo")  # cached build, fresh state
    parts = []
    for lo in range(0, n, 37):
        hi = min(n, lo + 37)
        parts.append(model.run(hi - lo, {"a": a[lo:hi], "b": b[lo:hi], "clear": clear[lo:hi]},
                               ["acc"])["acc"])
    np.testing.assert_array_equal(np.concatenate(parts), whole)


def test_set_get_tick(model):
    model.set("clear", 1)
    model.tick()
    model.set("clear", 0)
    model.set("a", -3)
    model.set("b", 5)
    assert model.get("prod") == -15
    model.tick(4)
    assert model.get("acc") == -60
    big = model.get("big")  # a port wider than 64 bits, read in 32-bit words
    assert big >> 88 == 0b101  # acc 40 + prod 24 + a 12 + b 12 bits below it
    assert big & ((1 << 40) - 1) == (-60) & ((1 << 40) - 1)
    assert (big >> 64) & 0xFFF == (-3) & 0xFFF
    with pytest.raises(ValueError, match="64 bits"):
        model.run(1, outputs=["big"])


def test_unknown_port_is_named(model):
    with pytest.raises(KeyError, match="nope"):
        model.get("nope")
    with pytest.raises(ValueError, match="output"):
        model.set("acc", 1)


def test_build_failure_is_reported():
    with pytest.raises(BuildError, match="not found"):
        CompiledModel(name="x", verilog_text="module y(clk); input clk; endmodule\n")


def test_reset_is_tied_low_unless_a_reset_port_is_asked_for(model):
    """The default build ties ``rst`` low in a harness (Verilator folds the reset logic away);
    ``reset_port=True`` keeps it as an input with a synchronous reset, as in Amaranth."""
    assert "rst" not in model.ports and "clk" in model.ports
    with_rst = CompiledModel(MacDemo(), "mac_demo", reset_port=True)
    assert "rst" in with_rst.ports
    with_rst.set("a", 3)
    with_rst.set("b", 4)
    with_rst.tick(2)
    assert with_rst.get("acc") == 24
    with_rst.set("rst", 1)
    with_rst.tick()
    with_rst.set("rst", 0)
    assert with_rst.get("acc") == 0


def test_trace_needs_a_trace_build(model, tmp_path):
    with pytest.raises(RuntimeError, match="trace=True"):
        model.trace_open(tmp_path / "x.vcd")
    assert not (tmp_path / "x.vcd").exists()


class NestedPorts(wiring.Component):
    """Ports from a nested signature (``rx__payload``, ``rx__valid``: C++ members Verilator
    renames), a name with a single underscore and a wide port."""

    rx: In(wiring.Signature({"payload": Out(8), "valid": Out(1), "ready": In(1)}))
    tx: Out(wiring.Signature({"payload": Out(72), "valid": Out(1)}))
    en_x: In(1)

    def elaborate(self, platform):
        m = Module()
        m.d.comb += self.rx.ready.eq(self.en_x)
        with m.If(self.rx.valid & self.en_x):
            m.d.sync += [self.tx.payload.eq(Cat(self.rx.payload, self.tx.payload[:64])),
                         self.tx.valid.eq(1)]
        return m


def test_ports_of_nested_signatures_are_reachable():
    """A component with ``a__b`` ports (any sub-signature, e.g. the ``node_core`` top's streams)
    builds and drives them; the build used to fail on the wrapper's member names."""
    from mrm_cosim.cosim.compiled import cxx_member

    assert cxx_member("rx__payload") == "rx___05Fpayload"
    assert cxx_member("en_x") == "en_x"
    assert cxx_member("a.b") == "a__02Eb"
    model = CompiledModel(NestedPorts(), "nested_ports")
    assert {"rx__payload", "rx__valid", "rx__ready", "tx__payload", "tx__valid",
            "en_x"} <= set(model.ports)
    out = model.run(3, {"rx__payload": [0x12, 0x34, 0x56], "rx__valid": [1, 0, 1],
                        "en_x": 1}, ["rx__ready", "tx__valid"])
    assert out["rx__ready"].tolist() == [1, 1, 1]
    assert out["tx__valid"].tolist() == [0, 1, 1]
    assert model.get("tx__payload") == 0x1256            # newest byte lowest


def test_a_cache_entry_is_whole_or_absent(tmp_path):
    """Builds go into a fresh folder renamed into place at the end: a failed build leaves
    nothing, and a build finished second leaves the first one's entry as it was."""
    from mrm_cosim.cosim.compiled import _building

    target = tmp_path / "cache" / "entry"
    with pytest.raises(RuntimeError):
        with _building(target) as work:
            (work / "half").write_text("written")
            raise RuntimeError("the compiler failed")
    assert not target.exists() and list(target.parent.iterdir()) == []
    with _building(target) as work:
        (work / "lib").write_text("first")
    with _building(target) as work:
        (work / "lib").write_text("second")
    assert (target / "lib").read_text() == "first"
    assert [p.name for p in target.parent.iterdir()] == ["entry"]
