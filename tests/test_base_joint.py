"""The base joint's own controller settings (docs/experiments.md "Tuning": on the compliant
plant joint 1's motor-side encoder sees the motor alone above the gear's anti-resonance):
the PIDs' base-joint pole reaches joint 1 alone — in the node's uploads and in the master's
1 kHz PID — VDC's ``vdc_base_fb`` scales joint 1's error in the master's link level and node
1's uploaded link gain alone,
and the defaults are today's controllers."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mrm_cosim.cosim import track, tune
from mrm_cosim.cosim.experiment_config import load, loads
from mrm_cosim.master.uploads import Gains, node_uploads, pid_gains
from mrm_cosim.master.vdc import propagate_velocities, required_velocities
from mrm_cosim.models.robot import load_robot

ROOT = Path(__file__).resolve().parents[1]
ROBOT = load_robot("mrm3")


def test_the_base_pole_sets_joint_1_alone_and_zero_means_the_others_pole():
    both = pid_gains(ROBOT, 10.0, 3.0)
    for name in ("kp", "ki", "kd"):
        assert both[name][0] == pid_gains(ROBOT, 3.0)[name][0]
        np.testing.assert_array_equal(both[name][1:], pid_gains(ROBOT, 10.0)[name][1:])
        np.testing.assert_array_equal(pid_gains(ROBOT, 10.0, 0.0)[name],
                                      pid_gains(ROBOT, 10.0)[name])


def _by_node(uploads):
    return {k: [(t, p) for d, t, p in uploads if d == k] for k in (1, 2, 3)}


def test_the_fpga_base_pole_reaches_node_1s_uploads_alone():
    g = replace(Gains(), pid_fpga_hz=10.0, pid_fpga_base_hz=3.0)
    got = _by_node(node_uploads(ROBOT, "pid-fpga", g))
    at3 = _by_node(node_uploads(ROBOT, "pid-fpga", replace(Gains(), pid_fpga_hz=3.0)))
    at10 = _by_node(node_uploads(ROBOT, "pid-fpga", replace(Gains(), pid_fpga_hz=10.0)))
    assert got[1] == at3[1] != at10[1]
    assert got[2] == at10[2] and got[3] == at10[3]
    # the default (0) uploads what the node got before the setting existed
    assert node_uploads(ROBOT, "pid-fpga", replace(Gains(), pid_fpga_hz=10.0)) == \
        node_uploads(ROBOT, "pid-fpga", replace(Gains(), pid_fpga_hz=10.0,
                                                pid_fpga_base_hz=10.0))


def test_the_1khz_base_pole_and_the_vdc_share_reach_the_master(monkeypatch):
    seen = {}

    class Spy(track.Master):
        def __init__(self, *args, **kwargs):
            seen.update(kwargs)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(track, "Master", Spy)
    g = replace(Gains(), pid_1khz_hz=10.0, pid_1khz_base_hz=2.5, vdc_base_fb=0.25)
    track.run_track(ROBOT, "pid-1khz", backend="model", duration=0.002, gains=g)
    for name in ("kp", "ki", "kd"):
        np.testing.assert_array_equal(seen["pid"][name], pid_gains(ROBOT, 10.0, 2.5)[name])
    assert seen["pid"]["kd"][0] == pytest.approx(3 * 2 * np.pi * 2.5 * (
        pid_gains(ROBOT, 1.0)["kd"][0] / (3 * 2 * np.pi)))
    assert seen["base_fb"] == 0.25


def _state(seed):
    rng = np.random.default_rng(seed)
    return [rng.normal(0, s, 3) for s in (0.3, 0.5, 2.0, 0.3, 0.5)]   # q_d, q̇_d, q̈_d, q, q̇


def test_the_vdc_share_1_is_the_papers_required_velocity():
    q_d, qd_d, qdd_d, q, qd = _state(0)
    qd_r, qdd_r, qd_p = required_velocities(q_d, qd_d, qdd_d, q, qd, 34.0)
    np.testing.assert_array_equal(qd_r, qd_d + 34.0 * (q_d - q))
    np.testing.assert_array_equal(qdd_r, qdd_d + 34.0 * (qd_d - qd))
    assert qd_p is qd


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_vdc_share_scales_joint_1s_error_in_every_links_velocity_error(seed):
    """``V_r − V`` of every frame is linear in the share ``w`` of joint 1's error, and at
    ``w = 0`` joint 1's measured velocity and position error do not enter it at all; joints
    2 and 3 are the paper's."""
    q_d, qd_d, qdd_d, q, qd = _state(seed)
    lam = 34.0

    def err(w, qd=qd, q_d=q_d):
        qd_r, qdd_r, qd_p = required_velocities(q_d, qd_d, qdd_d, q, qd, lam, w)
        kin = propagate_velocities(ROBOT, q, qd_p, qd_r, qdd_r)
        return np.array([np.r_[k.Vr_C - k.V_C, k.Vr_A - k.V_A] for k in kin]), qd_r

    e0, r0 = err(0.0)
    assert r0[0] == qd_d[0]
    np.testing.assert_array_equal(r0[1:], qd_d[1:] + lam * (q_d[1:] - q[1:]))
    other = qd.copy()
    other[0] += 0.7
    shifted = q_d.copy()
    shifted[0] += 0.01
    np.testing.assert_allclose(err(0.0, qd=other)[0], e0, atol=1e-12)
    np.testing.assert_allclose(err(0.0, q_d=shifted)[0], e0, atol=1e-12)
    e1 = err(1.0)[0]
    np.testing.assert_allclose(err(0.3)[0], e0 + 0.3 * (e1 - e0), atol=1e-12)
    assert np.abs(e1 - e0).max() > 1e-3              # joint 1's error is really there at 1


