# amaranth: UnusedElaboratable=no
"""Link start-up, its timing on the 20 ns grid, start options and the transmit rates.

# Ref: ECSS-E-ST-50-12C §8.5.2 (Error-Reset 6.4 µs, Error-Wait 12.8 µs, Ready, Started,
#      Connecting, Run), §6.6 (10 Mbit/s start-up rate).
"""

import pytest
from amaranth.sim import Simulator

from mrm_cosim.hdl.link.chars import LinkState
from mrm_cosim.hdl.link.codec import Codec

from mrm_cosim.testbench import ERROR_CLASSES, CodecPair, LineMonitor, PeerBench, run_simulation

ER, EW, READY, STARTED, CONNECTING, RUN = LinkState
SHORT = {"reset_cycles": 60, "wait_cycles": 150}


def state_trace(pair, n_cycles, *, a_ctl=None, b_ctl=None, monitor_a=None, name="trace",
                errors=None):
    """Run the pair; return per-codec lists of (first cycle, state) for each state entered.

    ``errors``, if a dict, receives each codec's error counters at the end.
    """
    trace = {"a": [], "b": []}
    a_ctl = a_ctl or (lambda cycle: {"link_start": 1})
    b_ctl = b_ctl or (lambda cycle: {"link_start": 1})

    async def testbench(ctx):
        for cycle in range(n_cycles):
            for who, codec, ctl in (("a", pair.a, a_ctl), ("b", pair.b, b_ctl)):
                for port in ("link_start", "auto_start", "link_disable"):
                    ctx.set(getattr(codec, port), ctl(cycle).get(port, 0))
                state = ctx.get(codec.state)
                if not trace[who] or trace[who][-1][1] != state:
                    trace[who].append((cycle, state))
            if monitor_a is not None:
                monitor_a.cycle(ctx.get(pair.a.d_out), ctx.get(pair.a.s_out))
            await ctx.tick()
        if errors is not None:
            for who, codec in (("a", pair.a), ("b", pair.b)):
                counts = ctx.get(codec.errors)
                errors[who] = {k: getattr(counts, k) for k in ERROR_CLASSES}

    sim = Simulator(pair)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, name)
    return trace


def test_startup_handshake_timing_at_standard_timers():
    """Two codecs with link_start: every state change on the predicted 20 ns cycle."""
    pair = CodecPair()                      # the standard's 6.4 µs / 12.8 µs / 850 ns
    monitor = LineMonitor(pair.a.slots)
    trace = state_trace(pair, 1200, monitor_a=monitor, name="startup_standard")
    assert trace["a"] == trace["b"]
    (t_er, s0), (t_ew, s1), (t_ready, s2), (t_started, s3), (t_conn, s4), (t_run, s5) = \
        trace["a"]
    assert [s0, s1, s2, s3, s4, s5] == [ER, EW, READY, STARTED, CONNECTING, RUN]
    assert (t_ew - t_er) * 20 == 6400, "Error-Reset must last 6.4 µs"
    assert (t_ready - t_ew) * 20 == 12800, "Error-Wait must last 12.8 µs"
    assert t_started - t_ready == 1, "link_start: Ready -> Started at once"
    # Started: the first NULL is queued in the first cycle, its first bit leaves the output
    # register two cycles later; a bit is 5 cycles at 10 Mbit/s; the peer sees the bit that
    # ends the NULL (bit 7) three cycles after it is on the wire (input register, receiver
    # register, state register).
    bit = 5
    assert t_conn - t_started == 2 + 7 * bit + 3
    # Connecting: the transmitter had already queued a second NULL, so the first FCT is bits
    # 16-19; it is committed at the flag bit of the next character (bit 21), when its parity
    # has checked.
    assert t_run - t_started == 2 + 21 * bit + 3
    assert t_run * 20 == 21420, "21.42 µs from reset to Run"

    # The line: only NULLs until Connecting, then FCTs; 10 Mbit/s before Run (30 slots of
    # 3.33 ns per bit), 150 Mbit/s after (2 slots).
    kinds_before_conn = {tok[0] for cyc, tok in monitor.tokens if cyc < t_conn}
    assert kinds_before_conn == {"NULL"}
    first_fct = next(cyc for cyc, tok in monitor.tokens if tok == ("FCT",))
    assert t_conn <= first_fct < t_run
    assert monitor.parity_errors == 0
    gaps = {b - a for a, b in zip(monitor.bit_slots, monitor.bit_slots[1:], strict=False)}
    run_slot = (t_run + 2) * pair.a.slots
    slow = {b - a for a, b in zip(monitor.bit_slots, monitor.bit_slots[1:], strict=False)
            if b < run_slot}
    fast = {b - a for a, b in zip(monitor.bit_slots, monitor.bit_slots[1:], strict=False)
            if a > run_slot + 30}
    slot_ns = 20 / pair.a.slots
    assert {g * slot_ns for g in slow} == {100}, "10 Mbit/s before Run"
    assert {round(g * slot_ns, 3) for g in fast} == {6.667}, "150 Mbit/s in Run"
    assert gaps == {2, 30}


def test_auto_start_waits_for_the_peers_null():
    pair = CodecPair(**SHORT)
    trace = state_trace(pair, 700, b_ctl=lambda cycle: {"auto_start": 1}, name="autostart")
    a, b = dict((s, t) for t, s in trace["a"]), dict((s, t) for t, s in trace["b"])
    assert b[READY] == a[READY]
    # b leaves Ready when a's first NULL has arrived (same path as Started -> Connecting).
    assert b[STARTED] - a[STARTED] == 2 + 7 * 5 + 3
    assert RUN in a and RUN in b
    assert trace["a"][-1][1] == RUN and trace["b"][-1][1] == RUN


