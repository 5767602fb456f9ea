# amaranth: UnusedElaboratable=no
"""Lost FCTs are detected (credit timeout), counted and recovered by a link restart; a small
link-level fault campaign (the full one: benchmarks/link_fault_campaign.py, docs/faults.md).

# Ref: ECSS-E-ST-50-12C flow control (FCT = 8 N-chars), §8.5.2 (Error-Reset), §8.12.
"""

import pytest

from mrm_cosim.cosim.link_faults import (KINDS, Fault, LinkCampaign, run_campaign, summarize,
                                         upper_bound_95)
from mrm_cosim.hdl.link.chars import CharKind, LinkState
from mrm_cosim.hdl.link.codec_ref import char_value
from mrm_cosim.protocol.link import rest_credit
from mrm_cosim.testbench import PeerBench, run_simulation

from amaranth.sim import Simulator


def test_gateware_flags_credit_it_announced_but_never_saw_used():
    """The peer behaves as if our second FCT was lost: it sends the 8 characters of the first
    and stops inside the packet. With 16 credits announced and 8 unused for the credit timeout,
    the codec counts a credit_timeout error, ends the packet with EEP and restarts."""
    bench = PeerBench(reset_cycles=60, wait_cycles=150, rx_fifo_depth=24, credit_timeout=100)
    dut = bench.dut
    seen = {}

    async def testbench(ctx):
        await bench.bring_up(ctx)
        await bench.until(ctx, lambda: ctx.get(dut.rx_credit) == 16)
        bench.peer.send(*[("DATA", 0x80 | k) for k in range(8)])
        await bench.until(ctx, lambda: len(bench.received) == 8)
        start = bench.cycles
        await bench.until(ctx, lambda: ctx.get(dut.state) != LinkState.RUN, limit=300)
        seen["after"] = bench.cycles - start
        seen["errors"] = bench.errors(ctx)
        await bench.run(ctx, 5)

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, "credit_timeout")
    assert seen["errors"] == {k: int(k == "credit_timeout") for k in seen["errors"]}
    assert 95 <= seen["after"] <= 110, seen["after"]
    assert bench.received == [char_value(CharKind.DATA.value, 0x80 | k) for k in range(8)] + [
        char_value(CharKind.EEP.value)]


@pytest.mark.parametrize("fcts,error", [(7, False), (6, True), (5, True)])
def test_gateware_audits_its_credit_after_a_silence(fcts, error):
    """The peer, scripted, grants ``fcts`` FCTs and sends nothing. A drained peer of the DUT's
    64-entry FIFO grants 7 (56 credits, ``rest_credit(64)`` = (48, 56]): with 7 the DUT stays in
    Run; with 6 or 5 (an FCT or two lost) it counts a credit_timeout error once it has sent no
    N-char for the audit time, and restarts."""
    audit = 120
    bench = PeerBench(reset_cycles=60, wait_cycles=150, credit_audit=audit)
    dut = bench.dut
    seen = {}

    async def testbench(ctx):
        await bench.bring_up(ctx)               # one FCT in the handshake
        bench.peer.send(*[("FCT",)] * (fcts - 1))
        await bench.until(ctx, lambda: ctx.get(dut.tx_credit) == 8 * fcts, limit=300)
        await bench.run(ctx, 30)
        seen["credit"] = ctx.get(dut.tx_credit)
        start = bench.cycles
        await bench.until(ctx, lambda: ctx.get(dut.state) != LinkState.RUN, limit=3 * audit)
        seen["after"] = bench.cycles - start
        seen["errors"] = bench.errors(ctx)

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    if error:
        run_simulation(sim, f"credit_audit_{fcts}")
        assert seen["credit"] == 8 * fcts
        assert seen["errors"] == {k: int(k == "credit_timeout") for k in seen["errors"]}
        assert seen["after"] <= audit
    else:
        with pytest.raises(AssertionError, match="condition not reached"):
            run_simulation(sim, f"credit_audit_{fcts}")
        assert seen["credit"] == 56


