# amaranth: UnusedElaboratable=no
"""Torque output stage: RTL == cycle-level reference; the safe state after silence."""

from amaranth.sim import Simulator
from hypothesis import given, settings
from hypothesis import strategies as st

from mrm_cosim.protocol.fixed import WORD_MAX, WORD_MIN
from mrm_cosim.hdl.node.watchdog import Watchdog
from mrm_cosim.hdl.node.watchdog_ref import WatchdogModel

from mrm_cosim.testbench import run_simulation

PULSES = ("packet", "tick", "cmd_valid", "arm", "disarm")


def run_both(events, timeout, ramp, tau_min, tau_max):
    """events: list of dicts of pulses (and cmd) per cycle."""
    dut = Watchdog()
    ref = WatchdogModel()
    rtl_out, ref_out = [], []

    async def tb(ctx):
        ctx.set(dut.timeout, timeout)
        ctx.set(dut.ramp, ramp)
        ctx.set(dut.tau_min, tau_min)
        ctx.set(dut.tau_max, tau_max)
        for ev in events:
            for name in PULSES:
                ctx.set(getattr(dut, name), int(ev.get(name, False)))
            ctx.set(dut.cmd, ev.get("cmd", 0))
            await ctx.tick()
            rtl_out.append((ctx.get(dut.torque), ctx.get(dut.armed), ctx.get(dut.tripped),
                            ctx.get(dut.safe)))
            ref.cycle(timeout=timeout, ramp=ramp, tau_min=tau_min, tau_max=tau_max, **ev)
            ref_out.append((ref.torque, int(ref.armed), int(ref.tripped), int(ref.safe)))

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
    assert rtl[-1] == (0, 1, 1, 1)                     # safe: tripped, torque zero
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
                               "cmd": st.integers(WORD_MIN, WORD_MAX)})


@settings(max_examples=30, deadline=None)
@given(events=st.lists(event, min_size=1, max_size=80), timeout=st.integers(0, 40),
       ramp=st.integers(0, 2**22), lim=st.tuples(st.integers(WORD_MIN, WORD_MAX),
                                                 st.integers(WORD_MIN, WORD_MAX)))
def test_rtl_equals_reference_on_random_pulses(events, timeout, ramp, lim):
    rtl, ref = run_both(events, timeout, ramp, min(lim), max(lim))
    assert rtl == ref