def test_without_start_the_link_stays_ready_and_silent():
    pair = CodecPair(**SHORT)
    monitor = LineMonitor(pair.a.slots)
    trace = state_trace(pair, 600, a_ctl=lambda c: {}, b_ctl=lambda c: {}, monitor_a=monitor,
                        name="no_start")
    assert [s for _, s in trace["a"]] == [ER, EW, READY]
    assert [s for _, s in trace["b"]] == [ER, EW, READY]
    assert monitor.bits == [], "the transmitter stays off until Started"


def test_link_disable_overrides_link_start():
    pair = CodecPair(**SHORT)
    trace = state_trace(pair, 600, a_ctl=lambda c: {"link_start": 1, "link_disable": 1},
                        b_ctl=lambda c: {"auto_start": 1}, name="disabled")
    assert [s for _, s in trace["a"]] == [ER, EW, READY]
    assert [s for _, s in trace["b"]] == [ER, EW, READY]


def test_started_times_out_after_12_8_us_without_null():
    """A starts, B never answers: A leaves Started after exactly the wait time (12.8 µs)."""
    pair = CodecPair(reset_cycles=60, wait_cycles=640)
    trace = state_trace(pair, 1400, b_ctl=lambda c: {}, name="started_timeout")
    a = trace["a"]
    started = [t for t, s in a if s == STARTED]
    assert started
    after = next(t for t, s in a if t > started[0])
    assert (after - started[0]) * 20 == 12800
    assert dict((t, s) for t, s in a)[after] == ER
    # B got A's NULLs while in Ready (not an error), then A fell silent: B must see a
    # disconnect, which is an error in Ready.
    assert any(s == ER for t, s in trace["b"][1:])
    assert CONNECTING not in [s for _, s in a]


def test_connecting_times_out_after_12_8_us_without_fct():
    """The peer sends NULLs but never an FCT: Connecting ends in Error-Reset after exactly
    the wait time (12.8 µs, §8.5.2), the link never reaches Run, and a timeout is no error."""
    bench = PeerBench(reset_cycles=60, wait_cycles=640)
    trace = []
    result = {}

    async def testbench(ctx):
        ctx.set(bench.dut.link_start, 1)
        bench.peer.silent = False               # NULLs only, from the start
        for cycle in range(1600):
            state = ctx.get(bench.dut.state)
            if not trace or trace[-1][1] != state:
                trace.append((cycle, state))
            await bench.cycle(ctx)
        result["errors"] = bench.errors(ctx)

    sim = Simulator(bench.dut)
    sim.add_clock(20e-9)
    sim.add_testbench(testbench)
    run_simulation(sim, "connecting_timeout")
    states = [s for _, s in trace]
    assert states[:6] == [ER, EW, READY, STARTED, CONNECTING, ER], trace
    t_conn, t_after = trace[4][0], trace[5][0]
    assert (t_after - t_conn) * 20 == 12800
    assert RUN not in states
    assert any(tok == ("FCT",) for _, tok in bench.monitor.tokens), "Connecting sends FCTs"
    assert all(n == 0 for n in result["errors"].values()), result["errors"]


def test_link_disable_in_run_resets_and_peer_sees_disconnect():
    """LinkDisabled is no error for A; B sees A fall silent as a disconnect; both restart."""
    pair = CodecPair(**SHORT)
    monitor = LineMonitor(pair.a.slots)
    errors = {}

    def a_ctl(cycle):
        return {"link_start": 1, "link_disable": int(500 <= cycle < 510)}

    trace = state_trace(pair, 520, a_ctl=a_ctl, monitor_a=monitor, errors=errors,
                        name="disable_in_run")
    a_states = [s for _, s in trace["a"]]
    assert a_states == [ER, EW, READY, STARTED, CONNECTING, RUN, ER]
    assert trace["a"][-1][0] == 501, "LinkDisabled in Run: Error-Reset at the next cycle"
    assert all(n == 0 for n in errors["a"].values())

    pair = CodecPair(**SHORT)
    monitor = LineMonitor(pair.a.slots)
    trace = state_trace(pair, 1100, a_ctl=a_ctl, monitor_a=monitor, errors=errors,
                        name="disable_in_run")
    t_b_drop = next(t for t, s in trace["b"] if t > 500 and s == ER)
    # A's output register falls silent the cycle after A enters Error-Reset; B flags the
    # disconnect `disconnect_cycles` after that last transition and enters Error-Reset.
    last_cycle = max(c for c, _ in monitor.changes if c < t_b_drop)
    assert last_cycle == 502
    assert t_b_drop == last_cycle + pair.b.disconnect_cycles + 1
    assert errors["b"]["disconnect"] == 1
    assert sum(errors["b"].values()) == 1
    assert all(n == 0 for n in errors["a"].values())
    assert trace["a"][-1][1] == RUN and trace["b"][-1][1] == RUN, "both restart and reach Run"


@pytest.mark.parametrize("args,match", [
    ({"slots": 0}, "Slots"),
    ({"run_div": 0}, "Run bit period"),
    ({"disconnect_cycles": 2}, "Disconnect time"),
    ({"reset_cycles": 47}, "Reset time"),
    ({"rx_fifo_depth": 8}, "FIFO depth"),
])
def test_codec_rejects_bad_parameters(args, match):
    with pytest.raises(ValueError, match=match):
        Codec(**args)
