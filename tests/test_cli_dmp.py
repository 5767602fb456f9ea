"""``mrm dmp learn`` / ``mrm dmp rollout``: demo → TOML → rollout, goal and τ scaling, the
file's bit-exact round trip, the Cartesian path through IK, and outputs that are refused."""

import json
import math
import os
import stat

import numpy as np
import pytest

import mrm_cosim.mrm.cli as cli
from mrm_cosim.master.dmp import learn_dmp
from mrm_cosim.master.dmp_demo import joints_from_poses, read_demo
from mrm_cosim.master.dmp_file import dmp_toml, read_dmp, read_dmp_file, write_dmp
from mrm_cosim.master.kinematics import forward
from mrm_cosim.models.robot import load_robot

DT = 0.005
DURATION = 1.2
#: Bound of the round trip (rollout at the demo's step vs the demo, 20 bases, both joints):
#: the measured worst error is 1.36e-3 rad (joint 2, whose sin³ wiggle 20 Gaussians fit less
#: well; joint 1's is 1.6e-4), the LWR approximation itself (docs/trajectories.md §4.4).
ROUND_TRIP_BOUND = 2e-3


def demo_table() -> np.ndarray:
    """t, q1, q2 at 5 ms over 1.2 s: a minimum-jerk move and a sin² swing (rad)."""
    t = np.arange(round(DURATION / DT) + 1) * DT
    u = t / DURATION
    q1 = 0.3 + 0.8 * (10 * u**3 - 15 * u**4 + 6 * u**5)
    q2 = -0.2 + 0.4 * np.sin(np.pi * u / 2) ** 2 + 0.05 * np.sin(2 * np.pi * u) ** 3
    return np.column_stack([t, q1, q2])


@pytest.fixture
def mrm(capsys):
    """Run ``mrm …`` in-process; returns (exit code, stdout, stderr)."""
    def run(*argv):
        try:
            code = cli.main([str(a) for a in argv])
        except SystemExit as exc:
            code = exc.code
        out, err = capsys.readouterr()
        return code, out, err
    return run


@pytest.fixture
def demo_csv(tmp_path):
    path = tmp_path / "demo.csv"
    rows = ["t_s,q1_rad,q2_rad,note"] + [",".join(map(repr, r.tolist())) + ",0"
                                         for r in demo_table()]
    path.write_text("\n".join(rows) + "\n")
    return path


def learn(mrm, demo_csv, tmp_path, *flags):
    out = tmp_path / "dmp.toml"
    code, stdout, err = mrm("dmp", "learn", demo_csv, "--basis", "20", "--columns",
                            "q1_rad,q2_rad", "--out", out, "--json", *flags)
    assert code == 0 and err == "", err
    return out, json.loads(stdout)


def rollout(mrm, dmp_file, tmp_path, *flags, name="r.csv"):
    samples = tmp_path / name
    code, stdout, err = mrm("dmp", "rollout", dmp_file, "--samples", samples, "--json", *flags)
    assert code == 0 and err == "", err
    data = np.loadtxt(samples, delimiter=",", skiprows=1, ndmin=2)
    return json.loads(stdout), data, samples.read_text().splitlines()[0].split(",")


def test_learn_then_rollout_reproduces_the_demo(mrm, demo_csv, tmp_path):
    out, summary = learn(mrm, demo_csv, tmp_path)
    assert summary["n_dof"] == 2 and summary["basis"] == 20 and summary["samples"] == 241
    assert summary["tau_s"] == pytest.approx(DURATION, rel=1e-12)
    assert summary["columns"] == ["q1_rad", "q2_rad"]
    fig, data, header = rollout(mrm, out, tmp_path, "--dt", str(DT))
    assert header == ["t_s", "x1", "x2", "xd1", "xd2", "xdd1", "xdd2"]
    demo = demo_table()
    assert data.shape == (241, 7)
    np.testing.assert_allclose(data[:, 0], demo[:, 0], atol=1e-12)
    error = np.abs(data[:, 1:3] - demo[:, 1:3])
    assert error.max() < ROUND_TRIP_BOUND
    # the summary's fit is the same comparison
    rmse = np.sqrt(np.mean(error**2, axis=0))
    np.testing.assert_allclose(summary["fit_rmse"], rmse, rtol=1e-9)
    assert fig["duration_s"] == pytest.approx(DURATION) and fig["steps"] == 240
    # at 1 ms the same path (the recurrence converges to the ODE), every 5th sample
    _, fine, _ = rollout(mrm, out, tmp_path, "--dt", "0.001", name="fine.csv")
    assert np.abs(fine[::5, 1:3] - demo[:, 1:3]).max() < 2 * ROUND_TRIP_BOUND