def test_a_dropped_fct_is_detected_counted_and_the_link_recovers():
    """A FIFO of 16 (one FCT of 8 credits outstanding at a time): a dropped FCT
    starves the sender inside a frame. Where parity does not see the drop, the credit timeout
    does; every time the link restarts, frames cross both ways again, none corrupted."""
    camp = LinkCampaign(seed=3, rx_fifo_depth=16)
    camp.bring_up()
    by = {"parity": 0, "credit_timeout": 0}
    for k in range(12):
        row = camp.judge(Fault("lost-fct", "ab" if k % 2 else "ba", seed=k))
        assert row["moved"], f"lost FCT {k} counted nowhere"
        assert row["went_down"] and row["recovered"]
        assert row["corrupted"] == 0
        rx, tx = ("b", "a") if row["line"] == "ab" else ("a", "b")
        by["parity"] += row["moved"].get(f"{rx}.parity", 0)
        # The codec whose FCT was lost sees its announced credit unused.
        by["credit_timeout"] += row["moved"].get(f"{tx}.credit_timeout", 0)
    assert by["credit_timeout"] >= 1, by


@pytest.mark.parametrize("depth", [16, 24, 64, 100])
def test_a_drained_peer_grants_the_rest_credit_the_audit_expects(depth):
    """After traffic of every length, once both hosts fall silent and the FIFOs drain, each
    sender holds more than ``low`` and at most ``high`` credits (``rest_credit``): the window
    the credit audit checks, derived from the receiver's FCT rule, holds on the reference."""
    camp = LinkCampaign(seed=depth, rx_fifo_depth=depth, credit_audit=0)
    camp.bring_up()
    low, high = rest_credit(depth)
    seen = set()
    for k in range(12):
        for _ in range(37 * (k + 1)):
            camp.step()
        camp._pause(True)
        while min(h.idle for h in camp.hosts.values()) < 150:
            camp.step()
        for c in camp.codecs.values():
            assert low < c.tx_credit <= high, (k, c.tx_credit, low, high)
            seen.add(c.tx_credit)
        camp._pause(False)
    assert len(seen) > 1            # frames end anywhere: more than one residue was checked


def test_with_the_default_fifo_every_lost_fct_is_detected_and_the_link_recovers():
    """The 64-entry FIFO: a lost FCT leaves its sender 40-48 credits and never starves it,
    which the credit timeout cannot see. The credit audit does: in the silence that ends every
    fault's window (the control cycle's), the codec whose credit went short counts a
    credit_timeout error, the link restarts, and frames cross again; nothing corrupted."""
    camp = LinkCampaign(seed=4)
    assert camp.codecs["a"].rx_fifo_depth == 64
    camp.bring_up()
    audited = 0
    for k in range(16):
        row = camp.judge(Fault("lost-fct", "ab" if k % 2 else "ba", seed=k))
        assert row["moved"], f"lost FCT {k} counted nowhere"
        assert row["went_down"] and row["recovered"] and row["corrupted"] == 0
        assert row["credit_skew"] == [0, 0], row          # the restart recovered the credit
        # The FCT on line ab was a's, granting b credit: b's audit finds it short.
        short = "b" if row["line"] == "ab" else "a"
        audited += row["moved"].get(f"{short}.credit_timeout", 0)
    assert audited >= 4


def test_without_the_audit_a_lost_fct_stays_latent():
    """The same faults with the audit off: some losses keep parity, nothing counts them, and
    the sender is left 8 credits short (the credit balance): what the audit is for."""
    camp = LinkCampaign(seed=4, credit_audit=0)
    camp.bring_up()
    latent = [row for row in (camp.judge(Fault("lost-fct", "ab" if k % 2 else "ba", seed=k))
                              for k in range(16)) if not row["moved"]]
    assert latent and all(not r["went_down"] and 8 in r["credit_skew"] for r in latent), latent


def test_small_campaign_counts_every_kind_and_accepts_no_corrupted_frame():
    rows, _ = run_campaign(280, seed=5)
    summary = {s["kind"]: s for s in summarize(rows)}
    assert set(summary) == set(KINDS) | {"all"}
    assert summary["all"]["corrupted_accepted"] == 0
    assert summary["all"]["unrecovered"] == 0
    for kind in ("bit", "cut", "stuck-d"):
        assert summary[kind]["detected"] >= 0.9 * summary[kind]["injected"], summary[kind]


def test_undetected_short_cuts_change_nothing():
    """Cuts counted nowhere (shorter than the disconnect time, losing whole characters that
    parity cannot see, or none) took no link down and let no corrupted frame through."""
    rows, _ = run_campaign(150, seed=9, kinds=("cut",))
    quiet = [r for r in rows if not r["moved"]]
    assert all(r["corrupted"] == 0 and not r["went_down"] for r in quiet)


@pytest.mark.parametrize("failures,trials,bound", [(0, 100_000, 3.0e-5), (0, 176, 0.0169)])
def test_upper_bound_95(failures, trials, bound):
    assert upper_bound_95(failures, trials) == pytest.approx(bound, rel=0.01)
