"""``mrm run table2``: plumbing with a stand-in run_track, atomic output, and one real short run."""

import io
import os
import json
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

import mrm_cosim.mrm.cli as cli
from mrm_cosim.cosim import experiment_config as ec
from mrm_cosim.cosim import table2
from mrm_cosim.cosim.track import BACKENDS, run_track
from mrm_cosim.master.cycle import MasterTiming, PeriodRecord
from mrm_cosim import __version__
from mrm_cosim.errors import InputError
from mrm_cosim.results import MARKER, atomic_output_dir

FIELDS = {"controller", "backend", "rho_s", "max_tip_error_m", "max_tip_speed_m_s",
          "max_joint_error_rad", "overruns", "link_errors", "phases_us", "trace_sha256"}


class FakeRunner:
    """Stands in for run_track: records its calls, returns a trace whose error scales with a
    per-controller factor, and fails on request."""

    def __init__(self, errors=None, fail_on=None):
        self.calls = []
        self.errors = errors or {"pid-1khz": 4e-3, "pid-fpga": 5e-4, "vdc": 1e-4}
        self.fail_on = fail_on

    def __call__(self, robot, controller, backend, duration, seed, gains=None, timing=None,
                 plant_config=None, progress=None):
        self.calls.append(dict(robot=robot.name, controller=controller, backend=backend,
                               duration=duration, seed=seed, gains=gains, timing=timing,
                               plant=plant_config))
        if controller == self.fail_on:
            raise RuntimeError("simulated crash")
        if progress is not None:
            progress(0.5 * duration, duration)
        t = np.arange(int(round(duration / 1e-5))) * 1e-5
        q = np.outer(np.sin(t), [1.0, 2.0, 3.0]) * self.errors[controller]
        tau = np.outer(np.cos(t), [1.0, -1.0, 0.5])
        records = []
        for i in range(int(duration / 1e-3)):
            r = PeriodRecord(i, 50_000 * (i + 1), complete=True)
            r.arrivals = {("A", k): r.start + 100 + 40 * k for k in (1, 2, 3)}
            r.events = {"A_done": r.start + 220, "D_sent": r.start + 1220}
            records.append(r)
        master = SimpleNamespace(records=records, timing=timing or MasterTiming())
        err = self.errors[controller]
        summary = {"controller": controller, "backend": backend, "robot": robot.name,
                   "seed": seed, "duration_s": duration, "rho_s": err / 0.5,
                   "max_tip_error_m": err, "max_tip_speed_m_s": 0.5,
                   "max_joint_error_rad": 3 * err, "overruns": 0, "missing_replies": 0,
                   "unexpected_replies": 0, "link_errors": 0,
                   "phases_us": {"A": 4.4, "D": 24.4, "cycle": 4.4}, "trace_sha256": "ab" * 32}
        return SimpleNamespace(t=t, q=q, tau=tau, master=master), summary


@pytest.fixture(scope="module")
def config():
    return ec.loads("[experiment]\nduration = 0.02\nseed = 5\nbackend = 'pysim'\n")


@pytest.fixture(scope="module")
def done(config, tmp_path_factory):
    """One stand-in run of the three controllers: (runner, summary returned, folder)."""
    out = tmp_path_factory.mktemp("table2") / "out"
    runner = FakeRunner()
    return runner, table2.run_table2(config, out, runner=runner), out


