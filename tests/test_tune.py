"""``mrm tune`` (issue 20 item 3): the held-out split, the objective, a 2-point tuning through
the sweep engine, the provenance written into a config; and the distribution table of a
seeds sweep (item 4) against numpy's percentiles."""

import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from mrm_cosim.cosim import sweep, tune
from mrm_cosim.cosim.experiment_config import load
from mrm_cosim.errors import InputError
from mrm_cosim.mrm.cli import main

ROOT = Path(__file__).resolve().parents[1]
TABLE2 = ROOT / "configs" / "table2.toml"

#: A tuning of the node's PID on one plant and one 20 ms quintic of 0.3 mrad (gentle enough
#: not to saturate; + 0.11 s hold): 2 runs.
TINY = """
[tune]
name = "tiny"
config = "{config}"
controllers = ["pid-fpga"]
backend = "model"
seeds = [3000]
held_out = ["{held}"]
amplitudes = [0.0003]
trajectory_duration = 0.02
hold = 0.11
budget = 2
initial = 1
seed = 0
settle_error = 0.002
ripple = 0.001

[tune.space.pid-fpga]
"gains.pid_fpga_hz" = [5.0, 20.0]
"""


def _spec(tmp_path, text=TINY, config=TABLE2, **subs):
    held = ROOT / "configs" / "sweeps" / "table2-seeds.toml"
    body = text.format(config=config, held=held)
    for old, new in subs.items():
        body = re.sub(rf"^{old} = .*$", f"{old} = {new}", body, flags=re.M)
    path = tmp_path / "tune.toml"
    path.write_text(body)
    return path


@pytest.mark.parametrize("key,value,field", [
    ("seeds", "[3000, 1017]", "tune.seeds"),          # a seed of table2-seeds.toml
    ("seeds", "[0]", "tune.seeds"),                   # the headline table's seed
    ("amplitudes", "[0.1571]", "tune.amplitudes[0]"),
    ("budget", "0", "tune.budget"),
    ("initial", "3", "tune.initial"),
    ("hold", "0.05", "tune.hold"),
    ("controllers", '["pid-fpga", "vdc"]', "tune.space.vdc"),
])
def test_a_spec_that_breaks_the_held_out_split_or_the_budget_is_refused(tmp_path, key, value,
                                                                        field):
    text = TINY
    if key == "amplitudes":                 # the test's quintic: 0.1571 rad in 1 s
        text = text.replace("trajectory_duration = 0.02", "trajectory_duration = 1.0")
    with pytest.raises(InputError) as exc:
        tune.load_tune_spec(_spec(tmp_path, text, **{key: value}))
    assert exc.value.field == field, exc.value


def test_the_shipped_tuning_spec_holds_out_every_test_seed():
    spec = tune.load_tune_spec(ROOT / "configs" / "tuning" / "table2.toml")
    tests = sweep.load_spec(ROOT / "configs" / "sweeps" / "table2-seeds.toml").seeds
    assert len(tests) >= 64
    assert set(tests) | {load(TABLE2).seed} <= set(spec.held_out_seeds)
    assert not set(spec.seeds) & set(spec.held_out_seeds)
    assert set(spec.controllers) == {"pid-1khz", "pid-fpga", "vdc"}
    assert spec.config["plant"]["joints"] == "compliant"


def _row(rho, torque=0.5, err=1e-4, ripple=1e-4, status="ok", faults=()):
    return {"status": status, "faults": list(faults),
            "figures": {"rho_s": rho, "max_torque_ratio": torque, "hold_error_rad": err,
                        "hold_ripple_rad": ripple}}


