# amaranth: UnusedElaboratable=no
"""Torque output stage: RTL == cycle-level reference; the safe stop after silence (hold,
brake, STO) and its re-arm."""

from amaranth.sim import Simulator
from hypothesis import given, settings
from hypothesis import strategies as st

from mrm_cosim.protocol.fixed import WORD_MAX, WORD_MIN
from mrm_cosim.hdl.node.watchdog import Watchdog
from mrm_cosim.hdl.node.watchdog_ref import WatchdogModel

from mrm_cosim.testbench import run_simulation

PULSES = ("packet", "tick", "cmd_valid", "arm", "disarm")


def run_both(events, timeout, ramp, tau_min, tau_max, stop_cycles=0, brake_cycles=0,
             standstill=0, standstill_ticks=0):
    """events: list of dicts of pulses (and cmd, velocity) per cycle. Outputs per cycle:
    torque, armed, tripped, safe, holding, brake, limit, rest."""
    dut = Watchdog()
    ref = WatchdogModel()
    rtl_out, ref_out = [], []

    async def tb(ctx):
        ctx.set(dut.timeout, timeout)
        ctx.set(dut.ramp, ramp)
        ctx.set(dut.tau_min, tau_min)
        ctx.set(dut.tau_max, tau_max)
        ctx.set(dut.stop_cycles, stop_cycles)
        ctx.set(dut.brake_cycles, brake_cycles)
        ctx.set(dut.standstill, standstill)
        ctx.set(dut.standstill_ticks, standstill_ticks)
        for ev in events:
            for name in PULSES:
                ctx.set(getattr(dut, name), int(ev.get(name, False)))
            ctx.set(dut.cmd, ev.get("cmd", 0))
            ctx.set(dut.velocity, ev.get("velocity", 0))
            await ctx.tick()
            rtl_out.append((ctx.get(dut.torque), ctx.get(dut.armed), ctx.get(dut.tripped),
                            ctx.get(dut.safe), ctx.get(dut.holding), ctx.get(dut.brake),
                            ctx.get(dut.limit), ctx.get(dut.rest)))
            ref.cycle(timeout=timeout, ramp=ramp, tau_min=tau_min, tau_max=tau_max,
                      stop_cycles=stop_cycles, brake_cycles=brake_cycles,
                      standstill=standstill, standstill_ticks=standstill_ticks, **ev)
            ref_out.append((ref.torque, int(ref.armed), int(ref.tripped), int(ref.safe),
                            int(ref.holding), int(ref.brake), int(ref.limit),
                            int(ref.rest(ev.get("velocity", 0)))))

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(tb)
    run_simulation(sim, "watchdog")
    return rtl_out, ref_out


def test_trips_after_two_periods_of_silence_and_ramps_to_zero():
    timeout, ramp = 200, 1000
    events = [{"arm": True}]
    events += [{"packet": k % 50 == 0, "tick": k % 10 == 0, "cmd_valid": k % 10 == 5,
                "cmd": 7000} for k in range(300)]                      # packets keep it alive
    events += [{"tick": k % 10 == 0, "cmd_valid": k % 10 == 5, "cmd": 7000}
               for k in range(400)]                                    # master silent
    rtl, ref = run_both(events, timeout, ramp, -5000, 5000)
    assert rtl == ref
    assert rtl[300][0] == 5000 and not rtl[300][2]     # limited command applied
    trip = next(k for k, o in enumerate(rtl) if o[2])
    last_packet = 1 + 250                              # event index of the last packet
    assert trip == last_packet + 1 + timeout
    assert rtl[-1][:7] == (0, 1, 1, 1, 0, 1, 0)        # safe: tripped, torque zero, braked
    torques = [o[0] for o in rtl[trip:]]
    assert all(a - b in (0, ramp) or b == 0 for a, b in zip(torques, torques[1:], strict=False))


def test_disarmed_joint_has_no_torque_and_arm_clears_a_trip():
    events = [{"cmd_valid": True, "cmd": 100}] * 3 + [{"arm": True}] + \
        [{"cmd_valid": True, "cmd": 100}] * 30 + [{"arm": True}] + [{"cmd_valid": True, "cmd": 5}]
    rtl, ref = run_both(events, 10, 3, -1000, 1000)
    assert rtl == ref
    assert rtl[2][0] == 0
    assert rtl[20][2] == 1                             # tripped after 10 silent cycles
    assert rtl[-1][:3] == (5, 1, 0)


pulse = st.booleans()
event = st.fixed_dictionaries({"packet": pulse, "tick": pulse, "cmd_valid": pulse,
                               "arm": st.sampled_from([False] * 5 + [True]),
                               "disarm": st.sampled_from([False] * 9 + [True]),
                               "cmd": st.integers(WORD_MIN, WORD_MAX),
                               "velocity": st.sampled_from([0, 1, -1, 3, -3, 4, -4, 100,
                                                            WORD_MIN, WORD_MAX])})


