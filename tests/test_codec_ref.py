# amaranth: UnusedElaboratable=no
"""The Python reference codec matches the gateware cycle for cycle, on every output."""

import numpy as np
import pytest
from amaranth.sim import Simulator

from mrm_cosim.hdl.link.codec_ref import CodecRef
from mrm_cosim.hdl.link.chars import LinkState

from mrm_cosim.testbench import (CodecPair, RandomHost, apply_line_faults, assert_outputs_equal,
                          drive_codec_inputs, read_codec_outputs, run_simulation)

SHORT = {"reset_cycles": 60, "wait_cycles": 150}
NO_FAULT = (0, 0, 0)


def run_lockstep(params, n_cycles, seed, *, faults=None, controls=None, name="lockstep"):
    """Run a gateware pair and a reference pair side by side on the same random stimulus.

    ``faults(cycle, rng)`` returns ``{"ab": ((clear, set, flip) for D, (...) for S), "ba": ...}``
    or None; ``controls(cycle)`` returns per-codec link control levels.
    Returns the RandomHost and CodecRef objects and the cycles each codec spent in Run.
    """
    rng = np.random.default_rng(seed)
    pair = CodecPair(**params)
    refs = {"a": CodecRef(**params), "b": CodecRef(**params)}
    hosts = {"a": RandomHost(np.random.default_rng(seed + 1)),
             "b": RandomHost(np.random.default_rng(seed + 2))}
    codecs = {"a": pair.a, "b": pair.b}
    lines = {"ab": pair.ab, "ba": pair.ba}
    run_cycles = {"a": 0, "b": 0}

    async def testbench(ctx):
        for cycle in range(n_cycles):
            ctl = controls(cycle) if controls else {}
            fault = (faults(cycle, rng) if faults else None) or {}
            inputs = {}
            for who in "ab":
                values = hosts[who].inputs()
                values.update(ctl.get(who, {"link_start": 1, "auto_start": 0,
                                            "link_disable": 0}))
                inputs[who] = values
                drive_codec_inputs(ctx, codecs[who], values)
                for port in ("link_start", "auto_start", "link_disable", "run_div"):
                    if port in values:
                        ctx.set(getattr(codecs[who], port), values[port])
            for key, line in lines.items():
                fd, fs = fault.get(key, (NO_FAULT, NO_FAULT))
                ctx.set(line.clear_d, fd[0])
                ctx.set(line.set_d, fd[1])
                ctx.set(line.flip_d, fd[2])
                ctx.set(line.clear_s, fs[0])
                ctx.set(line.set_s, fs[1])
                ctx.set(line.flip_s, fs[2])

            outs = {}
            for who in "ab":
                rtl = read_codec_outputs(ctx, codecs[who])
                ref = refs[who].outputs()
                assert_outputs_equal(rtl, ref, cycle=cycle, who=who)
                hosts[who].observe(ref)
                outs[who] = ref
                run_cycles[who] += ref.running

            for who, peer, key in (("a", "b", "ba"), ("b", "a", "ab")):
                fd, fs = fault.get(key, (NO_FAULT, NO_FAULT))
                refs[who].step(d_in=apply_line_faults(outs[peer].d_out, fd),
                               s_in=apply_line_faults(outs[peer].s_out, fs),
                               **inputs[who])
            await ctx.tick()

    sim = Simulator(pair)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, name)
    return hosts, refs, run_cycles


@pytest.mark.parametrize("slots,run_div", [(1, 1), (2, 1), (3, 1), (3, 2), (4, 1), (4, 3),
                                           (6, 2), (8, 3)])
def test_reference_matches_rtl_with_traffic(slots, run_div):
    params = dict(SHORT, slots=slots, run_div=run_div, rx_fifo_depth=16)
    hosts, refs, run_cycles = run_lockstep(params, 1400, seed=slots * 10 + run_div,
                                     name=f"ref_traffic_w{slots}_d{run_div}")
    # The comparison is only worth something if the link came up and carried traffic.
    assert run_cycles["a"] > 800 and run_cycles["b"] > 800
    for who, peer in (("a", "b"), ("b", "a")):
        assert len(hosts[who].sent) > 50
        assert hosts[peer].received == hosts[who].sent[:len(hosts[peer].received)]