def test_three_controllers_same_plant_seed_gains_and_timing(done, config):
    runner, summary, out = done
    assert [c["controller"] for c in runner.calls] == ["pid-1khz", "pid-fpga", "vdc"]
    for call in runner.calls:
        assert (call["robot"], call["backend"], call["seed"], call["duration"]) == \
            ("mrm3", "pysim", 5, 0.02)
        assert call["gains"] == config.gains and call["timing"] == config.timing
        assert call["plant"] == config.plant
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk == json.loads(json.dumps(summary))
    assert set(on_disk["controllers"]) == {"pid-1khz", "pid-fpga", "vdc"}
    for name, s in on_disk["controllers"].items():
        assert FIELDS <= set(s) and s["controller"] == name
        assert s["version"] == __version__
    assert on_disk["seed"] == 5 and on_disk["version"] == __version__
    assert on_disk["ordering"] == {"best_to_worst": ["vdc", "pid-fpga", "pid-1khz"],
                                   "moved": True, "apart": True, "as_paper": True}
    assert ec.loads((out / "config.toml").read_text()) == config
    assert on_disk["config"] == config.to_dict()


def test_folder_holds_table_plots_and_per_controller_results(done):
    _, _, out = done
    for name in ("fig4_tracking.png", "fig5_errors.png", "torques.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"
    for c in ("pid-1khz", "pid-fpga", "vdc"):
        for name in ("tracking.png", "timeline.png", "parameters.png"):
            assert (out / c / name).read_bytes()[:4] == b"\x89PNG"
        timeline = json.loads((out / c / "timeline.json").read_text())
        assert timeline[3]["arrivals"] == {"A1": 200_140, "A2": 200_180, "A3": 200_220}
        rows = (out / c / "trace.csv").read_text().splitlines()
        assert len(rows) == 1 + 20 and rows[0].startswith("t_s,q_d1_rad")
    s = json.loads((out / "vdc" / "summary.json").read_text())
    assert "adaptation off" in s["parameter_estimates"]
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".")]


def test_markdown_table_sits_beside_the_papers_numbers(done):
    md = (done[2] / "table2.md").read_text()
    rows = {line.split("|")[1].strip(): [x.strip() for x in line.split("|")[2:-1]]
            for line in md.splitlines() if line.startswith("| ") and "`" in line}
    assert rows["VDC with embedded FPGA (`vdc`)"][:7] == [
        "0.5000", "0.1000", "0.000200", "0.5226", "0.0618", "0.000120", "0.3000"]
    assert rows["PID with 1000 Hz (`pid-1khz`)"][3:6] == ["0.5226", "2.3", "0.004400"]
    assert rows["PID with embedded FPGA (`pid-fpga`)"][5] == "0.000500"
    assert "as in the paper" in md


def test_ordering_unlike_the_paper_is_said_plainly(done):
    summary = json.loads(json.dumps(done[1]))
    for c, rho in {"pid-1khz": 1e-4, "pid-fpga": 5e-4, "vdc": 2e-4}.items():
        summary["controllers"][c]["rho_s"] = rho
    runs = {c: (None, s) for c, s in summary["controllers"].items()}
    summary["ordering"] = table2._ordering(runs)
    assert summary["ordering"] == {"best_to_worst": ["pid-1khz", "vdc", "pid-fpga"],
                                   "moved": True, "apart": True, "as_paper": False}
    assert "NOT the paper's order" in table2.table_markdown(summary)


def test_a_failed_run_leaves_no_folder_and_keeps_the_old_one(tmp_path, config):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        table2.run_table2(config, out, runner=FakeRunner(fail_on="pid-fpga"))
    assert list(tmp_path.iterdir()) == []
    with atomic_output_dir(out) as tmp:         # an earlier result folder
        (tmp / "keep.txt").write_text("old result")
    with pytest.raises(RuntimeError):
        table2.run_table2(config, out, runner=FakeRunner(fail_on="vdc"))
    assert [p.name for p in tmp_path.iterdir()] == ["out"]
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "keep.txt"]