def test_the_objective_is_mean_log_rho_and_any_infeasible_run_loses(tmp_path):
    spec = tune.load_tune_spec(_spec(tmp_path))
    value, ok = tune.objective([_row(1e-4), _row(1e-2)], spec)
    assert ok and value == pytest.approx(-3.0)
    for bad in (_row(1e-5, torque=0.96), _row(1e-5, err=0.003), _row(1e-5, ripple=0.002),
                _row(1e-5, faults=["1 periods overrun"]), _row(1e-5, status="error"),
                _row(1e-5, err=None)):
        v, ok = tune.objective([_row(1e-4), bad], spec)
        assert not ok and v >= tune.PENALTY > value
    # more violation, higher objective: the search is pulled back to the feasible side
    assert tune.objective([_row(1e-5, err=0.004)], spec)[0] > \
        tune.objective([_row(1e-5, err=0.0025)], spec)[0]


def test_gains_live_in_the_unit_cube_on_a_log_scale_when_positive():
    space = {"gains.lam": (20.0, 400.0), "gains.K": (0.0, 150.0)}
    assert tune._to_gains(space, [0.0, 0.0]) == {"gains.lam": 20.0, "gains.K": 0.0}
    assert tune._to_gains(space, [1.0, 1.0]) == {"gains.lam": 400.0, "gains.K": 150.0}
    mid = tune._to_gains(space, [0.5, 0.5])
    assert mid["gains.lam"] == float(f"{math.sqrt(20 * 400):.3g}") and mid["gains.K"] == 75.0


def test_a_two_point_tuning_runs_as_sweeps_and_writes_its_provenance(tmp_path, capsys):
    config = tmp_path / "table2.toml"
    shutil.copy(TABLE2, config)
    # loose bounds: 20 ms of a 2 mrad quintic settles on any gain of the range
    spec_path = _spec(tmp_path, config=config, settle_error="1.0", ripple="1.0")
    out = tmp_path / "tune"
    code = main(["tune", str(spec_path), "--out", str(out), "--workers", "1", "--apply",
                 "--json", "--quiet"])
    assert code == 0
    record = json.loads((out / "tune.json").read_text())
    evals = record["controllers"]["pid-fpga"]["evaluations"]
    assert [e["stage"] for e in evals] == ["lhs", "nelder-mead"]
    assert len({e["gains"]["gains.pid_fpga_hz"] for e in evals}) == 2
    for e in evals:                          # each evaluation is a sweep of its own
        rows = [json.loads(x) for x in (out / "pid-fpga" / f"e{e['k']:02d}" /
                                        "points.jsonl").read_text().splitlines()]
        assert [r["seed"] for r in rows] == [3000]
        assert rows[0]["params"]["gains.pid_fpga_hz"] == e["gains"]["gains.pid_fpga_hz"]
        assert e["runs"][0]["rho_s"] == rows[0]["figures"]["rho_s"]
        assert e["objective"] == tune.objective(rows, tune.load_tune_spec(spec_path))[0]
    chosen = record["controllers"]["pid-fpga"]["chosen"]
    assert chosen["objective"] == min(e["objective"] for e in evals)
    printed = json.loads(capsys.readouterr().out)
    assert printed["chosen"]["pid-fpga"]["gains"] == chosen["gains"]
    # --apply: the gains and the provenance are in the config, which still loads
    text = config.read_text()
    assert load(config).gains.pid_fpga_hz == chosen["gains"]["gains.pid_fpga_hz"]
    assert load(config).gains.lam == load(TABLE2).gains.lam       # the others untouched
    block = text[text.index(tune.PROVENANCE_MARK):text.index("[gains]")]
    assert "spec 'tiny'" in block and "[3000]" in block and record["commit"] in block
    assert f"objective {chosen['objective']:.4f}" in block
    # applying again replaces the block instead of stacking a second one
    tune.apply_gains(record, config)
    assert config.read_text().count(tune.PROVENANCE_MARK) == 1
    # a controller without a feasible point keeps its gains, and the provenance says so
    record["controllers"]["pid-fpga"]["chosen"] = dict(chosen, feasible=False,
                                                       gains={"gains.pid_fpga_hz": 7.0})
    text = tune.apply_gains(record, config)
    assert load(config).gains.pid_fpga_hz == chosen["gains"]["gains.pid_fpga_hz"]
    assert "NO FEASIBLE POINT, gains not written" in text
    assert (out / "tuned_gains.toml").read_text().startswith(tune.PROVENANCE_MARK)