def test_the_vdc_share_scales_node_1s_uploaded_link_gain_alone():
    """Node 1 forms its Link a force ``K (V_rA − V_A)`` from its own measured ``q̇_1``: its
    uploaded ``K`` (both links) is ``w K``, so at ``w = 0`` none of joint 1's link-level
    feedback is left; nodes 2–3 upload ``K``, and ``w = 1`` is the paper's upload, byte for
    byte."""
    g = replace(Gains(), K=60.0, vdc_base_fb=1.0)
    paper = node_uploads(ROBOT, "vdc", g)
    assert node_uploads(ROBOT, "vdc", replace(Gains(), K=60.0)) == paper
    for w in (0.0, 0.25):
        got = node_uploads(ROBOT, "vdc", replace(g, vdc_base_fb=w))
        scaled = node_uploads(ROBOT, "vdc", replace(g, K=60.0 * w))
        a, b, p = _by_node(got), _by_node(scaled), _by_node(paper)
        assert a[1] == b[1] != p[1]                  # node 1: the uploads of K = w K
        assert a[2] == p[2] and a[3] == p[3]         # nodes 2-3: K
    # the PIDs' uploads do not depend on w
    for c in ("pid-fpga", "pid-1khz"):
        assert node_uploads(ROBOT, c, replace(g, vdc_base_fb=0.0)) == node_uploads(ROBOT, c, g)


def test_the_settings_load_round_trip_and_default_to_todays_controllers():
    d = Gains()
    assert (d.pid_fpga_base_hz, d.pid_1khz_base_hz, d.vdc_base_fb) == (0.0, 0.0, 1.0)
    g = load(ROOT / "configs" / "table2-rigid.toml").gains
    assert (g.pid_fpga_base_hz, g.pid_1khz_base_hz, g.vdc_base_fb) == (0.0, 0.0, 1.0)
    text = (ROOT / "configs" / "table2-rigid.toml").read_text().replace(
        "[gains]\n", "[gains]\npid_fpga_base_hz = 3.5\npid_1khz_base_hz = 2.0\n"
        "vdc_base_fb = 0.25\n")
    cfg = loads(text)
    assert (cfg.gains.pid_fpga_base_hz, cfg.gains.pid_1khz_base_hz,
            cfg.gains.vdc_base_fb) == (3.5, 2.0, 0.25)
    assert loads(cfg.to_toml()) == cfg