@settings(max_examples=30, deadline=None)
@given(events=st.lists(event, min_size=1, max_size=80), timeout=st.integers(0, 40),
       ramp=st.integers(0, 2**22), lim=st.tuples(st.integers(WORD_MIN, WORD_MAX),
                                                 st.integers(WORD_MIN, WORD_MAX)),
       stop=st.integers(0, 40), brake=st.integers(0, 12),
       standstill=st.sampled_from([0, 1, 3, 4, 2**23, 2**24 - 1]),
       ticks=st.integers(0, 4))
def test_rtl_equals_reference_on_random_pulses(events, timeout, ramp, lim, stop, brake,
                                               standstill, ticks):
    rtl, ref = run_both(events, timeout, ramp, min(lim), max(lim), stop, brake, standstill,
                        ticks)
    assert rtl == ref


def test_safe_stop_holds_then_brakes_then_ramps_and_arm_releases():
    """SS1-t: after the trip the commands still apply (the engine holds) for stop + brake
    cycles, the brake from stop cycles on, then STO's ramp; ARM releases the brake."""
    timeout, ramp, stop, brake = 20, 1000, 30, 40
    events = [{"arm": True}] + [{"packet": True, "cmd_valid": True, "cmd": 4000}] * 5
    events += [{"tick": k % 10 == 0, "cmd_valid": k % 10 == 5, "cmd": 3000 + k}
               for k in range(150)]
    events += [{"arm": True}] + [{"cmd_valid": True, "cmd": 10}] * 3
    rtl, ref = run_both(events, timeout, ramp, -5000, 5000, stop, brake)
    assert rtl == ref
    trip = next(k for k, o in enumerate(rtl) if o[2])
    assert trip == 5 + 1 + timeout                     # the last packet's index is 5
    assert all(o[4] for o in rtl[trip:trip + stop + brake])      # holding
    assert not any(o[5] for o in rtl[trip:trip + stop])          # brake released
    assert all(o[5] for o in rtl[trip + stop:-4])                # brake engaged to the ARM
    hold_cmds = [o[0] for o in rtl[trip + 10:trip + stop + brake]]
    assert len(set(hold_cmds)) > 1 and all(t > 3000 for t in hold_cmds)   # commands applied
    sto = rtl[trip + stop + brake:-4]
    assert not any(o[4] for o in sto) and sto[-1][0] == 0 and sto[-1][3] == 1
    assert rtl[-1][:7] == (10, 1, 0, 0, 0, 0, 0)      # re-armed: brake off, commands apply


def test_disarm_while_holding_engages_the_brake_at_once():
    timeout, stop, brake = 5, 50, 50
    events = [{"arm": True}] + [{"cmd_valid": True, "cmd": 100}] * 12 + [{"disarm": True}] + \
        [{"cmd_valid": True, "cmd": 100}] * 3
    rtl, ref = run_both(events, timeout, 1, -1000, 1000, stop, brake)
    assert rtl == ref
    assert rtl[12][4] == 1 and rtl[12][5] == 0          # holding, brake released
    assert rtl[-1][:7] == (0, 0, 1, 1, 0, 1, 0)         # disarmed: no torque, brake engaged


