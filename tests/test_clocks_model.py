"""The ``model`` backend with a clock per node (docs/clocks.md "The model backend"): each
node's reference runs in cycles of its own clock, mapped onto the master's grid as the gateware
harnesses map it — bit for bit the compiled gateware's run with free-running timers, within
the link's jitter with the timers disciplined; the fast nodes' plain ticks with the discipline
equal the reference's event loop."""

import random

import numpy as np
import pytest

from mrm_cosim.cosim import experiment_config as ec
from mrm_cosim.cosim import model as model_mod
from mrm_cosim.cosim.clocks import ClockConfig, ClockedEngine, ClockPlan, NodeTime
from mrm_cosim.cosim.model_kernel import KernelNode
from mrm_cosim.cosim.model_node import FastNode
from mrm_cosim.cosim.skew import start_offsets
from mrm_cosim.cosim.table2 import run_table2
from mrm_cosim.cosim.track import run_track
from mrm_cosim.errors import InputError
from mrm_cosim.hdl.node.core_ref import NodeModel
from mrm_cosim.protocol.discipline import Discipline
from mrm_cosim.protocol.packet import PacketType
from mrm_cosim.protocol.regs import Config, config_payloads


def _offsets(result):
    return start_offsets(result.master.records, 3, 50_000,
                         strobes=result.master.boundary_strobes)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_node_time_is_the_harness_event_order(seed):
    """:class:`NodeTime` against :class:`ClockedEngine`'s own walk (the pysim harness's
    order, which the compiled loop shares): every node cycle in the master cycle whose end
    its edge reaches, and each master cycle's first node cycle."""
    rng = random.Random(seed)
    ppm = [rng.uniform(-100, 100) for _ in range(4)]
    if seed == 2:
        ppm = [rng.choice((-1e4, 1e4)) for _ in range(4)]     # ±1 %: empty master cycles
    plan = ClockPlan.from_ppm(ppm, [rng.random() for _ in range(4)], 6)
    eng = ClockedEngine(plan, [])
    times = [NodeTime(plan, k) for k in range(1, 4)]
    first = [[] for _ in range(3)]
    for g in range(3_000):
        until = plan.phases[0] + (g + 1) * plan.periods[0]
        for k in range(3):
            first[k].append(eng.cycle[k + 1])
        while (group := eng.node_group(until)) is not None:
            for d in group:
                assert times[d - 1].master_cycle(eng.cycle[d]) == g
                eng.cycle[d] += 1
    for k in range(3):
        assert [times[k].node_cycle(g) for g in range(3_000)] == first[k]


def test_free_running_timers_are_the_compiled_gateware_bit_for_bit():
    """Drawn ±100 ppm clocks, no discipline: the nodes drift apart period by period, and the
    model's run is the Verilated gateware's — the same trace hash, the same boundary of every
    node in every period."""
    clocks = ClockConfig(mode="drawn")
    model, sm = run_track("mrm3", "vdc", "model", duration=0.02, clocks=clocks)
    gate, sg = run_track("mrm3", "vdc", "compiled", duration=0.02, clocks=clocks)
    assert sm["model_violations"] == []
    assert sm["trace_sha256"] == sg["trace_sha256"]
    b = _offsets(model)
    np.testing.assert_array_equal(b, _offsets(gate))
    assert np.nanmax(np.abs(b)) > 50                    # (they did drift)
    assert sm["clocks"] == sg["clocks"]


def test_disciplined_timers_follow_the_compiled_gateware_within_the_links_jitter():
    """With the discipline the loop acts on the time-code's arrival phase; the model's link
    delivers it 12 cycles a hop exactly, the gateware's after the character on the line
    (docs/clocks.md): the period starts agree within a few cycles, the motion to 1e-9 rad."""
    clocks = ClockConfig(mode="drawn", discipline=True)
    model, sm = run_track("mrm3", "vdc", "model", duration=0.03, clocks=clocks)
    gate, sg = run_track("mrm3", "vdc", "compiled", duration=0.03, clocks=clocks)
    assert sm["model_violations"] == [] and sm["link_errors"] == 0
    bm, bg = _offsets(model), _offsets(gate)
    assert np.nanmax(np.abs(bm - bg)) <= 8
    assert abs(sm["period_skew"]["node_vs_master"]["max_abs_cycles"]
               - sg["period_skew"]["node_vs_master"]["max_abs_cycles"]) <= 4
    np.testing.assert_allclose(model.q, gate.q, rtol=0, atol=1e-9)
    assert sm["rho_s"] == pytest.approx(sg["rho_s"], rel=1e-4)


class _ReferenceNode(FastNode):
    """The node reference's own event loop: every tick through :meth:`NodeModel.run`."""

    def run(self, until, sample=None):
        NodeModel.run(self, until, sample)

    def _tick(self, now, sample, tt, ramped=False, hold=None):
        NodeModel._tick(self, now, sample, tt, ramped, hold)

    def torque_at(self, now):
        return NodeModel.torque_at(self, now)


