"""``mrm sweep``: points as pure functions, on every executor with the same results."""

import json
import os
import signal
import subprocess
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from mrm_cosim.cosim import sweep
from mrm_cosim.cosim.executors import LocalExecutor, SerialExecutor, make_executor
from mrm_cosim.errors import InputError
from mrm_cosim.mrm.cli import main

TINY = """
[sweep]
name = "tiny"
config = "table2"
controllers = ["pid-fpga", "vdc"]
backends = ["model"]
seeds = [3, 4]
duration = 0.004

[[axis]]
field = "gains.lam"
values = [100.0, 200.0]
"""


def _spec(tmp_path, text=TINY, name="spec.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _hashes(out: Path) -> dict:
    rows = [json.loads(line) for line in (out / "points.jsonl").read_text().splitlines()]
    return {r["id"]: r["trace_sha256"] for r in rows if r["status"] == "ok"}


def test_the_same_points_give_the_same_traces_on_every_executor(tmp_path):
    """Serial, the local process pool and a Dask LocalCluster: every point's trace hash is
    the same (a point is a pure function of its config and seed)."""
    spec = sweep.load_spec(_spec(tmp_path))
    assert len(sweep.expand(spec)) == 8
    hashes = {}
    for name, scheduler, workers in (("serial", None, 1), ("local", None, 2),
                                     ("dask", "local-dask", 2)):
        with make_executor(workers, scheduler) as ex:
            outcome = sweep.run_sweep(spec, tmp_path / name, ex)
        assert outcome["failed"] == 0 and outcome["ran"] == 8, name
        hashes[name] = _hashes(tmp_path / name)
    assert hashes["serial"] == hashes["local"] == hashes["dask"]
    # the seeds change every run, λ only VDC's (the node's PID does not use it): 2 + 4 traces
    assert len(set(hashes["serial"].values())) == 6
    out = tmp_path / "serial"
    for pid in hashes["serial"]:
        summary = json.loads((out / "points" / pid / "summary.json").read_text())
        assert summary["trace_sha256"] == hashes["serial"][pid]
    text = (out / "summary.md").read_text()
    assert "## By controller" in text and "## By gains.lam" in text
    assert (out / "rho_by_controller.png").stat().st_size > 0
    assert (out / "rho_vs_gains_lam.png").stat().st_size > 0
    assert "[[axis]]" in (out / "sweep.toml").read_text()


def test_resume_runs_only_what_is_missing(tmp_path, capsys):
    spec = _spec(tmp_path)
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "1", "-q"]) == 0
    lines = (out / "points.jsonl").read_text().splitlines()
    # a sweep killed after three points, the fourth cut mid-line
    (out / "points.jsonl").write_text("\n".join(lines[:3]) + "\n" + lines[3][:40])
    # without --resume a folder that holds a sweep is not touched
    assert main(["sweep", str(spec), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0] and "--resume" in err[0]
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "1", "--resume",
                 "--json"]) == 0
    outcome = json.loads(capsys.readouterr().out)
    assert (outcome["ran"], outcome["skipped"], outcome["failed"]) == (5, 3, 0)
    rows = [json.loads(x) for x in (out / "points.jsonl").read_text().splitlines()
            if x.startswith("{") and x.endswith("}")]
    assert len({r["id"] for r in rows}) == 8


