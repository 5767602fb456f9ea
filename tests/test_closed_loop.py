# amaranth: UnusedElaboratable=no
"""Closed loop with the gateware: master ⇄ link ⇄ nodes ⇄ plant, on the compiled and pysim
backends (issue 5)."""

import numpy as np
import pytest
from amaranth.hdl import Fragment

from mrm_cosim.cosim.closed_loop import LineFault
from mrm_cosim.cosim.track import link_errors_detail, run_faults, run_loop, run_track
from mrm_cosim.master.uploads import Gains, node_uploads
from mrm_cosim.master.cycle import Master, MasterTiming
from mrm_cosim.master.quintic import QuinticProfile
from mrm_cosim.models.plant import Plant
from mrm_cosim.models.robot import robot_from_dict
from mrm_cosim.errors import InputError


@pytest.fixture(scope="module")
def vdc_run():
    return run_track("mrm3", "vdc", "compiled", duration=0.004, seed=3)


def test_every_period_completes_the_exchange_inside_the_period(vdc_run):
    result, summary = vdc_run
    master = result.master
    assert len(master.records) == 4
    assert summary["overruns"] == 0 and summary["missing_replies"] == 0
    assert summary["unexpected_replies"] == 0 and summary["link_errors"] == 0
    # every node reported its link counters (cumulative from reset: start-up counted nothing)
    assert sorted(master.node_link) == [1, 2, 3]
    assert all(v == 0 for c in master.node_link.values() for v in c.values())
    for rec in master.records[:-1]:
        ev = rec.events
        assert rec.complete
        assert rec.start < ev["A_done"] < ev["B_sent"] < ev["C_done"] < ev["D_sent"]
        assert ev["D_sent"] - rec.start < MasterTiming().period_cycles // 2
        # replies come back node by node: the nearest node first
        assert rec.arrivals[("A", 1)] < rec.arrivals[("A", 2)] < rec.arrivals[("A", 3)]


def test_vdc_holds_the_start_of_the_quintic(vdc_run):
    _, summary = vdc_run
    assert summary["max_joint_error_rad"] < 1e-4


def _one_module_loop(backend, record=True, faults=(), cycles=8_000):
    robot = robot_from_dict({"name": "one", "modules": [{"type": "I"}]})
    profile = QuinticProfile([0.0], [0.01], 0.02)

    def trajectory(t):
        q, qd, qdd, _ = profile.evaluate(np.array([t]))
        return q[0], qd[0], qdd[0]

    timing = MasterTiming(period_cycles=5_000, kinematics_cycles=500, force_cycles=500)
    master = Master(robot, "vdc", trajectory, robot.counts_per_rev, timing)
    plant = Plant(robot, seed=1)
    plant.reset(robot.home)
    uploads = node_uploads(robot, "vdc", Gains(), period_cycles=5_000, commit_cycles=3_000)
    return run_loop(robot, backend, master, plant, 5_000, uploads, cycles, record=record,
                    faults=faults)


def test_pysim_and_compiled_agree_cycle_for_cycle():
    """The same design, inputs and seed give the same outputs on every cycle of the window,
    through start-up, uploads and two A/B/C/D exchanges."""
    compiled, rec_c = _one_module_loop("compiled")
    pysim, rec_p = _one_module_loop("pysim")
    assert len(compiled.master.records) == 2 and compiled.master.records[0].complete
    for name in rec_c.samples:
        np.testing.assert_array_equal(rec_p.trace(name), rec_c.trace(name), err_msg=name)
    assert pysim.trace_sha256 == compiled.trace_sha256
    assert pysim.frames == compiled.frames
    assert [r.events for r in pysim.master.records] == \
        [r.events for r in compiled.master.records]
    # the node's observation port (events1, compared per cycle above) as the period records
    # hold it: every phase of the exchange at the node, cycle for cycle
    assert [r.node_events for r in pysim.master.records] == \
        [r.node_events for r in compiled.master.records]
    first = compiled.master.records[0].node_events
    assert {name for name, _ in first} >= {"BOUNDARY", "RX_A", "TX_A", "RX_B", "VDC_START",
                                           "VDC_DONE", "RX_C", "TX_C", "RX_D", "COMMIT"}
    assert "events1" in rec_c.samples