def test_a_file_as_the_folder_is_refused_before_anything_runs(tmp_path, config):
    """The result folder used to replace a file of that name (deleting it) after the runs."""
    target = tmp_path / "out"
    target.write_text("precious")
    runner = FakeRunner()
    with pytest.raises(InputError) as exc:
        table2.run_table2(config, target, runner=runner)
    assert exc.value.field == "out" and runner.calls == []
    assert target.read_text() == "precious"
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_other_trajectories_are_refused_before_anything_runs(tmp_path, config):
    cfg = replace(config, trajectory=ec.TrajectoryConfig(0.1, 1.0, 0.2))
    runner = FakeRunner()
    with pytest.raises(InputError) as exc:
        table2.run_table2(cfg, tmp_path / "out", runner=runner)
    assert exc.value.field == "trajectory" and runner.calls == []
    assert not (tmp_path / "out").exists()


def test_progress_reports_each_controller_with_speed_and_eta():
    stream = io.StringIO()
    p = table2.Progress(["pid-fpga", "vdc"], 1.0, stream=stream, every=0.0)
    p.begin("pid-fpga")
    p(0.25, 1.0)
    p.end("pid-fpga", {"rho_s": 1e-3, "max_tip_error_m": 5e-4})
    p.begin("vdc")
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("[1/2] pid-fpga: 1 s simulated")
    assert "0.250/1 s simulated" in lines[1] and "RTF" in lines[1] and "ETA" in lines[1]
    assert "pid-fpga: rho 0.001 s" in lines[2] and "ETA" in lines[2]
    assert lines[3].startswith("[2/2] vdc") and "ETA" in lines[3]


def test_cli_prints_progress_unless_quiet(tmp_path, monkeypatch, capsys):
    import mrm_cosim.cosim.track as track

    monkeypatch.setattr(track, "run_track", FakeRunner())
    cfg = tmp_path / "c.toml"
    cfg.write_text("[experiment]\nduration = 0.01\ncontrollers = ['pid-fpga', 'vdc']\n")
    assert cli.main(["run", "table2", "--config", str(cfg), "--out", str(tmp_path / "a"),
                     "--seed", "3"]) == 0
    out, err = capsys.readouterr()
    assert "[2/2] vdc" in err and "| VDC with embedded FPGA" in out
    assert json.loads((tmp_path / "a" / "summary.json").read_text())["seed"] == 3
    assert cli.main(["run", "table2", "--config", str(cfg), "--out", str(tmp_path / "b"),
                     "--quiet", "--duration", "0.005"]) == 0
    assert capsys.readouterr() == ("", "")
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["duration_s"] == 0.005


def test_cli_rejects_an_unknown_backend_naming_the_flag(tmp_path, capsys):
    code = cli.main(["run", "table2", "--backend", "fpga", "--out", str(tmp_path / "o")])
    assert code == 2 and "--backend" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_real_short_run_of_the_three_controllers(tmp_path):
    """The gateware in the loop for 3 ms per controller on the fastest backend."""
    backend = "model" if "model" in BACKENDS else "compiled"
    cfg = ec.load().with_overrides(backend=backend, duration=0.003, seed=1)
    summary = table2.run_table2(cfg, tmp_path / "out", runner=run_track)
    for c, s in summary["controllers"].items():
        assert s["overruns"] == 0 and s["link_errors"] == 0, c
        assert s["max_joint_error_rad"] < 1e-3
    timeline = json.loads((tmp_path / "out" / "vdc" / "timeline.json").read_text())
    done = [p for p in timeline if p["complete"]]
    assert len(done) >= 2
    for p in done:
        ev = p["events"]
        assert p["start_cycle"] < ev["A_done"] < ev["B_sent"] < ev["C_done"] < ev["D_sent"] \
            < p["start_cycle"] + 50_000


def test_track_writes_its_gantt_timeline(tmp_path, capsys):
    backend = "model" if "model" in BACKENDS else "compiled"
    out = tmp_path / "track"
    assert cli.main(["run", "track", "--controller", "vdc", "--backend", backend,
                     "--duration", "0.003", "--out", str(out), "--quiet"]) == 0
    assert capsys.readouterr() == ("", "")
    assert (out / "timeline.png").read_bytes()[:4] == b"\x89PNG"
    timeline = json.loads((out / "timeline.json").read_text())
    assert any(p["complete"] for p in timeline)