@pytest.mark.parametrize("text, field", [
    (TINY.replace('field = "gains.lam"', 'field = "gains.lamda"'), "axis[0].field"),
    (TINY.replace("values = [100.0, 200.0]", "values = [100.0, -1.0]"), "axis[0].field"),
    (TINY.replace('field = "gains.lam"', 'field = "experiment.seed"'), "axis[0].field"),
    (TINY.replace("seeds = [3, 4]", "seeds = [3, 4]\nworkers = 2"), "sweep.workers"),
    (TINY.replace('controllers = ["pid-fpga", "vdc"]', 'controllers = ["lqr"]'),
     "sweep.controllers"),
    (TINY.replace('config = "table2"', 'config = "nope"'), "sweep.config"),
    (TINY + '\n[draws]\ncount = 4\nfields = { "gains.K" = [50.0, 10.0] }\n',
     'draws.fields.gains.K'),
    # each value fits alone; together the master's compute does not fit the 1 ms period
    (TINY.replace('field = "gains.lam"\nvalues = [100.0, 200.0]',
                  'field = "timing.kinematics_cycles"\nvalues = [1000, 30000]\n\n[[axis]]\n'
                  'field = "timing.force_cycles"\nvalues = [1000, 25000]'),
     "timing.kinematics_cycles"),
])
def test_bad_specs_are_refused_before_anything_runs(tmp_path, capsys, text, field):
    out = tmp_path / "out"
    assert main(["sweep", str(_spec(tmp_path, text)), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and field in err[0], err
    assert not out.exists()


def test_latin_hypercube_draws_fill_every_stratum():
    draws = {"method": "lhs", "count": 16, "seed": 7,
             "fields": {"gains.K": (0.0, 50.0), "gains.lam": (50.0, 250.0)}}
    params = sweep._draw_params(draws)
    assert len(params) == 16
    for f, (lo, hi) in draws["fields"].items():
        strata = sorted(int((p[f] - lo) / (hi - lo) * 16) for p in params)
        assert strata == list(range(16)), f
    assert sweep._draw_params(draws) == params                 # seeded


def _flaky(item, report):
    if item == "die":
        os._exit(3)                          # a worker killed outright
    if item == "raise":
        raise ValueError("bad luck")
    if item == "refuse":
        raise InputError("gains.k_j", "too large")
    report("progress", item)
    return item * 2


@pytest.mark.parametrize("executor", [SerialExecutor, partial(LocalExecutor, 2)])
def test_a_failing_point_does_not_stop_the_others(executor):
    items = ["a", "raise", "b", "refuse", "c"]
    messages = []
    with executor() as ex:
        out = {i: (status, value) for i, status, value in
               ex.run(_flaky, items, lambda *m: messages.append(m))}
    assert {i: s for i, (s, _) in out.items()} == {0: "ok", 1: "error", 2: "ok", 3: "input",
                                                  4: "ok"}
    assert out[0][1] == "aa" and "bad luck" in out[1][1]
    assert out[3][1] == ("gains.k_j", "too large")
    assert sorted(m[1] for m in messages) == ["a", "b", "c"]


def test_a_worker_that_dies_marks_its_point_failed_and_the_rest_run():
    items = ["a", "die", "b", "c", "d"]
    with LocalExecutor(1) as ex:
        out = {i: status for i, status, _ in ex.run(_flaky, items)}
    assert out[1] == "error"
    assert out[0] == "ok" and out[4] == "ok" and len(out) == 5


def test_ctrl_c_stops_every_worker_and_keeps_the_finished_points(tmp_path):
    spec = _spec(tmp_path, TINY.replace("seeds = [3, 4]", "seeds = { start = 0, count = 40 }")
                 .replace("duration = 0.004", "duration = 0.02"))
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "mrm_cosim.mrm.cli", "sweep", str(spec),
                             "--out", str(out), "--workers", "2", "-q"],
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    jsonl = out / "points.jsonl"
    deadline = time.time() + 120
    while time.time() < deadline and not (jsonl.exists() and jsonl.read_text().count("\n") >= 2):
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    rows = [json.loads(x) for x in jsonl.read_text().splitlines()]
    assert 2 <= len(rows) < 160 and all(r["status"] == "ok" for r in rows)
    time.sleep(0.5)
    left = subprocess.run(["pgrep", "-g", str(proc.pid)], capture_output=True, text=True)
    assert left.stdout.strip() == "", "a worker outlived the sweep"


def test_shipped_sweeps_are_valid():
    root = Path(__file__).resolve().parents[1] / "configs" / "sweeps"
    seeds = sweep.load_spec(root / "table2-seeds.toml")
    assert seeds.controllers == ("pid-1khz", "pid-fpga", "vdc") and len(seeds.seeds) == 64
    assert 0 not in seeds.seeds                              # the headline table's plant
    assert len(sweep.expand(seeds)) == 192
    gains = sweep.load_spec(root / "vdc-gains.toml")
    assert len(sweep.expand(gains)) == 80
    assert np.all(np.array(gains.seeds) >= 1000)
    for name, field in (("table2-stiffness.toml", "plant.gear.stiffness_scale"),
                        ("table2-friction.toml", "plant.perturbation.friction")):
        spec = sweep.load_spec(root / name)
        points = sweep.expand(spec)
        assert len(points) == 60 and set(spec.seeds) <= set(seeds.seeds), name
        assert {p["config"]["plant"]["joints"] for p in points} == {"compliant"}
        assert len({p["params"][field] for p in points}) == 5


def test_a_sweep_over_clock_draws_reports_the_skew(tmp_path):
    """A config with clocks of its own: each seed draws its clocks, every point keeps the
    period-start skew, summary.md gives its distribution; the shipped spec is valid."""
    root = Path(__file__).resolve().parents[1] / "configs"
    shipped = sweep.load_spec(root / "sweeps" / "clocks-seeds.toml")
    assert shipped.backends == ("model",) and 0 not in shipped.seeds
    assert shipped.config["clocks"]["mode"] == "drawn" and shipped.config["clocks"]["discipline"]
    spec = sweep.load_spec(_spec(tmp_path, f"""
[sweep]
name = "clocks"
config = "{root / 'table2-clocks.toml'}"
controllers = ["vdc"]
backends = ["model"]
seeds = [5, 6]
duration = 0.006
"""))
    with SerialExecutor() as ex:
        outcome = sweep.run_sweep(spec, tmp_path / "out", ex)
    assert outcome["failed"] == 0
    figures = [r["figures"] for r in outcome["rows"]]
    assert all(set(sweep.SKEW_FIGURES) <= set(f) for f in figures)
    assert all(f["skew_max_cycles"] > 0 for f in figures)
    assert figures[0]["skew_max_cycles"] != figures[1]["skew_max_cycles"]  # other clocks
    text = (tmp_path / "out" / "summary.md").read_text()
    assert "## Period-start skew over clock draws (cycles)" in text
    # a common clock keeps no skew figures
    common = sweep.load_spec(_spec(tmp_path, TINY.replace('seeds = [3, 4]', 'seeds = [3]'),
                                   "common.toml"))
    with SerialExecutor() as ex:
        rows = sweep.run_sweep(common, tmp_path / "common", ex)["rows"]
    assert not any("skew_max_cycles" in r["figures"] for r in rows)


def test_a_sweep_of_the_cartesian_line(tmp_path):
    """kind = "line": the six-module arm's line (configs/line.toml by default) over profiles;
    the tool's errors are the figures; the same points give the same traces serially and on
    the process pool."""
    line = Path(__file__).resolve().parents[1] / "examples" / "line.toml"
    spec_path = _spec(tmp_path, f"""
[sweep]
name = "line-profiles"
kind = "line"
line = "{line}"
profiles = ["trig", "ruckig"]
controllers = ["vdc"]
seeds = [1, 2]
duration = 0.004
""")
    spec = sweep.load_spec(spec_path)
    assert spec.config["experiment"]["robot"] == "mrm6" and len(sweep.expand(spec)) == 4
    with SerialExecutor() as ex:
        outcome = sweep.run_sweep(spec, tmp_path / "a", ex)
    assert outcome["failed"] == 0
    rows = outcome["rows"]
    assert {r["profile"] for r in rows} == {"trig", "ruckig"}
    assert all(0 < r["figures"]["max_position_error_mm"] < 1 for r in rows)
    with LocalExecutor(2) as ex:
        sweep.run_sweep(spec, tmp_path / "b", ex)
    assert _hashes(tmp_path / "a") == _hashes(tmp_path / "b")
    text = (tmp_path / "a" / "summary.md").read_text()
    assert "## By profile" in text and "tool position error (mm)" in text
    assert (tmp_path / "a" / "position_error_by_controller.png").stat().st_size > 0


@pytest.mark.parametrize("extra, field", [
    ('kind = "line"\nline = "nope.toml"', "sweep.line"),
    ('kind = "line"\nline = "{line}"\nprofiles = ["fast"]', "sweep.profiles"),
    ('profiles = ["trig"]', "sweep.profiles"),
    ('kind = "dmp"', "sweep.kind"),
])
def test_bad_line_sweeps(tmp_path, capsys, extra, field):
    line = Path(__file__).resolve().parents[1] / "examples" / "line.toml"
    text = f'[sweep]\nname = "x"\n{extra.format(line=line)}\nseeds = [1]\n'
    assert main(["sweep", str(_spec(tmp_path, text)), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and field in err[0], err


def test_a_point_is_the_run_of_table2_with_its_configuration(tmp_path):
    """A sweep point of Table 2's configuration (one controller, its seed) gives the trace hash
    of that controller's row in mrm run table2: the same function of the same config.
    (The test is the other sweep implementation's, branch `sweep`, 342177b.)"""
    from dataclasses import replace

    from mrm_cosim.cosim import experiment_config as ec
    from mrm_cosim.cosim.table2 import run_table2

    config = replace(ec.load().with_overrides(backend="model", duration=0.01, seed=4),
                     controllers=("pid-fpga", "vdc"))
    table = run_table2(config, tmp_path / "t2")
    (tmp_path / "base.toml").write_text(config.to_toml())
    spec = sweep.load_spec(_spec(tmp_path, '[sweep]\nconfig = "base.toml"\n'))
    points = sweep.expand(spec)
    assert [p["controller"] for p in points] == list(config.controllers)
    for p in points:
        assert sweep.run_point(p)["trace_sha256"] == \
            table["controllers"][p["controller"]]["trace_sha256"], p["controller"]
