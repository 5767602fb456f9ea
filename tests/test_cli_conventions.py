"""The command line's conventions: exit codes, interrupts and workers, standard output that
cannot be written, --json, -v/-q, help pages, repeated flags, output targets that are not
ours to replace, and ``mrm run track`` as the ``vdc`` row of ``mrm run table2``."""

import json
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

import mrm_cosim.cosim.track as track_module
from mrm_cosim.cosim import experiment_config as ec
from mrm_cosim.errors import InputError
from mrm_cosim.mrm import cli
from mrm_cosim.results import MARKER, OWNER, atomic_output_dir, atomic_write_text, remove_stale
from tests.test_table2 import FakeRunner

MRM = [sys.executable, "-m", "mrm_cosim"]


def _mrm(*argv, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([*MRM, *argv], capture_output=True, text=True, timeout=300, **kwargs)


class Runner(FakeRunner):
    """FakeRunner taking run_track's keyword arguments; ``unclean`` controllers overrun."""

    def __init__(self, unclean=()):
        super().__init__()
        self.unclean = set(unclean)

    def __call__(self, robot, controller, backend, duration, seed, gains=None, timing=None,
                 plant_config=None, progress=None, **kwargs):
        result, summary = super().__call__(robot, controller, backend, duration, seed, gains,
                                           timing, plant_config, progress)
        if controller in self.unclean:
            summary["overruns"] = 2
        return result, summary


def _config_file(tmp_path, controllers=("pid-fpga", "vdc")) -> Path:
    path = tmp_path / "c.toml"
    path.write_text(f"[experiment]\nduration = 0.01\ncontrollers = {list(controllers)!r}\n")
    return path


# --- mrm run track is the vdc row of mrm run table2 ------------------------------------
def test_track_with_the_default_config_is_the_vdc_row_of_table2(tmp_path, capsys):
    """Same duration and seed, model backend: the same trace hash. ``track`` reads the
    same configs/table2.toml as ``table2`` (the tuned gains λ = 20, k_j = 51.2, K = 38.9, not
    the code's defaults), and writes the resolved configuration, which loads back equal."""
    vdc_only = tmp_path / "vdc.toml"
    vdc_only.write_text(ec.load().to_toml().replace(
        'controllers = ["pid-1khz", "pid-fpga", "vdc"]', 'controllers = ["vdc"]'))
    assert cli.main(["run", "track", "--controller", "vdc", "--backend", "model",
                     "--duration", "0.05", "--out", str(tmp_path / "track"), "-q"]) == 0
    assert cli.main(["run", "table2", "--config", str(vdc_only), "--backend", "model",
                     "--duration", "0.05", "--out", str(tmp_path / "t2"), "-q"]) == 0
    track = json.loads((tmp_path / "track" / "summary.json").read_text())
    table = json.loads((tmp_path / "t2" / "summary.json").read_text())["controllers"]["vdc"]
    assert track["trace_sha256"] == table["trace_sha256"]
    resolved = ec.load(tmp_path / "track" / "config.toml")
    assert resolved == ec.load(tmp_path / "t2" / "config.toml")
    assert resolved.gains == ec.load().gains and resolved.gains.lam == 20.0


def test_track_takes_its_experiment_from_config(tmp_path, monkeypatch):
    """Gains, timing, plant, seed and backend of --config reach run_track; flags override."""
    calls = []

    def runner(*args, **kwargs):
        calls.append((args, kwargs))
        return Runner()(*args, **kwargs)

    monkeypatch.setattr(track_module, "run_track", runner)
    cfg = tmp_path / "c.toml"
    cfg.write_text("[experiment]\nbackend = 'pysim'\nseed = 4\nduration = 0.01\n"
                   "[gains]\nlam = 123.0\n[timing]\nperiod_cycles = 100000\n")
    assert cli.main(["run", "track", "--config", str(cfg), "--out", str(tmp_path / "a"),
                     "-q"]) == 0
    (robot, controller, backend, duration, seed), kw = calls[0]
    assert (controller, backend, duration, seed) == ("vdc", "pysim", 0.01, 4)
    assert kw["gains"].lam == 123.0 and kw["timing"].period_cycles == 100_000
    assert cli.main(["run", "track", "--config", str(cfg), "--seed", "9", "--backend", "model",
                     "--out", str(tmp_path / "b"), "-q"]) == 0
    assert calls[1][0][2:] == ("model", 0.01, 9)
    written = ec.load(tmp_path / "b" / "config.toml")
    assert (written.seed, written.backend, written.controllers) == (9, "model", ("vdc",))


# --- exit codes ----------------------------------------------------------------------------
def test_a_run_that_is_not_clean_exits_3_and_says_why(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(track_module, "run_track", Runner(unclean={"pid-fpga"}))
    cfg = _config_file(tmp_path)
    assert cli.main(["run", "table2", "--config", str(cfg), "--out", str(tmp_path / "a"),
                     "-q"]) == cli.EXIT_NOT_CLEAN == 3
    err = capsys.readouterr().err
    assert err == "mrm run table2: NOT A CLEAN RUN: pid-fpga: 2 periods overrun\n"
    assert (tmp_path / "a" / "summary.json").exists()        # the record is written
    assert cli.main(["run", "track", "--controller", "pid-fpga", "--config", str(cfg),
                     "--out", str(tmp_path / "b"), "-q"]) == 3
    assert "NOT A CLEAN RUN: 2 periods overrun" in capsys.readouterr().err
    assert cli.main(["run", "track", "--controller", "vdc", "--config", str(cfg),
                     "--out", str(tmp_path / "c"), "-q"]) == 0


def test_json_prints_the_summary_on_stdout(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(track_module, "run_track", Runner())
    cfg = _config_file(tmp_path)
    assert cli.main(["run", "table2", "--config", str(cfg), "--out", str(tmp_path / "a"),
                     "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out) == json.loads((tmp_path / "a" / "summary.json").read_text())
    assert "[2/2] vdc" in err                                  # progress stays on stderr
    assert cli.main(["run", "track", "--config", str(cfg), "--out", str(tmp_path / "b"),
                     "--json", "-q"]) == 0
    assert json.loads(capsys.readouterr().out)["controller"] == "vdc"
    assert cli.main(["run", "preview", "--duration", "0.01", "--out", str(tmp_path / "p"),
                     "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["robot"] == "mrm3"


@pytest.mark.parametrize("flags, level", [([], "INFO"), (["-q"], "ERROR"), (["-v"], "DEBUG"),
                                          (["--verbose"], "DEBUG")])
def test_verbosity_flags_set_the_logging_level(tmp_path, monkeypatch, capsys, flags, level):
    import logging

    monkeypatch.setattr(track_module, "run_track", Runner())
    assert cli.main(["run", "table2", "--config", str(_config_file(tmp_path)), "--out",
                     str(tmp_path / "a"), *flags]) == 0
    assert logging.getLevelName(logging.getLogger("mrm_cosim").level) == level
    err = capsys.readouterr().err
    assert ("[1/2] pid-fpga" in err) == (level != "ERROR")
    assert ("experiment: {" in err) == (level == "DEBUG")


# --- help pages and repeated flags -------------------------------------------------------
def test_every_help_page_shows_defaults_and_an_example():
    for leaf in cli.leaf_parsers(cli.build_parser()):
        text = leaf.format_help()
        assert "example:\n  mrm " in text, leaf.prog
        for action in leaf._actions:
            shown = action.default not in (None, [], "==SUPPRESS==") and not isinstance(
                action.default, bool | int) and action.option_strings
            if shown:
                assert f"(default: {action.default})" in " ".join(text.split()), \
                    (leaf.prog, action.dest)


@pytest.mark.parametrize("argv, flag", [
    (["run", "preview", "--duration", "1", "--duration", "2"], "--duration"),
    (["run", "track", "--backend", "model", "--backend", "pysim"], "--backend"),
    (["robot", "show", "mrm3", "--json", "--json"], "--json"),
    (["plan", "quintic", "--q0", "0", "--qf", "1", "--tf", "1", "--tf", "2"], "--tf"),
])
def test_a_flag_given_twice_is_refused_naming_it(tmp_path, capsys, argv, flag):
    with pytest.raises(SystemExit) as e:
        cli.main([*argv, "--out", str(tmp_path / "o")] if argv[0] == "run" else argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {flag}: given more than once" in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_a_param_given_twice_is_refused_naming_it(tmp_path, capsys):
    assert cli.main(["hdl", "verilog", "--top", "spw_codec", "--out", str(tmp_path / "v"),
                     "--param", "slots=1", "--param", "slots=2"]) == 2
    assert capsys.readouterr().err == "mrm hdl: error: --param slots: given more than once\n"
    assert cli.main(["bench", "--backend", "model", "--backend", "model"]) == 2
    assert "--backend: 'model' given more than once" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


# --- output targets ------------------------------------------------------------------------
def _targets(tmp_path) -> list[tuple[str, Path]]:
    """A FIFO, a symbolic link to a file that must stay as it is, and one to a folder, all in
    ``tmp_path``: (what the refusal calls it, path)."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    kept = tmp_path / "kept.txt"
    kept.write_text("precious")
    link = tmp_path / "link"
    link.symlink_to(kept)
    (tmp_path / "real").mkdir()
    dir_link = tmp_path / "dirlink"
    dir_link.symlink_to(tmp_path / "real")
    return [("a FIFO", fifo), ("a symbolic link", link), ("a symbolic link", dir_link)]


def _unchanged(tmp_path):
    assert stat.S_ISFIFO((tmp_path / "fifo").lstat().st_mode)
    assert (tmp_path / "link").is_symlink() and (tmp_path / "dirlink").is_symlink()
    assert (tmp_path / "kept.txt").read_text() == "precious"
    assert list((tmp_path / "real").iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dirlink", "fifo", "kept.txt",
                                                           "link", "real"]


@pytest.mark.parametrize("command", [
    ["plan", "quintic", "--q0", "0", "--qf", "1", "--tf", "1", "--samples"],
    ["plan", "line", "examples/line_vertical.toml", "--samples"],
])
def test_samples_to_a_fifo_or_a_link_are_refused(tmp_path, capsys, monkeypatch, command):
    monkeypatch.chdir(Path(__file__).parents[1])
    for kind, target in _targets(tmp_path):
        assert cli.main([*command, str(target)]) == 2
        err = capsys.readouterr().err
        assert f"--samples: '{target}' is {kind}" in err and err.count("\n") == 1
    _unchanged(tmp_path)


@pytest.mark.parametrize("command", [["run", "preview", "--duration", "0.01"],
                                     ["run", "table2", "--jobs", "1", "--duration", "0.01"]])
def test_out_as_a_fifo_a_link_or_a_folder_not_ours_is_refused(tmp_path, capsys, monkeypatch,
                                                              command):
    monkeypatch.setattr(track_module, "run_track", Runner())
    for kind, target in _targets(tmp_path):
        assert cli.main([*command, "--out", str(target), "-q"]) == 2
        assert f"--out: '{target}' is {kind}" in capsys.readouterr().err
    _unchanged(tmp_path)
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("years of work")
    assert cli.main([*command, "--out", str(mine), "-q"]) == 2
    assert "holds other files than results" in capsys.readouterr().err
    assert [p.name for p in mine.iterdir()] == ["thesis.tex"]


def test_verilog_over_a_link_or_fifo_is_refused(tmp_path, capsys):
    out = tmp_path / "v"
    out.mkdir()
    os.mkfifo(out / "spw_codec.v")
    assert cli.main(["hdl", "verilog", "--top", "spw_codec", "--out", str(out)]) == 2
    assert "--out: " in capsys.readouterr().err
    assert stat.S_ISFIFO((out / "spw_codec.v").lstat().st_mode)


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_dev_full_as_samples_is_refused_and_left_a_device(tmp_path, capsys):
    """Run as root, ``--samples /dev/full`` replaced the device node with a CSV file."""
    before = os.lstat("/dev/full")
    assert stat.S_ISCHR(before.st_mode)
    assert cli.main(["plan", "quintic", "--q0", "0", "--qf", "1", "--tf", "1",
                     "--samples", "/dev/full"]) == 2
    assert "is a character device" in capsys.readouterr().err
    after = os.lstat("/dev/full")
    assert stat.S_ISCHR(after.st_mode) and after.st_rdev == before.st_rdev


def test_atomic_write_text_refuses_what_became_a_link_meanwhile(tmp_path):
    target = tmp_path / "a.csv"
    target.write_text("old")
    atomic_write_text(target, "new")
    assert target.read_text() == "new"
    target.unlink()
    target.symlink_to(tmp_path / "elsewhere")
    with pytest.raises(InputError, match="symbolic link"):
        atomic_write_text(target, "x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv"]


# --- what a killed run left behind ---------------------------------------------------------
def _dead_pid() -> int:
    proc = subprocess.Popen(["true"])
    proc.wait()
    return proc.pid


def test_stale_temporary_folders_of_dead_runs_are_removed_and_no_others(tmp_path):
    dead = tmp_path / ".res.dead"
    dead.mkdir()
    (dead / OWNER).write_text(f"{_dead_pid()} 1\n")
    (dead / "half.json").write_text("{")
    alive = tmp_path / ".res.alive"
    alive.mkdir()
    (alive / OWNER).write_text(f"{os.getpid()} -\n")
    unowned = tmp_path / ".res.unowned"
    unowned.mkdir()
    stale_file = tmp_path / f".a.csv.{_dead_pid()}.xyz.tmp"
    stale_file.write_text("half")
    put_aside = tmp_path / ".res.old.abc"
    (put_aside / "res").mkdir(parents=True)
    (put_aside / "res" / "summary.json").write_text("{}")
    (put_aside / OWNER).write_text(f"{_dead_pid()} 1\n")
    removed = remove_stale(tmp_path / "res") + remove_stale(tmp_path / "a.csv")
    assert sorted(p.name for p in removed) == sorted([dead.name, put_aside.name,
                                                       stale_file.name])
    assert sorted(p.name for p in tmp_path.iterdir()) == [".res.alive", ".res.unowned", "res"]
    assert (tmp_path / "res" / "summary.json").read_text() == "{}"   # put back


# --- interrupts ----------------------------------------------------------------------------
def _children(pid: int) -> list[int]:
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(entry.name))
    return out


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _start_table2(tmp_path) -> tuple[subprocess.Popen, list[int], Path]:
    """``mrm run table2`` with two workers, an earlier result folder at its --out; returns
    once both workers run (their pids)."""
    out = tmp_path / "t2"
    with atomic_output_dir(out) as tmp:
        (tmp / "summary.json").write_text('{"earlier": true}')
    proc = subprocess.Popen([*MRM, "run", "table2", "--backend", "model", "--duration", "0.3",
                             "--jobs", "2", "--out", str(out), "-q"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 120
    while len(workers := _children(proc.pid)) < 2:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "no workers"
        time.sleep(0.1)
    time.sleep(1.0)
    return proc, workers, out


def _earlier_results_intact(tmp_path, out):
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t2"]      # no .t2.xxxx left
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "summary.json"]
    assert json.loads((out / "summary.json").read_text()) == {"earlier": True}


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
@pytest.mark.parametrize("signum, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_an_interrupt_stops_the_workers_and_leaves_earlier_results(tmp_path, signum, code):
    proc, workers, out = _start_table2(tmp_path)
    os.killpg(proc.pid, signum)         # as a terminal's Ctrl-C: the parent's whole group
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == code
    assert stdout == "" and stderr.count("\n") == 1 and "Traceback" not in stderr
    assert stderr.startswith("mrm run: ") and "earlier results kept" in stderr
    assert not [w for w in workers if _running(w)]
    _earlier_results_intact(tmp_path, out)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_workers_die_with_a_killed_parent_and_the_next_run_clears_its_folder(tmp_path):
    proc, workers, out = _start_table2(tmp_path)
    proc.kill()
    proc.communicate(timeout=60)
    deadline = time.monotonic() + 10
    while [w for w in workers if _running(w)]:
        assert time.monotonic() < deadline, "workers outlived their parent"
        time.sleep(0.1)
    assert len([p for p in tmp_path.iterdir() if p.name.startswith(".t2.")]) == 1
    result = _mrm("run", "table2", "--out", str(out), "--duration", "0.01", "--seed", "-1")
    assert result.returncode == 2                      # refused: nothing made, nothing removed
    assert len([p for p in tmp_path.iterdir() if p.name.startswith(".t2.")]) == 1
    with atomic_output_dir(out) as tmp:                # the next run writing there
        (tmp / "summary.json").write_text('{"earlier": true}')
    _earlier_results_intact(tmp_path, out)


# --- standard output -----------------------------------------------------------------------
@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_full_standard_output_ends_with_one_line():
    with open("/dev/full", "w") as full:
        result = subprocess.run([*MRM, "robot", "urdf", "mrm3"], stdout=full,
                                stderr=subprocess.PIPE, text=True, timeout=120)
    assert result.returncode == 1
    assert result.stderr == ("mrm robot: error: standard output not writable (No space left "
                             "on device)\n")


def test_a_closed_standard_output_ends_with_one_line():
    read, write = os.pipe()
    os.close(read)                      # nobody will read: every write is EPIPE
    try:
        result = subprocess.run([*MRM, "robot", "urdf", "mrm3"], stdout=write,
                                stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write)
    assert result.returncode == 1
    assert result.stderr == "mrm robot: error: standard output closed (broken pipe)\n"
