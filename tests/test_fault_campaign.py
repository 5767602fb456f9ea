# amaranth: UnusedElaboratable=no
"""The fault campaign as a kind of sweep (issue 22 item 4): the link-level campaign through
``mrm sweep`` (its small CI spec, executors giving the same rows, resume), the link-level node
reset and master stall, and a tiny closed-loop campaign on the compiled gateware."""

import json
from functools import partial
from pathlib import Path

import pytest

from mrm_cosim.cosim import sweep
from mrm_cosim.cosim.executors import LocalExecutor, SerialExecutor
from mrm_cosim.cosim.link_faults import (KINDS, STALL_CYCLES, SHORT_TIMERS, Fault,
                                         LinkCampaign)
from mrm_cosim.mrm.cli import main

SPECS = Path(__file__).resolve().parents[1] / "configs" / "sweeps"


def _rows(out):
    return [json.loads(line) for line in (out / "points.jsonl").read_text().splitlines()]


def test_the_ci_campaign_runs_through_mrm_sweep(tmp_path, capsys):
    out = tmp_path / "lf"
    assert main(["sweep", str(SPECS / "link-faults-ci.toml"), "--out", str(out),
                 "--workers", "2", "--quiet"]) == 0
    doc = json.loads((out / "summary.json").read_text())
    by = {s["kind"]: s for s in doc["summary"]}
    assert doc["faults"] == 360 and set(by) == set(KINDS) | {"all"}
    assert by["all"]["corrupted_accepted"] == 0 and by["all"]["unrecovered"] == 0
    for kind in ("bit", "cut", "stuck-d", "node-reset"):
        assert by[kind]["detected"] >= 0.9 * by[kind]["injected"], by[kind]
    assert by["node-reset"]["by"].startswith("disconnect")
    text = (out / "summary.md").read_text()
    assert "95 % upper bound" in text and "| master-stall |" in text
    # a lost FCT that breaks no parity check leaves the sender 8 credits short, which the FIFO
    # of 64 never starves: the credit audit finds every one in the silence after the fault
    # (without it, tests/test_link_faults.py, they stay latent), and none is left unbalanced
    assert by["lost-fct"]["detected"] == by["lost-fct"]["injected"] > 0, by["lost-fct"]
    assert "## Credit left unbalanced" in text
    assert doc["credit_skew_link_up"]["lost-fct"] == 0, doc["credit_skew_link_up"]
    assert (out / "recovery.png").stat().st_size and (out / "detectors.png").stat().st_size


def test_the_full_campaign_has_1e5_faults_in_resumable_points():
    spec = sweep.load_spec(SPECS / "link-faults.toml")
    points = sweep.expand(spec)
    assert sum(p["task"]["n"] for p in points) == spec.campaign["faults"] >= 100_000
    assert set(spec.campaign["kinds"]) == set(KINDS)
    assert len({p["id"] for p in points}) == len(points) > 1


def _small(tmp_path, name="s.toml", faults=48, chunk=12):
    path = tmp_path / name
    path.write_text(f'[sweep]\nkind = "link-faults"\n[campaign]\nfaults = {faults}\n'
                    f'chunk = {chunk}\nseed = 4\n')
    return sweep.load_spec(path)


@pytest.mark.parametrize("executor", [partial(LocalExecutor, 2)])
def test_serial_and_processes_give_the_same_rows(tmp_path, executor):
    spec = _small(tmp_path)
    got = {}
    for name, ex in (("serial", SerialExecutor), ("pool", executor)):
        with ex() as e:
            sweep.run_sweep(spec, tmp_path / name, e, plots=False)
        got[name] = {r["id"]: r["rows"] for r in _rows(tmp_path / name)}
    assert got["serial"] == got["pool"] and len(got["serial"]) == 4


def test_a_killed_campaign_resumes_at_its_unfinished_chunks(tmp_path):
    spec = _small(tmp_path)
    out = tmp_path / "r"
    with SerialExecutor() as e:
        sweep.run_sweep(spec, out, e, plots=False)
    lines = (out / "points.jsonl").read_text().splitlines()
    (out / "points.jsonl").write_text("\n".join(lines[:2]) + "\n" + lines[2][:40])
    with SerialExecutor() as e:
        outcome = sweep.run_sweep(spec, out, e, resume=True, plots=False)
    assert (outcome["ran"], outcome["skipped"]) == (2, 2)
    assert json.loads((out / "summary.json").read_text())["faults"] == 48


def test_a_node_reset_is_seen_as_a_disconnect_by_its_peer_and_the_link_recovers():
    camp = LinkCampaign(seed=2)
    camp.bring_up()
    for k in range(6):
        line = "ab" if k % 2 else "ba"
        row = camp.judge(Fault("node-reset", line, seed=k))
        peer = "b" if line == "ab" else "a"
        assert row["moved"].get(f"{peer}.disconnect", 0) >= 1, row
        assert row["went_down"] and row["recovered"] and row["corrupted"] == 0
        # the reset codec's own counts are kept across its reset, never negative
        assert all(v > 0 for v in row["moved"].values()), row