def test_reference_matches_rtl_under_bit_errors_and_cuts():
    """Random bit flips, stuck lines and cuts: errors, resets, EEPs, discards all agree."""
    def faults(cycle, rng):
        if 300 <= cycle % 900 < 340:          # cut a -> b for 40 cycles, every 900
            return {"ab": ((7, 0, 0), (7, 0, 0))}
        if 600 <= cycle % 900 < 620:          # D stuck high b -> a
            return {"ba": ((0, 7, 0), (0, 0, 0))}
        if rng.random() < 0.004:              # single-slot flip somewhere
            key = "ab" if rng.random() < 0.5 else "ba"
            mask = 1 << int(rng.integers(0, 3))
            pair = ((0, 0, mask), NO_FAULT) if rng.random() < 0.5 else (NO_FAULT, (0, 0, mask))
            return {key: pair}
        return None

    params = dict(SHORT, slots=3, rx_fifo_depth=16)
    hosts, refs, run_cycles = run_lockstep(params, 3600, seed=7, faults=faults, name="ref_faults")
    assert run_cycles["a"] > 500


def test_reference_matches_rtl_with_autostart_and_disable():
    def controls(cycle):
        return {
            "a": {"link_start": int(cycle < 900), "auto_start": 0,
                  "link_disable": int(900 <= cycle < 950)},
            "b": {"link_start": 0, "auto_start": 1, "link_disable": 0},
        }

    params = dict(SHORT, slots=3, rx_fifo_depth=16)
    hosts, refs, run_cycles = run_lockstep(params, 1300, seed=3, controls=controls,
                                     name="ref_autostart")
    assert run_cycles["b"] > 300


def test_reference_matches_rtl_when_the_run_rate_changes_in_run():
    """The run rate is a register the host sets at any time (§6.6 lets the rate change in
    Run): both ends change it independently every 150 cycles, through every legal period,
    out-of-range values clamped (0 and 1 to 2, 31 to the slowest, 30); RTL and reference
    agree, the link stays up and carries traffic without an error."""
    periods = [2, 3, 7, 1, 31, 0, 4, 2, 5]

    def controls(cycle):
        k = cycle // 150
        return {who: {"link_start": 1, "auto_start": 0, "link_disable": 0,
                      "run_div": periods[(k + off) % len(periods)]}
                for who, off in (("a", 0), ("b", 4))}

    params = dict(SHORT, slots=6, run_div=2, rx_fifo_depth=16)
    hosts, refs, run_cycles = run_lockstep(params, 1600, seed=11, controls=controls,
                                           name="ref_rate_change")
    assert run_cycles["a"] > 1200 and run_cycles["b"] > 1200
    for who, peer in (("a", "b"), ("b", "a")):
        assert not any(refs[who].errors.values()), refs[who].errors
        assert len(hosts[who].sent) > 30
        assert hosts[peer].received == hosts[who].sent[:len(hosts[peer].received)]


def test_reference_matches_rtl_when_the_credit_audit_fires():
    """A credit audit of 24 cycles is shorter than the random hosts' receive stalls: a sender
    held without credit by a stalled peer goes silent with less than a drained peer's credit
    and counts a credit_timeout error. RTL and reference agree on every such restart."""
    params = dict(SHORT, slots=3, rx_fifo_depth=16, credit_audit=24)
    hosts, refs, run_cycles = run_lockstep(params, 3000, seed=21, name="ref_credit_audit")
    assert sum(r.errors["credit_timeout"] for r in refs.values()) >= 2, \
        [r.errors for r in refs.values()]
    assert run_cycles["a"] > 800


def test_reference_rejects_bad_parameters():
    with pytest.raises(ValueError, match="Slots"):
        CodecRef(slots=9)
    with pytest.raises(ValueError, match="Run bit period"):
        CodecRef(slots=6, run_div=1)
    with pytest.raises(ValueError, match="FIFO depth"):
        CodecRef(rx_fifo_depth=8)
    with pytest.raises(ValueError, match="Credit audit"):
        CodecRef(credit_audit=1)
    assert CodecRef().outputs().state == LinkState.ERROR_RESET.value