def test_pysim_and_compiled_agree_under_a_line_fault():
    """One bit inverted on the line from the node to the master during period 0's Comm A
    reply (``mrm run track --line-fault bit:up:1@3us``): both backends see the same thing on
    every cycle — the master port's codec and the node's upstream codec each count the error,
    the master drops the cut frame, the period is an overrun with its two replies missing
    (no Comm A, so no Comm B and C), and the next period's exchange completes."""
    fault = [LineFault(1, "up", "bit", 150)]
    compiled, rec_c = _one_module_loop("compiled", faults=fault)
    pysim, rec_p = _one_module_loop("pysim", faults=fault)
    for name in rec_c.samples:
        np.testing.assert_array_equal(rec_p.trace(name), rec_c.trace(name), err_msg=name)
    assert pysim.trace_sha256 == compiled.trace_sha256
    assert pysim.frames == compiled.frames
    for result in (compiled, pysim):
        master = result.master
        assert [r.complete for r in master.records] == [False, True]
        assert (master.overruns, master.missing) == (1, 2)
        detail = link_errors_detail(result)
        assert (detail["master_rx_dropped"], detail["master_port"]) == (1, 1)
        assert detail["per_node"]["1"] == {"up_link_errors": 1, "down_link_errors": 0,
                                           "rx_dropped": 0, "router_dropped": 0}


def test_bench_reports_speed_of_the_compiled_loop():
    from mrm_cosim.cosim.bench import bench_backend

    r = bench_backend("compiled", "mrm3", cycles=20_000)
    assert r["cycles"] == 20_000 and r["wall_s"] > 0 and r["cycles_per_s"] > 0
    assert r["rtf"] == pytest.approx(r["wall_s"] / (20_000 / 50e6))


@pytest.mark.parametrize("controller", ["pid-fpga", "pid-1khz"])
def test_pid_controllers_run_their_exchange(controller):
    """PID modes skip Comm B/C: A then D every period, the joints held near the reference."""
    result, summary = run_track("mrm3", controller, "compiled", duration=0.003, seed=2)
    assert summary["overruns"] == 0 and summary["unexpected_replies"] == 0
    for rec in result.master.records[:-1]:
        assert rec.complete and "B_sent" not in rec.events and "C_done" not in rec.events
        assert rec.start < rec.events["A_done"] < rec.events["D_sent"]
    assert summary["max_joint_error_rad"] < 2e-3
    assert np.any(result.tau != 0.0)


@pytest.mark.parametrize("fault_period, judged", [(0, [False, True]), (1, [True, False])])
def test_a_run_of_whole_periods_judges_its_last_period_too(fault_period, judged):
    """Two whole 5,000-cycle periods, a Comm A reply cut in one of them: the fault counts the
    same whether the next period's start judges that period or the end of the run does (the
    last period was never judged before: a fault in it went uncounted)."""
    fault = [LineFault(1, "up", "bit", 150 + 5_000 * fault_period)]
    result, _ = _one_module_loop("compiled", record=False, faults=fault, cycles=10_000)
    master = result.master
    assert [r.complete for r in master.records] == judged
    assert (master.overruns, master.missing) == (1, 2)


def test_a_period_the_run_cuts_short_is_not_judged():
    """The run ends 3,000 cycles into period 1, whose replies could still come: no overrun."""
    result, _ = _one_module_loop("compiled", record=False, cycles=8_000)
    master = result.master
    assert len(master.records) == 2 and master.overruns == 0 and master.missing == 0


@pytest.mark.parametrize("duration, words", [(1e9, "at most 60.0 s"), (1e-9, "one plant step"),
                                             (-1.0, "positive"), (float("nan"), "finite")])