def test_the_distribution_table_quantiles_are_numpys():
    rng = np.random.default_rng(7)
    rows = []
    for c in ("pid-fpga", "vdc"):
        for s, rho in enumerate(rng.lognormal(-8, 0.4, 37)):
            rows.append({"controller": c, "seed": s, "status": "ok", "params": {},
                         "figures": {"rho_s": float(rho), "max_tip_error_m": float(rho) * 0.5}})
    lines = sweep.distribution_table(rows, ("pid-fpga", "vdc"))
    for c in ("pid-fpga", "vdc"):
        rho = np.array([r["figures"]["rho_s"] for r in rows if r["controller"] == c])
        cells = [x.strip() for x in next(line for line in lines
                                         if line.startswith(f"| {c} |")).split("|")[1:-1]]
        assert int(cells[1]) == 37
        for cell, q in zip(cells[2:5], (50, 5, 95), strict=True):
            assert float(cell) == pytest.approx(np.percentile(rho, q), rel=1e-3)
        assert float(cells[5]) == pytest.approx(
            {"pid-fpga": 0.0005, "vdc": 0.00012}[c])


def test_a_two_seed_sweep_prints_the_distribution_table(tmp_path):
    """The seeds sweep's summary.md opens with ρ's median and 5–95 % per controller, computed
    from its own points (numpy's percentiles)."""
    spec_path = tmp_path / "seeds.toml"
    spec_path.write_text('[sweep]\nname = "two"\nconfig = "table2"\ncontrollers = ["pid-fpga"]\n'
                         'backends = ["model"]\nseeds = [1000, 1001]\nduration = 0.004\n')
    out = tmp_path / "out"
    assert main(["sweep", str(spec_path), "--out", str(out), "--workers", "1", "--quiet"]) == 0
    rows = [json.loads(x) for x in (out / "points.jsonl").read_text().splitlines()]
    rho = np.array([r["figures"]["rho_s"] for r in rows])
    assert len(rho) == 2
    text = (out / "summary.md").read_text()
    assert "## ρ over plants (Table 2 as a prediction)" in text
    cells = [x.strip() for x in next(line for line in text.splitlines()
                                     if line.startswith("| pid-fpga | 2 |")).split("|")[1:-1]]
    for cell, q in zip(cells[2:5], (50, 5, 95), strict=True):
        assert float(cell) == pytest.approx(np.percentile(rho, q), rel=1e-3)
    for r in rows:                          # the tuning's figures are kept for every point
        assert {"max_torque_ratio", "hold_error_rad", "hold_ripple_rad"} <= set(r["figures"])


def test_apply_replaces_a_key_with_digits_in_place(tmp_path):
    """``pid_1khz_hz`` (a digit in its name) is rewritten on its own line, its comment kept:
    the key pattern once missed it and appended it a second time, an invalid TOML."""
    config = tmp_path / "table2.toml"
    shutil.copy(TABLE2, config)
    chosen = {"gains": {"gains.pid_1khz_hz": 13.2, "gains.pid_1khz_base_hz": 2.78},
              "objective": -2.0, "feasible": True, "k": 0}
    record = {"spec": "t", "spec_path": str(tmp_path / "t.toml"), "date": "d", "commit": "c",
              "seeds": [3000], "held_out_seeds": [0], "amplitudes": [0.04],
              "trajectory_duration": 0.4, "hold": 0.2, "set": {}, "budget": 1, "initial": 1,
              "constraints": {}, "controllers": {"pid-1khz": {"chosen": chosen}}}
    text = tune.apply_gains(record, config)
    assert [line.split("#")[0].strip() for line in text.splitlines()
            if line.startswith("pid_1khz_hz")] == ["pid_1khz_hz = 13.2"]
    g = load(config).gains
    assert (g.pid_1khz_hz, g.pid_1khz_base_hz) == (13.2, 2.78)