def test_a_master_stall_inside_a_frame_longer_than_the_credit_timeout_is_caught():
    timeout = SHORT_TIMERS["credit_timeout"]
    camp = LinkCampaign(seed=6)
    camp.bring_up()
    seen = {True: 0, False: 0}
    for k, cycles in enumerate(STALL_CYCLES * 2):
        line = "ab" if k % 2 else "ba"
        row = camp.judge(Fault("master-stall", line, cycles=cycles, seed=k))
        assert row["corrupted"] == 0 and row["recovered"]
        peer = "b" if line == "ab" else "a"
        if not row["in_frame"]:
            continue
        if cycles > timeout:
            assert row["moved"] == {f"{peer}.credit_timeout": 1} or \
                set(row["moved"]) >= {f"{peer}.credit_timeout"}, row
            seen[True] += 1
        elif cycles < timeout - 20:
            assert not row["moved"] and not row["went_down"], row
            seen[False] += 1
    assert seen[True] >= 4 and seen[False] >= 4, seen


def test_a_tiny_closed_loop_campaign(tmp_path):
    """Four line faults in one 10 ms VDC run on the compiled gateware, judged against the same
    run without faults; the reference is run_track's run bit for bit."""
    from mrm_cosim.cosim.experiment_config import from_dict
    from mrm_cosim.cosim.track import run_track

    out = tmp_path / "loop"
    spec = sweep.load_spec(SPECS / "link-faults-loop-ci.toml")
    with SerialExecutor() as e:
        outcome = sweep.run_sweep(spec, out, e)
    assert outcome["failed"] == 0
    (row,) = outcome["rows"]
    faults = row["rows"]
    assert len(faults) == 4 and all(f["corrupted"] == 0 for f in faults)
    # every fault that cost the master a frame or a period was counted somewhere
    for f in faults:
        if f["periods_lost"] or f["moved"].get("master.missing"):
            assert set(f["moved"]) - {"master.missing", "master.overruns"}, f
    config = from_dict(spec.campaign["resolved"])
    _, s = run_track(controller="vdc", backend="compiled", duration=0.010, seed=0,
                     gains=config.gains, timing=config.timing, plant_config=config.plant)
    assert row["ref_sha256"] == s["trace_sha256"]
    assert (out / "summary.md").read_text().count("| 0 |") >= 1
    assert (out / "loop_faults.png").stat().st_size


def test_a_short_master_stall_pays_for_an_earlier_fault():
    """Fault 245 of chunk 10 of configs/sweeps/link-faults.toml (a 50-cycle stall of host a
    inside a frame, a quarter of the credit timeout) took the link down with a credit error.
    The stall is not the cause, and the rows' ``credit_skew`` column says which fault was:
    fault 241 (D flipped for one bit period on a → b) made b decode one N-char more than a sent
    with no parity error (only b's CRC check dropped frames): b's credit count one below a's
    (skew −1), unflagged. Fault 242, a reset of b's codec, restarted the link and settled that
    account (+1). Fault 244, a lost-FCT injection on a → b that held the lines over a
    time-code and an N-char (b's CRC, EEP and time-code sequence counters moved; no codec
    error), left the same −1 again, and that is the skew b's next FCT turned into a's credit
    error (§8.5.2) during the stall — which then shows +1, the restart settling it (an earlier
    version of this test and of docs/faults.md blamed fault 241 alone). The campaign as it ran
    then: without the credit audit, whose silences change every later fault's timing."""
    import numpy as np

    from mrm_cosim.cosim.link_faults import draw

    rng = np.random.default_rng([10, 1])
    camp = LinkCampaign(10, rx_fifo_depth=64, credit_timeout=200, credit_audit=0)
    camp.bring_up()
    judged, rows = 0, {}
    while judged < 244:
        if judged == 240:
            assert camp.credit_balance() == (0, 0)
        fault = draw(rng, KINDS)
        row = camp.judge(fault)
        if not row.get("skipped"):
            judged += 1
            rows[judged] = (fault, row)
    fault, row = rows[241]
    assert (fault.kind, fault.line) == ("bit", "ab")
    assert not row["went_down"] and row["corrupted"] == 0
    assert set(row["moved"]) == {"b.crc_drop"}         # no codec counter moved
    assert row["credit_skew"] == [-1, 0]
    fault, row = rows[242]
    assert fault.kind == "node-reset" and row["went_down"] and row["credit_skew"] == [1, 0]
    assert rows[243][1]["credit_skew"] == [0, 0]
    fault, row = rows[244]
    assert (fault.kind, fault.line) == ("lost-fct", "ab") and not row["went_down"]
    assert set(row["moved"]) == {"b.crc_drop", "b.eep", "b.tc_sequence"}
    assert row["credit_skew"] == [-1, 0]
    assert camp.credit_balance() == (-1, 0)              # still there before the stall
    stall = draw(rng, KINDS)
    assert (stall.kind, stall.line, stall.cycles) == ("master-stall", "ab", 50)
    row = camp.judge(stall)
    assert row["corrupted"] == 0 and row["went_down"] and row["moved"]["a.credit"] == 1
    assert row["credit_skew"] == [1, 0]                  # the restart settled the account


def test_a_loop_campaign_refuses_a_config_with_clocks_of_their_own(tmp_path):
    """The loop campaign's runs are built on one clock without the discipline's upload: a
    config with [clocks] is refused by field before anything runs, not run on one clock."""
    from mrm_cosim.cosim import sweep
    from mrm_cosim.errors import InputError

    text = (SPECS / "link-faults-loop-ci.toml").read_text()
    text = text.replace('config = "table2"', 'config = "table2-clocks"')
    (tmp_path / "c.toml").write_text(text)
    with pytest.raises(InputError) as exc:
        sweep.load_spec(tmp_path / "c.toml")
    assert exc.value.field == "campaign.config" and "[clocks]" in exc.value.message