def test_tau_scales_the_duration_and_plays_the_same_path(mrm, demo_csv, tmp_path):
    out, _ = learn(mrm, demo_csv, tmp_path)
    base, x1, _ = rollout(mrm, out, tmp_path, "--dt", "0.001", name="a.csv")
    slow, x2, _ = rollout(mrm, out, tmp_path, "--tau", str(2 * DURATION), "--dt", "0.002",
                          name="b.csv")
    assert slow["duration_s"] == pytest.approx(2 * base["duration_s"], rel=1e-12)
    assert slow["steps"] == base["steps"] == 1200
    # only Δt/τ enters the recurrence: twice τ at twice Δt is the same sequence of positions
    np.testing.assert_array_equal(x2[:, 1:3], x1[:, 1:3])
    np.testing.assert_allclose(x2[:, 0], 2 * x1[:, 0], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(x2[:, 3:5], x1[:, 3:5] / 2, rtol=1e-12, atol=1e-15)
    assert slow["end"] == base["end"]


def test_a_new_goal_is_reached_and_scales_the_shape(mrm, demo_csv, tmp_path):
    out, _ = learn(mrm, demo_csv, tmp_path)
    demo = demo_table()
    x0, g = demo[0, 1:3], demo[-1, 1:3]
    new_goal = np.array([1.5, -0.6])
    base, xb, _ = rollout(mrm, out, tmp_path, name="a.csv")
    fig, xg, _ = rollout(mrm, out, tmp_path, "--goal", ",".join(map(repr, new_goal.tolist())),
                         name="b.csv")
    assert fig["goal"] == new_goal.tolist()
    kappa = (new_goal - x0) / (g - x0)
    # the end point scales like the goal and lands as close to it as the demo's end does
    end_gap = np.abs(np.array(fig["end"]) - new_goal)
    assert np.all(end_gap <= np.abs(kappa) * np.abs(np.array(base["end"]) - g) + 1e-12)
    assert np.all(end_gap < 1e-3 * np.abs(new_goal - x0))
    # the whole path is the demo's, scaled about the start by κ per joint (Ijspeert 2013)
    np.testing.assert_allclose(xg[:, 1:3] - x0, kappa * (xb[:, 1:3] - x0), rtol=1e-9,
                               atol=1e-12)
    # the path reaches the new goal as the phase dies out
    code, stdout, _ = mrm("dmp", "rollout", out, "--goal", "1.5,-0.6", "--duration", "6",
                          "--json")
    assert code == 0
    far = json.loads(stdout)
    assert far["duration_s"] == 6.0 and far["tau_s"] == pytest.approx(DURATION)
    assert np.abs(np.array(far["end"]) - new_goal).max() < 1e-5


def test_the_file_round_trip_is_bit_exact(tmp_path):
    demo = demo_table()
    dmp = learn_dmp(demo[:, 1:], DT, 17, alpha=31.7, alpha_s=2.3, overlap=0.37)
    path = tmp_path / "d.toml"
    meta = {"source": "demo.csv", "basis": 17, "alpha": 31.7, "alpha_s": 2.3, "dt": DT,
            "fit_rmse": [1e-4, 3.3e-300], "kind": "joint"}
    write_dmp(path, dmp, meta)
    back, prov = read_dmp_file(path)
    for name in ("weights", "centers", "widths", "x0", "g", "xd0", "goal_scaling"):
        a, b = getattr(dmp, name), getattr(back, name)
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), name
    for name in ("alpha", "beta", "alpha_s", "tau"):
        assert math.copysign(1, getattr(back, name)) == 1
        assert getattr(back, name).hex() == getattr(dmp, name).hex(), name
    assert prov == meta
    assert dmp_toml(back, prov) == path.read_text()            # and writes back identically
    np.testing.assert_array_equal(back.rollout(0.001).x, dmp.rollout(0.001).x)