def _pid_runner(*args, **kwargs):
    """run_track, saying which process ran it (module level: the process executor pickles
    the runner)."""
    result, summary = run_track(*args, **kwargs)
    return result, dict(summary, pid=os.getpid())


def _refuse(robot, controller, *args, **kwargs):
    raise InputError("gains.k_j", "too large for the node's word")


def test_side_by_side_runs_give_the_same_results_as_one_after_the_other(tmp_path):
    """jobs=2 runs the controllers on two worker processes: the gateware-in-the-loop results
    (trace hashes, every summary figure but the wall time) and the table are those of the
    sequential run."""
    backend = "model" if "model" in BACKENDS else "compiled"
    cfg = ec.load().with_overrides(backend=backend, duration=0.003, seed=2)
    runner = _pid_runner
    stream = io.StringIO()
    progress = table2.Progress(cfg.controllers, cfg.duration, stream=stream, every=0.0)
    one = table2.run_table2(cfg, tmp_path / "one", runner=runner)
    two = table2.run_table2(cfg, tmp_path / "two", runner=runner, jobs=2, progress=progress)
    assert {s["pid"] for s in one["controllers"].values()} == {os.getpid()}
    pids = {s["pid"] for s in two["controllers"].values()}
    assert os.getpid() not in pids and 1 <= len(pids) <= 2     # two workers, reused
    volatile = {"wall_s", "rtf", "pid"}
    for c in cfg.controllers:
        a, b = one["controllers"][c], two["controllers"][c]
        assert {k: v for k, v in a.items() if k not in volatile} == \
            {k: v for k, v in b.items() if k not in volatile}, c
    assert (tmp_path / "one" / "table2.md").read_text() == \
        (tmp_path / "two" / "table2.md").read_text()
    for c in cfg.controllers:
        assert (tmp_path / "one" / c / "trace.csv").read_bytes() == \
            (tmp_path / "two" / c / "trace.csv").read_bytes()
    # the comparison figures, drawn side by side on forked processes with jobs > 1: the same
    # bytes as drawn one after the other
    for name in ("fig4_tracking.png", "fig5_errors.png", "torques.png"):
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "two" / name).read_bytes()
    lines = stream.getvalue().splitlines()
    assert sum(line.startswith("[") for line in lines) == len(cfg.controllers)
    for c in cfg.controllers:
        assert any(line.strip().startswith(f"{c}: rho") for line in lines), c
        assert any(line.strip().startswith(f"{c}: 0.") and "simulated" in line
                   for line in lines), c             # the children's progress, named


def test_a_failure_in_a_side_by_side_run_leaves_no_folder(tmp_path, config):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError, match="pid-fpga run failed"):
        table2.run_table2(config, out, runner=FakeRunner(fail_on="pid-fpga"), jobs=2)
    assert not out.exists()

    with pytest.raises(InputError) as e:
        table2.run_table2(config, out, runner=_refuse, jobs=3)
    assert e.value.field == "gains.k_j" and not out.exists()


def test_cli_refuses_a_bad_jobs_count(tmp_path, capsys):
    code = cli.main(["run", "table2", "--jobs", "0", "--out", str(tmp_path / "o")])
    assert code == 2 and "--jobs" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_table2_runs_one_process_per_controller_on_two_cores_or_more():
    """Three equal runs on two cores end in 1.5 run times side by side, in 2 when each core
    takes whole runs: one process per controller wherever there are two cores; one core runs
    them in turn."""
    from mrm_cosim.mrm.commands.run import table2_jobs

    assert table2_jobs(3, cores=2) == 3
    assert table2_jobs(3, cores=16) == 3
    assert table2_jobs(2, cores=2) == 2
    assert table2_jobs(3, cores=1) == 1