@pytest.mark.parametrize("controller", ["vdc", "pid-fpga"])
def test_fast_nodes_with_the_discipline_are_the_references_event_loop(monkeypatch, controller):
    """The fast nodes' plain ticks stop at the disciplined period's tail and at each step
    of the loop (:meth:`FastNode.next_special`): same trace, torques and boundaries as the
    reference's event loop on every tick, on clocks of their own: two nodes slower than the
    master, whose periods the loop shortens (a tail without ticks), one faster."""
    clocks = ClockConfig(mode="list", ppm=(-80.0, 50.0, -20.0), phase=(0.3, 0.6, 0.9),
                         master_ppm=80.0, master_phase=0.1, discipline=True)
    fast, sf = run_track("mrm3", controller, "model", duration=0.02, clocks=clocks, seed=3)
    monkeypatch.setattr(model_mod, "FastNode", _ReferenceNode)
    ref, sr = run_track("mrm3", controller, "model", duration=0.02, clocks=clocks, seed=3)
    assert sf["trace_sha256"] == sr["trace_sha256"]
    np.testing.assert_array_equal(_offsets(fast), _offsets(ref))
    assert fast.master.boundary_strobes == ref.master.boundary_strobes


def test_the_fast_node_takes_the_loop_and_the_kernel_refuses_it():
    """A nonzero TC_DISCIPLINE: the fast node (the backend's pure-Python path) and the
    reference take it; the compiled kernel's node, which keeps PERIOD-cycle periods and every
    tick, refuses it naming the field."""
    on = config_payloads({Config.TC_DISCIPLINE: Discipline(target=12).word})[0]
    for cls in (FastNode, NodeModel):
        node = cls()
        node.packet(10, PacketType.CONFIG, on)
        node.run(12)                # (a record acts the cycle after its last byte)
        assert node.config[Config.TC_DISCIPLINE] == Discipline(target=12).word
    node = KernelNode()
    node.packet(10, PacketType.CONFIG, on)
    with pytest.raises(InputError, match="config.tc_discipline"):
        node.run(12)


def test_table2_runs_on_the_model_with_clocks_of_their_own(tmp_path):
    config = ec.loads("""
[experiment]
controllers = ["vdc"]
backend = "model"
duration = 0.03
[clocks]
mode = "drawn"
discipline = true
""")
    summary = run_table2(config, tmp_path / "out")
    s = summary["controllers"]["vdc"]
    assert s["backend"] == "model" and s["model_violations"] == []
    assert s["clocks"]["discipline"] and len(set(s["clocks"]["ppm"])) == 3
    assert s["period_skew"]["periods"] >= 29
    assert s["period_skew"]["missing"] == 0         # period 0's early boundaries kept too
    assert 0 < s["period_skew"]["node_vs_master"]["max_abs_cycles"] < 20
    assert (tmp_path / "out" / "vdc" / "skew.png").stat().st_size > 0
    assert "not bit for bit" in (tmp_path / "out" / "table2.md").read_text()
    # and the compiled configuration switches to the model from the command line
    cfg = ec.loads("[experiment]\nbackend = 'compiled'\n[clocks]\nmode = 'drawn'\n")
    assert cfg.with_overrides(backend="model", field_prefix="--").backend == "model"


def test_run_track_on_clocks_of_their_own_draws_the_skew(tmp_path, capsys):
    """``mrm run track`` with a ``[clocks]`` config: summary.json's ``period_skew`` and a
    ``skew.png`` beside the timeline, as each Table 2 controller's folder has."""
    from mrm_cosim.mrm import cli

    config = tmp_path / "clocks.toml"
    config.write_text("[experiment]\nbackend = 'model'\nduration = 0.01\n"
                      "[clocks]\nmode = 'drawn'\ndiscipline = true\n")
    out = tmp_path / "run"
    assert cli.main(["run", "track", "--controller", "vdc", "--config", str(config),
                     "--out", str(out)]) == 0
    assert "skew.png" in capsys.readouterr().out
    assert (out / "skew.png").stat().st_size > 0
    common = tmp_path / "common"
    config.write_text("[experiment]\nbackend = 'model'\nduration = 0.01\n")
    assert cli.main(["run", "track", "--controller", "vdc", "--config", str(config),
                     "--out", str(common), "--quiet"]) == 0
    assert not (common / "skew.png").exists()


def test_the_eager_path_on_clocks_of_their_own_is_the_lazy_ones(monkeypatch):
    """``ModelBackend(lazy=False)`` with a clock per node: every tick computed, the encoder
    lines fed cycle by cycle through the same mapping — the same trace and boundaries as the
    lazy path's count changes."""
    clocks = ClockConfig(mode="list", ppm=(5000.0, -3000.0, 1000.0), phase=(0.2, 0.5, 0.7),
                         master_ppm=-4000.0, master_phase=0.9)
    lazy, sl = run_track("mrm3", "pid-fpga", "model", duration=0.04, clocks=clocks, seed=4)
    init = model_mod.ModelBackend.__init__

    def eager(self, *a, **kw):
        init(self, *a, **{**kw, "lazy": False})

    monkeypatch.setattr(model_mod.ModelBackend, "__init__", eager)
    slow, se = run_track("mrm3", "pid-fpga", "model", duration=0.04, clocks=clocks, seed=4)
    assert sl["trace_sha256"] == se["trace_sha256"]
    assert lazy.master.boundary_strobes == slow.master.boundary_strobes