def test_learn_writes_the_provenance(mrm, demo_csv, tmp_path):
    out, _ = learn(mrm, demo_csv, tmp_path, "--alpha", "30", "--alpha-s", "3")
    dmp, prov = read_dmp_file(out)
    assert prov["source"] == str(demo_csv) and prov["kind"] == "joint"
    assert (prov["basis"], prov["alpha"], prov["alpha_s"], prov["overlap"]) == (20, 30.0, 3.0,
                                                                                0.2)
    assert prov["dt"] == pytest.approx(DT, rel=1e-12) and prov["samples"] == 241
    assert (dmp.alpha, dmp.beta, dmp.alpha_s) == (30.0, 7.5, 3.0)
    code, out_text, _ = mrm("dmp", "learn", demo_csv, "--basis", "5", "--out", out)
    assert code == 0 and "fit_rmse" in out_text                 # a regular file is replaced
    assert read_dmp(out).n_dof == 3                             # every column but t


def test_rollout_plot_and_text_summary(mrm, demo_csv, tmp_path):
    out, _ = learn(mrm, demo_csv, tmp_path)
    png = tmp_path / "r.png"
    code, stdout, err = mrm("dmp", "rollout", out, "--plot", png, "--tau", "2")
    assert code == 0 and err == ""
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "duration_s" in stdout and "end_minus_goal" in stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.csv", "dmp.toml", "r.png"]


def test_cartesian_demo_is_solved_on_one_branch_and_learned(mrm, tmp_path):
    robot = load_robot("mrm6")
    t = np.arange(101) * 0.01
    rows = ["t,x,y,z,qw,qx,qy,qz"]
    from mrm_cosim.master.quaternion import from_matrix

    q_path = robot.home + np.outer(np.sin(np.pi * t / 2) ** 2, [0.3, -0.2, 0.25, 0.4, -0.3, 0.5])
    for tk, q in zip(t, q_path, strict=True):
        T = forward(robot, q)
        rows.append(",".join(repr(float(v)) for v in [tk, *T[:3, 3],
                                                      *from_matrix(T[:3, :3])]))
    path = tmp_path / "cart.csv"
    path.write_text("\n".join(rows) + "\n")
    demo = read_demo(path, cartesian=True)
    Q = joints_from_poses(robot, demo)
    np.testing.assert_allclose(Q, q_path, atol=1e-9)           # the branch the path came from
    out = tmp_path / "c.toml"
    code, stdout, err = mrm("dmp", "learn", path, "--cartesian", "--robot", "mrm6", "--basis",
                            "15", "--out", out, "--json")
    assert code == 0 and err == ""
    summary = json.loads(stdout)
    assert summary["n_dof"] == 6 and max(summary["fit_max_error"]) < 2e-3   # measured 1.14e-3
    dmp, prov = read_dmp_file(out)
    assert prov["kind"] == "cartesian" and prov["robot"] == "mrm6"
    np.testing.assert_array_equal(dmp.x0, Q[0])


def _targets(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    kept = tmp_path / "kept.txt"
    kept.write_text("precious")
    link = tmp_path / "link"
    link.symlink_to(kept)
    return [("a FIFO", fifo), ("a symbolic link", link)]


@pytest.mark.parametrize("flag", ["--out", "--samples", "--plot"])
def test_outputs_to_a_fifo_or_a_link_are_refused(mrm, demo_csv, tmp_path, flag):
    dmp_file, _ = learn(mrm, demo_csv, tmp_path)
    for kind, target in _targets(tmp_path):
        if flag == "--out":
            argv = ["dmp", "learn", demo_csv, "--basis", "5", "--out", target]
        else:
            argv = ["dmp", "rollout", dmp_file, flag, target]
        code, out, err = mrm(*argv)
        assert code == 2 and out == ""
        assert f"{flag}: '{target}' is {kind}" in err and err.count("\n") == 1
    assert stat.S_ISFIFO((tmp_path / "fifo").lstat().st_mode)
    assert (tmp_path / "link").is_symlink() and (tmp_path / "kept.txt").read_text() == "precious"
    assert not list(tmp_path.glob(".*tmp"))