def _stopping(speeds, tick=10):
    """Silence after an arm and five packets; the velocity word at the k-th tick after the
    last packet is ``speeds(k)`` (between ticks: a value far outside any threshold, which
    must not count)."""
    events = [{"arm": True}] + [{"packet": True, "cmd_valid": True, "cmd": 4000}] * 5
    events += [{"tick": k % tick == 0, "cmd_valid": k % tick == 5, "cmd": 3000 + k,
                "velocity": speeds(k // tick) if k % tick == 0 else 10**6}
               for k in range(400)]
    return events


def test_standstill_engages_the_brake_before_the_time_limit():
    """SS1 with monitored standstill: the velocity within ±standstill at ``ticks``
    consecutive ticks engages the brake from the next cycle; a tick outside restarts the
    count; BRAKE_CYCLES count from the brake's first cycle; the time limit is not reached."""
    timeout, stop, brake, thr, n = 20, 300, 40, 4, 3
    # ticks 0..6 moving; 7, 8 still; 9 moving (restarts); 10, 11, 12 still → brake after 12
    speeds = lambda k: 5 if k < 7 or k == 9 else (-4 if k % 2 else 4)   # noqa: E731
    rtl, ref = run_both(_stopping(speeds), timeout, 1000, -5000, 5000, stop, brake, thr, n)
    assert rtl == ref
    trip = next(k for k, o in enumerate(rtl) if o[2])
    engage = next(k for k, o in enumerate(rtl) if o[5])
    assert engage == 6 + 12 * 10                       # seen after tick 12 (its index)
    assert engage < trip + stop
    assert all(o[4] for o in rtl[trip:engage + brake])           # holding to brake cycles on
    assert not any(o[4] for o in rtl[engage + brake:])
    assert all(o[5] and not o[6] for o in rtl[engage:])          # braked, not at the limit
    # rest: at the first tick within ±standstill (tick 7), not at a moving one, and from the
    # brake on whatever the velocity; with the rule off, always (the hold's target frozen at
    # its first tick, the step of the fixed timer)
    first_still = 6 + 7 * 10
    assert rtl[first_still][7] == 1 and rtl[first_still - 10][7] == 0
    assert rtl[6 + 9 * 10][7] == 0
    assert all(o[7] for o in rtl[engage:])
    off, _ = run_both(_stopping(speeds), timeout, 1000, -5000, 5000, stop, brake, 0, n)
    assert all(o[7] for o in off)


def test_standstill_ignored_would_fail():
    """The same stop without the standstill rule (threshold 0) brakes at the time limit:
    the test above tells the two apart."""
    timeout, stop, brake = 20, 300, 40
    speeds = lambda k: 0                                            # noqa: E731
    off, ref = run_both(_stopping(speeds), timeout, 1000, -5000, 5000, stop, brake, 0, 3)
    assert off == ref
    on, ref = run_both(_stopping(speeds), timeout, 1000, -5000, 5000, stop, brake, 4, 3)
    assert on == ref
    trip = next(k for k, o in enumerate(off) if o[2])
    assert next(k for k, o in enumerate(off) if o[5]) == trip + stop
    assert next(k for k, o in enumerate(on) if o[5]) < trip + 40


def test_no_standstill_brakes_at_the_time_limit_and_says_so():
    """A joint never seen at standstill: the brake at STOP_CYCLES into the trip (SS1-t as a
    fallback), ``limit`` set from then on; BRAKE_CYCLES from there."""
    timeout, stop, brake = 20, 100, 40
    speeds = lambda k: 5 if k % 3 == 0 else 0                       # noqa: E731
    rtl, ref = run_both(_stopping(speeds), timeout, 1000, -5000, 5000, stop, brake, 4, 3)
    assert rtl == ref
    trip = next(k for k, o in enumerate(rtl) if o[2])
    assert not any(o[5] or o[6] for o in rtl[:trip + stop])
    assert all(o[5] and o[6] for o in rtl[trip + stop:])
    assert all(o[4] for o in rtl[trip:trip + stop + brake])
    assert not any(o[4] for o in rtl[trip + stop + brake:])


def test_the_safe_stop_timers_are_24_bits_and_config_ignores_larger_values():
    """STOP_CYCLES and BRAKE_CYCLES are 24-bit registers (0.336 s at 50 MHz; 32 bits did not
    fit the XC2V1000, docs/node.md "Resources"): the gateware's CONFIG ignores a value of
    2^24 or more, as the reference does, and the master refuses such a duration naming it."""
    import pytest
    from mrm_cosim.errors import InputError
    from mrm_cosim.hdl.node.config import NodeConfig
    from mrm_cosim.hdl.node.core_ref import NodeModel
    from mrm_cosim.protocol.encoder import EncoderParams
    from mrm_cosim.protocol.regs import Config
    from mrm_cosim.protocol.safe_stop import SAFE_STOP_CYCLES_MAX, SafeStopParams

    assert SAFE_STOP_CYCLES_MAX == (1 << 24) - 1
    writes = [(Config.STOP_CYCLES, (1 << 24) - 1), (Config.BRAKE_CYCLES, 12_345),
              (Config.STOP_CYCLES, 1 << 24), (Config.BRAKE_CYCLES, (1 << 32) - 1)]
    dut = NodeConfig()
    seen = []

    async def bench(ctx):
        for reg, value in writes:
            ctx.set(dut.config.valid, 1)
            ctx.set(dut.config.p.id, int(reg))
            ctx.set(dut.config.p.value, value)
            await ctx.tick()
            ctx.set(dut.config.valid, 0)
            await ctx.tick()            # NodeConfig holds the record: it acts a cycle later
            seen.append((ctx.get(dut.stop_cycles), ctx.get(dut.brake_cycles)))

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(bench)
    run_simulation(sim, "config_timers")
    want = [((1 << 24) - 1, 0), ((1 << 24) - 1, 12_345), ((1 << 24) - 1, 12_345),
            ((1 << 24) - 1, 12_345)]
    assert seen == want
    model = NodeModel(encoder=EncoderParams())
    for reg, value in writes:
        model._config(0, reg, value)
    assert (model.config[Config.STOP_CYCLES], model.config[Config.BRAKE_CYCLES]) == want[-1]
    with pytest.raises(InputError, match="24-bit") as err:
        SafeStopParams(stop_s=0.34)
    assert err.value.field == "safe_stop.stop_s"
    SafeStopParams(stop_s=SAFE_STOP_CYCLES_MAX / 50e6, brake_s=0.3)