def test_run_track_refuses_a_duration_it_cannot_run(tmp_path, capsys, duration, words):
    """Refused naming the flag, before anything is built (1e9 s used to die allocating the
    trace, 1e-9 s on an empty one), and nothing is written."""
    from mrm_cosim.mrm.cli import main

    with pytest.raises(InputError, match=words) as e:
        run_track("mrm3", "vdc", "model", duration=duration)
    assert e.value.field == "duration"
    out = tmp_path / "res"
    assert main(["run", "track", "--backend", "model", "--duration", str(duration), "--quiet",
                 "--out", str(out)]) == 2
    assert "--duration" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_run_track_refuses_a_robot_longer_than_the_system(tmp_path, capsys):
    """A 17-module robot is refused naming --robot before anything runs or is written."""
    from mrm_cosim.mrm.cli import main

    path = tmp_path / "long.toml"
    path.write_text('name = "long"\n' + '[[modules]]\ntype = "I"\ntwist_deg = 90.0\n' * 17)
    with pytest.raises(InputError, match="17 modules.*at most 16") as e:
        run_track(str(path), "vdc", "model", duration=0.01)
    assert e.value.field == "robot"
    out = tmp_path / "res"
    assert main(["run", "track", "--robot", str(path), "--backend", "model", "--duration",
                 "0.01", "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert "--robot" in captured.err and "[1/1]" not in captured.out + captured.err
    assert not out.exists()


def _encoder_robot(lines: int) -> dict:
    """mrm3 with every module's encoder given ``lines`` (2000 is the actuators' own)."""
    return {"name": f"enc{lines}", "base": {"xyz": [0.0, 0.0, 0.3]},
            "modules": [{"type": "Ie"}, {"type": "IIe", "twist_deg": 90.0}, {"type": "Ie"}],
            "module_types": {"Ie": {"like": "I", "encoder_lines": lines},
                             "IIe": {"like": "II", "encoder_lines": lines}}}


def test_a_module_encoder_other_than_the_actuators_is_the_one_the_loop_measures_with():
    """A module type with another encoder (1900 lines: 760,000 counts/rev) was half applied:
    the master and the joint program used its counts, the plant's encoder the actuator's
    catalogue 800,000 and the nodes' velocity constant and angle scale the gateware's default.
    The arm stopped 5 % short of every target (max joint error 24 mrad instead of 0.8) and the
    nodes reported velocities 5 % low. Now all use the module's counts: the run tracks as with
    the catalogue encoder, and the velocity in Comm A is the count's derivative."""
    from mrm_cosim.cosim.track import loop_system, loop_system_key

    robot = robot_from_dict(_encoder_robot(1900))
    plant = Plant(robot)
    plant.reset(np.ones(3))
    assert list(plant.encoder_counts()) == [int(760_000 / (2 * np.pi))] * 3
    one = robot_from_dict({**_encoder_robot(1900), "modules": [{"type": "Ie"}]})
    system = loop_system(one)
    Fragment.get(system, None)          # elaborated, as a build would (and so not unused)
    assert system.nodes[0]._core.encoder_params.counts_per_rev == 760_000
    assert loop_system_key(robot) != loop_system_key(robot_from_dict(_encoder_robot(2000)))

    errors = {}
    for lines in (1900, 2000):
        result, summary = run_track(robot_from_dict(_encoder_robot(lines)), "vdc", "model",
                                    duration=0.6)
        errors[lines] = summary["max_joint_error_rad"]
    assert errors[1900] < 1.5 * errors[2000] < 3e-3

    result, _ = run_track(robot, "vdc", "model", duration=0.6)
    recs = result.master.records
    q = np.array([r.q for r in recs])
    qd = np.array([r.qd for r in recs])
    central = (q[2:] - q[:-2]) / 2e-3
    moving = np.abs(central) > 0.1
    assert moving.sum() > 100
    ratio = np.median(qd[1:-1][moving] / central[moving])
    assert abs(ratio - 1.0) < 0.01, ratio


def test_a_module_encoder_the_node_cannot_hold_is_refused_naming_the_robot():
    """400,000 counts/rev (1000 lines) overflows the node's velocity constant: refused as the
    robot before anything runs, with the range that fits."""
    with pytest.raises(InputError, match=r"400,000 encoder counts.*613,595 to 823,549") as e:
        run_track(robot_from_dict(_encoder_robot(1000)), "vdc", "model", duration=0.01)
    assert e.value.field == "robot"


def test_the_fpga_pid_runs_where_its_gains_once_overflowed():
    """A robot with 1,700-line encoders has more torque per count than mrm3 for the same PID
    gain: with one KP format for every node its ``pid-fpga`` run was refused as joint1.kp.
    The nodes are built with a PID gain shift per module (master.uploads.pid_shifts), so it
    runs, clean, and tracks as a PID should (sub-mrad in its first 50 ms)."""
    robot = robot_from_dict(_encoder_robot(1700))
    _, summary = run_track(robot, "vdc", "model", duration=0.01)
    assert summary["overruns"] == 0
    _, summary = run_track(robot, "pid-fpga", "model", duration=0.05)
    assert run_faults(summary) == []
    assert summary["max_joint_error_rad"] < 1e-3


def _home_robot(home_deg) -> dict:
    """mrm3 with a rest posture (``home_deg``, or none)."""
    doc = {"name": "homed", "base": {"xyz": [0.0, 0.0, 0.3]},
           "modules": [{"type": "I"}, {"type": "II", "twist_deg": 90.0}, {"type": "I"}]}
    if home_deg is not None:
        doc["home_deg"] = home_deg
    return doc


def test_a_robot_with_a_home_posture_tracks_from_it():
    """The arm rests at its home posture until period 0, and a node's incremental encoder
    counts from 0 at reset. Nothing preset the nodes' counts, so every joint's angle was off
    by its home angle in the master and the nodes: a robot with home_deg = [10, 20, -30]
    (and mrm6) settled a whole home angle away from every target (max joint error 0.65 rad
    instead of 0.8 mrad, exit 0). Now each node is preset to its home count (CONFIG PRESET,
    what the plant's encoder shows there): the master reads the home posture in period 0 and
    the run tracks as well as from zero."""
    from mrm_cosim.protocol.packet import PacketType
    from mrm_cosim.protocol.regs import Config
    from mrm_cosim.models.encoder import counts_per_rad, joint_counts

    robot = robot_from_dict(_home_robot([10.0, 20.0, -30.0]))
    plant = Plant(robot)
    presets = [(dest, int.from_bytes(p[1:5], "little", signed=True))
               for dest, t, p in node_uploads(robot, "vdc", Gains())
               if t == PacketType.CONFIG and p[0] == Config.PRESET]
    assert presets == [(k + 1, int(c)) for k, c in enumerate(plant.encoder_counts())]
    assert presets == [(k + 1, int(c)) for k, c in enumerate(
        joint_counts(robot.home, counts_per_rad(robot.counts_per_rev)))]

    errors = {}
    for home in ([10.0, 20.0, -30.0], None):
        result, summary = run_track(robot_from_dict(_home_robot(home)), "vdc", "model",
                                    duration=0.6)
        errors[home is None] = summary["max_joint_error_rad"]
        if home is not None:
            first = result.master.records[0].q
            assert np.abs(first - np.deg2rad(home)).max() < 1e-5
    assert errors[False] < 1.5 * errors[True] < 3e-3


def test_the_model_and_the_gateware_preset_the_count_alike():
    """With a home posture the model backend (which ignored CONFIG PRESET) and the gateware
    (pysim) run the same loop bit for bit, and both read the home angle."""
    robot = robot_from_dict({"name": "one", "modules": [{"type": "I"}], "home_deg": [20.0]})
    profile = QuinticProfile(robot.home, robot.home + 0.01, 0.02)

    def trajectory(t):
        q, qd, qdd, _ = profile.evaluate(np.array([t]))
        return q[0], qd[0], qdd[0]

    results = {}
    for backend in ("pysim", "model"):
        timing = MasterTiming(period_cycles=5_000, kinematics_cycles=500, force_cycles=500)
        master = Master(robot, "vdc", trajectory, robot.counts_per_rev, timing)
        plant = Plant(robot, seed=1)
        plant.reset(robot.home)
        uploads = node_uploads(robot, "vdc", Gains(), period_cycles=5_000, commit_cycles=3_000)
        results[backend], _ = run_loop(robot, backend, master, plant, 5_000, uploads, 8_000)
    assert results["model"].violations == []
    assert results["model"].trace_sha256 == results["pysim"].trace_sha256
    for result in results.values():
        assert len(result.master.records) == 2
        assert all(abs(r.q[0] - robot.home[0]) < 1e-5 for r in result.master.records)


def test_the_watchdog_timeout_follows_the_period():
    """The watchdog timeout was 100,000 cycles (2 ms, two default periods) whatever the
    period: with ``[timing] period_cycles = 150000`` (3 ms) every node tripped between two
    periods' packets, the torques ramped to zero and the arm fell (1.07 rad off), the run
    ending with exit 0. The timeout is two periods now, so a 3 ms period tracks as 1 ms does."""
    from mrm_cosim.protocol.packet import PacketType
    from mrm_cosim.protocol.regs import Config
    from mrm_cosim.models.robot import load_robot

    def timeouts(period):
        uploads = node_uploads(load_robot("mrm3"), "vdc", Gains(), period_cycles=period)
        return [int.from_bytes(p[i + 1:i + 5], "little") for _, t, p in uploads
                if t == PacketType.CONFIG for i in range(0, len(p), 5) if p[i] == Config.TIMEOUT]

    assert timeouts(50_000) == [100_000] * 3
    assert timeouts(150_000) == [300_000] * 3
    errors = {}
    for period in (50_000, 150_000):
        _, summary = run_track("mrm3", "vdc", "model", duration=0.06,
                               timing=MasterTiming(period_cycles=period))
        assert summary["tripped_nodes"] == [] and summary["model_violations"] == []
        assert summary["overruns"] == summary["missing_replies"] == 0
        errors[period] = summary["max_joint_error_rad"]
    assert errors[150_000] < 2 * errors[50_000] < 2e-3


def test_the_vdc_differences_and_adapts_over_the_masters_period():
    """The VDC's backward difference 1/T and adaptation step ρ·T were uploaded for 1 ms
    whatever ``[timing] period_cycles``: at 2 ms every required acceleration (dV_r/dt, q̈_r)
    the nodes computed was twice the truth, and the adaptation half as fast; the run ended
    normally with a tip error 3x the 1 ms run's. The words follow the period now."""
    from mrm_cosim.cosim import experiment_config as ec
    from mrm_cosim.cosim.closed_loop import ClosedLoop
    from mrm_cosim.cosim.model import ModelBackend
    from mrm_cosim.cosim.track import _trajectory, node_encoders
    from mrm_cosim.protocol.fixed import INVT, RHOT
    from mrm_cosim.protocol.regs import Config
    from mrm_cosim.models.robot import load_robot

    robot = load_robot("mrm3")
    for period in (50_000, 100_000):
        uploads = node_uploads(robot, "vdc", Gains(adapt=0.5), period_cycles=period)
        master = Master(robot, "vdc", _trajectory(robot), robot.counts_per_rev,
                        MasterTiming(period_cycles=period), uploads=uploads)
        plant = Plant(robot)
        plant.reset(robot.home)
        loop = ClosedLoop(robot, ModelBackend(encoder=node_encoders(robot)), master, plant,
                          100_000, uploads)
        loop.run(500)
        for node in loop.backend.nodes:
            assert node.config[Config.PERIOD] == period
            assert INVT.decode(node.vdc.params.inv_T) == 50e6 / period
            assert node.vdc.params.rho_T[0][0] == RHOT[0].encode(0.5 * period / 50e6)

    cfg = ec.load()
    errors = {}
    for period in (50_000, 100_000):
        _, summary = run_track(cfg.robot, "vdc", "model", duration=0.5, gains=cfg.gains,
                               timing=MasterTiming(period_cycles=period))
        assert summary["node_counters"] == dict.fromkeys(summary["node_counters"], 0)
        errors[period] = summary["max_tip_error_m"]
    assert errors[100_000] < 1.5 * errors[50_000]


def test_a_run_that_is_not_clean_says_so_and_short_periods_do_not_trip_the_watchdog():
    """Late Comm D, tripped nodes and the model's violated assumptions were in summary.json
    only: ``mrm run track`` and table2.md printed overruns and link errors and looked clean.
    :func:`run_faults` names everything a clean run does not have; the CLI and table2.md say
    NOT A CLEAN RUN. With a 0.4 ms period (commit phase 80 µs, before Comm D reaches node 3)
    every Comm D is late — counted and said. The watchdog timeout of two periods (0.8 ms) had
    tripped every node in the silence between the uploads' ARM and period 0; it is at least
    2 ms now."""
    from mrm_cosim.cosim.table2 import table_markdown
    from mrm_cosim.cosim.track import run_faults

    _, clean = run_track("mrm3", "vdc", "model", duration=0.01)
    assert run_faults(clean) == []
    _, short = run_track("mrm3", "vdc", "model", duration=0.05,
                         timing=MasterTiming(period_cycles=20_000))
    assert short["tripped_nodes"] == []
    faults = run_faults(short)
    assert any("late Comm D" in f for f in faults) and not any("watchdog" in f for f in faults)
    md = table_markdown({"robot": "mrm3", "backend": "model", "seed": 0, "duration_s": 0.05,
                         "controllers": {"vdc": short, "pid-fpga": clean},
                         "ordering": {"best_to_worst": ["vdc", "pid-fpga"], "as_paper": True}})
    assert "**NOT A CLEAN RUN**, `vdc`: " in md and "`pid-fpga`: " not in md
