"""Table 2 with a clock per node (docs/clocks.md): ±100 ppm clocks drawn from the seed, the
nodes' timers disciplined by the time-code — no link error, the period-start skew reported
and small; without the discipline the same clocks drift apart period by period."""

import json

import numpy as np
import pytest

from mrm_cosim.cosim import experiment_config as ec
from mrm_cosim.cosim.clocks import ClockConfig
from mrm_cosim.cosim.skew import start_offsets
from mrm_cosim.cosim.table2 import run_table2
from mrm_cosim.cosim.track import run_faults, run_track
from mrm_cosim.errors import InputError

CONFIG = """
[experiment]
controllers = ["vdc"]
backend = "compiled"
duration = 0.03
[clocks]
mode = "drawn"
range_ppm = 100.0
discipline = true
"""


def test_table2_with_drawn_clocks_and_discipline_reports_a_small_skew(tmp_path):
    config = ec.loads(CONFIG)
    summary = run_table2(config, tmp_path / "out")
    s = summary["controllers"]["vdc"]
    assert run_faults(s) == [], run_faults(s)
    assert s["link_errors"] == 0
    clocks = s["clocks"]
    assert clocks["discipline"] and clocks["mode"] == "drawn"
    ppm = [clocks["master_ppm"], *clocks["ppm"]]
    assert all(abs(p) <= 100 for p in ppm) and len(set(ppm)) == 4
    skew = s["period_skew"]
    assert skew["periods"] >= 29 and skew["missing"] <= 3
    # locked: a few cycles of the chain's jitter (docs/node.md "Discipline": ≤ 7.5)
    assert skew["node_vs_master"]["rms_cycles"] < 8
    assert skew["between_nodes"]["max_cycles"] < 12
    on_disk = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert on_disk["controllers"]["vdc"]["period_skew"] == skew
    table = (tmp_path / "out" / "table2.md").read_text()
    assert "disciplined by the time-code" in table and "between nodes" in table
    assert (tmp_path / "out" / "vdc" / "skew.png").stat().st_size > 0
    assert ec.loads((tmp_path / "out" / "config.toml").read_text()) == config


def test_without_discipline_the_same_clocks_drift_apart():
    clocks = ClockConfig(mode="drawn")
    result, s = run_track("mrm3", "vdc", "compiled", duration=0.02, clocks=clocks)
    assert s["link_errors"] == 0 and s["overruns"] == 0
    b = start_offsets(result.master.records, 3, 50_000,
                      strobes=result.master.boundary_strobes)
    # each node's offset moves by its clock's offset against the master's every period
    ppm = np.array(s["clocks"]["ppm"]) - s["clocks"]["master_ppm"]
    drift = np.nanmean(np.diff(b[2:], axis=0), axis=0)
    np.testing.assert_allclose(drift, -ppm * 1e-6 * 50_000, atol=1.0)
    assert s["period_skew"]["node_vs_master"]["max_abs_cycles"] > 50


@pytest.mark.parametrize("table, field", [
    ("mode = 'drawn'\nrange_ppm = -5", "clocks.range_ppm"),
    ("mode = 'list'\nppm = [0, 0, 1e6]\nphase = [0, 0, 0]", "clocks.ppm[2]"),
    ("mode = 'list'\nppm = [0, 0, 0]\nphase = [0, 1.0, 0]", "clocks.phase[1]"),
    ("mode = 'list'\nppm = [0, 0]\nphase = [0, 0, 0]", "clocks.ppm"),
    ("mode = 'list'\nppm = [0, 0, 0]", "clocks.phase"),
    ("mode = 'drawn'\nppm = [0, 0, 0]", "clocks.ppm"),
    ("mode = 'common'\nmaster_ppm = 3", "clocks.master_ppm"),
    ("mode = 'wobbly'", "clocks.mode"),
    ("mode = 'drawn'\ndiscipline = 'yes'", "clocks.discipline"),
    ("mode = 'drawn'\nkp = 9", "clocks.kp"),
    ("mode = 'drawn'\nfrequency = 50e6", "clocks.frequency"),
    ("mode = 'list'\nppm = 'fast'\nphase = [0, 0, 0]", "clocks.ppm"),
])
def test_bad_clocks_are_refused_by_field(table, field):
    with pytest.raises(InputError) as exc:
        ec.loads(f"[experiment]\nbackend = 'compiled'\n[clocks]\n{table}\n")
    assert exc.value.field == field


def test_drawn_clocks_come_from_the_seed_alone():
    c = ClockConfig(mode="drawn", range_ppm=100.0)
    assert c.resolve(3, 0) == c.resolve(3, 0)
    assert c.resolve(3, 0) != c.resolve(3, 1)
    ppm, phase = c.resolve(6, 7)
    assert len(ppm) == 7 and all(abs(p) <= 100 for p in ppm)
    assert all(0 <= f < 1 for f in phase)
    assert ClockConfig().resolve(3, 5) == ((0.0,) * 4, (0.0,) * 4)


def test_the_clocks_table_is_the_default_table_on_drawn_clocks():
    from dataclasses import replace
    from pathlib import Path

    clocks = ec.load(Path(ec.DEFAULT_CONFIG).with_name("table2-clocks.toml"))
    assert clocks.clocks == ClockConfig(mode="drawn", range_ppm=100.0, discipline=True)
    assert clocks.backend == "compiled"
    assert replace(ec.load(), backend="compiled", clocks=clocks.clocks) == clocks