def test_the_shipped_tuning_space_gives_every_controller_one_base_joint_setting():
    spec = tune.load_tune_spec(ROOT / "configs" / "tuning" / "table2.toml")
    base = {"pid-1khz": "gains.pid_1khz_base_hz", "pid-fpga": "gains.pid_fpga_base_hz",
            "vdc": "gains.vdc_base_fb"}
    for c, field in base.items():
        assert field in spec.space[c]
    assert spec.space["pid-1khz"]["gains.pid_1khz_base_hz"] == \
        spec.space["pid-fpga"]["gains.pid_fpga_base_hz"] == (1.0, 60.0)
    assert spec.space["vdc"]["gains.vdc_base_fb"] == (0.0, 1.0)


def _compliant_table(name: str):
    """A shipped Table 2 config on the compliant plant: its gains as ``((1 kHz PID pole, base
    pole), (FPGA PID pole, base pole), (λ, k_j, K, w))`` and its text."""
    path = ROOT / "configs" / name
    cfg = load(path)
    assert cfg.plant.joints == "compliant", name
    g = cfg.gains
    return (((g.pid_1khz_hz, g.pid_1khz_base_hz), (g.pid_fpga_hz, g.pid_fpga_base_hz),
             (g.lam, g.k_j, g.K, g.vdc_base_fb)), path.read_text())


def test_the_compliant_table_carries_tuning_run_4s_choices():
    """configs/table2-compliant.toml: the gains its provenance block names (docs/experiments.md
    "What the tuning found on the compliant plant", run 4), on the compliant plant."""
    gains, text = _compliant_table("table2-compliant.toml")
    assert gains == ((8.73, 2.74), (19.9, 5.02), (59.8, 15.0, 59.7, 0.0016))
    for line in ("pid_1khz_hz = 8.73, pid_1khz_base_hz = 2.74", "FEASIBLE (7 of 24)",
                 "pid_fpga_hz = 19.9, pid_fpga_base_hz = 5.02",
                 "lam = 59.8, k_j = 15, K = 59.7, vdc_base_fb = 0.0016"):
        assert line in text


def test_the_default_table_is_compliant_with_tuning_run_5s_choices():
    """configs/table2.toml: the compliant plant and the gains tuning run 5 chose and wrote
    (``--apply``), feasible for all three controllers, with their provenance; the rigid table
    stays runnable (configs/table2-rigid.toml, the hand-chosen gains and the defaults)."""
    gains, text = _compliant_table("table2.toml")
    assert gains == ((13.2, 2.78), (9.08, 4.46), (20.0, 51.2, 38.9, 0.293))
    assert text.count(tune.PROVENANCE_MARK) == 1 and "NO FEASIBLE POINT" not in text
    for line in ("budget 36 evaluations per controller (18 Latin hypercube",
                 "gains.pid_1khz_hz = 13.2, gains.pid_1khz_base_hz = 2.78",
                 "gains.pid_fpga_hz = 9.08, gains.pid_fpga_base_hz = 4.46",
                 "gains.lam = 20, gains.k_j = 51.2, gains.K = 38.9, gains.vdc_base_fb = 0.293"):
        assert line in text
    rigid = load(ROOT / "configs" / "table2-rigid.toml")
    assert rigid.plant.joints == "rigid"
    assert (rigid.gains.lam, rigid.gains.k_j, rigid.gains.K) == (200.0, 60.0, 50.0)
    assert (rigid.gains.pid_fpga_hz, rigid.gains.pid_1khz_hz) == (15.0, 5.0)
    assert tune.load_tune_spec(ROOT / "configs" / "tuning" / "table2-rigid.toml").config[
        "plant"]["joints"] == "rigid"
