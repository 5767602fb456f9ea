# amaranth: UnusedElaboratable=no
"""Fault injection in a running 3-node chain: every fault detected, counted and recovered from.

Faults hit the line between node 1 and node 2 (``Chain(line_faults=True)``) while a 40-byte
package crosses it: a cut of both wires and a cut of the D wire alone (1.2 µs each, longer than
the 850 ns disconnect time) on the way down to node 3, and a single bit error on the way up
while node 3 replies. Each test checks that the two codecs of that line count the fault in the
right class, restart and reach Run again within a bound derived from the timers; that the
package the fault cut is never delivered as good (it arrives ended by EEP and is counted as
such); that the packages sent after the recovery arrive intact; and that the other links stay in
Run with no error counted.

# Ref: ECSS-E-ST-50-12C §8.5.2 (recovery through Error-Reset and Error-Wait), §8.5.3 (errors),
#      §8.5 (a packet cut by a link error ends with EEP at the receiver and is spilled at the
#      sender).
"""

import numpy as np
import pytest
from amaranth.sim import Simulator

from mrm_cosim.protocol import packet as proto
from mrm_cosim.hdl.link.chain import (
    Chain, master_receive, master_send, node_receive, node_send, read_stats,
)
from mrm_cosim.hdl.link.chars import LinkState

from mrm_cosim.testbench import ERROR_CLASSES, run_simulation

SHORT = {"reset_cycles": 60, "wait_cycles": 150}
STANDARD = {"reset_cycles": 320, "wait_cycles": 640}     # 6.4 µs, 12.8 µs
DISCONNECT = 43            # Codec default: 860 ns at 50 MHz
BIT = 5                    # cycles per line bit at the 10 Mbit/s start-up rate
CUT_CYCLES = 60            # 1.2 µs > 850 ns; ends before the receiver leaves Error-Reset
FAULT_AFTER = 12           # characters of the package across the line before the fault
HOP_MIN, HOP_MAX = 10, 14  # time-code latency per hop, cycles (docs/link.md, test_chain.py)

ER, EW, READY, STARTED, CONNECTING, RUN = LinkState

# The two codecs on the faulted line, and the links that must not notice.
LINE = ("node1.down", "node2.up")
OTHERS = ("master", "node1.up", "node2.down", "node3.up")

# Timing, in cycles, from the codec's figures in docs/link.md:
# - Detection: a disconnect is flagged DISCONNECT cycles after the cycle of the last
#   transition and the state changes a cycle later. Under a cut the last transition is at the
#   latest the cut's own edge, in the first faulty cycle. A bit error is found sooner (parity).
DETECT_MAX = DISCONNECT + 1
# - The end that detects the fault enters Error-Reset and lowers S a cycle later, D (if it was
#   high with S) one cycle after that: the standard's controlled reset, never both in one slot.
#   If that changes no line its last transition was in its last Run cycle (+ DISCONNECT + 1);
#   if S falls alone, or S and then D, the last transition is 1 or 2 cycles later
#   (+ DISCONNECT + 2, + DISCONNECT + 3), and each is one more bit on the peer's line, which
#   can complete a character whose parity then fails: the peer's state changes 1 + 3 or
#   2 + 3 register stages later. Either class is the standard's behaviour (a link that stops
#   mid-character).
PEER_OUTCOMES = {("disconnect", DISCONNECT + 1), ("disconnect", DISCONNECT + 2),
                 ("disconnect", DISCONNECT + 3), ("parity", 1 + 3), ("parity", 2 + 3)}
SILENCE_MAX = DISCONNECT + 3
# - Handshake, from the later end's Ready: the link_start end (node 1's downstream codec) is
#   Started a cycle later; its first NULL, from a freshly started transmitter, is recognised
#   2 + 7 BIT + 3 cycles later and the auto-start end starts; that end's first NULL takes as
#   long back, and node 1's codec is Connecting; its FCT may wait for the NULL being sent
#   (8 bits), then takes 4 bits plus the next flag (2 bits), queue and output register (2) and
#   3 register stages until the peer is in Run. Measured here: 118 cycles.
HANDSHAKE_MAX = 1 + 2 * (2 + 7 * BIT + 3) + (8 + 4 + 2) * BIT + 2 + 3


def recovery_max(timers):
    """Cycles from the first faulty cycle until both ends of the line are in Run again."""
    return (DETECT_MAX + SILENCE_MAX + timers["reset_cycles"] + timers["wait_cycles"] +
            HANDSHAKE_MAX)


def only(errors, name):
    """Exactly one error counted, of class ``name`` (``None``: no error at all)."""
    return errors == {k: int(k == name) for k in ERROR_CLASSES}


class FaultBench:
    """A 3-node chain with fault injection on the line above node 2, watched every cycle.

    ``trace[name]`` lists ``(cycle, LinkState)`` for every state each codec enters;
    ``fault_start`` is the first faulty cycle, ``down``/``up`` the cycles (from it) when the
    faulted line left Run and when both its ends were back in Run.
    """

    def __init__(self, timers=SHORT):
        self.timers = timers
        self.recovery_max = recovery_max(timers)
        self.chain = Chain(3, codec=timers, line_faults=True)
        n1, n2, n3 = self.chain.nodes
        self.codecs = {
            "master": self.chain.master,
            "node1.up": n1.up_codec, "node1.down": n1.down_codec,
            "node2.up": n2.up_codec, "node2.down": n2.down_codec,
            "node3.up": n3.up_codec, "node3.down": n3.down_codec,
        }
        self.trace = {name: [] for name in self.codecs}
        self.fault_start = None
        self.down = self.up = None
        self.done = False
        self.sim = Simulator(self.chain)
        self.sim.add_clock(20e-9)
        self.sim.add_testbench(self._monitor, background=True)
        self.sim.add_testbench(self._watchdog)

    def running(self, names):
        return all(self.trace[name] and self.trace[name][-1][1] == RUN for name in names)

    async def _monitor(self, ctx):
        names = list(self.codecs)
        states = [self.codecs[name].state for name in names]
        async for _, _, cycle, *values in ctx.tick().sample(self.chain.cycle, *states):
            for name, state in zip(names, values, strict=True):
                if not self.trace[name] or self.trace[name][-1][1] != state:
                    self.trace[name].append((cycle, state))
            if self.fault_start is not None and cycle >= self.fault_start:
                if self.down is None and not self.running(LINE):
                    self.down = cycle - self.fault_start
                if self.down is not None and self.up is None and self.running(LINE):
                    self.up = cycle - self.fault_start

    async def _watchdog(self, ctx):
        """Fail instead of hanging when a testbench waits for something that never comes."""
        limit = 1500 + 2 * self.recovery_max + 1500
        for _ in range(limit):
            if self.done:
                return
            await ctx.tick()
        raise AssertionError(f"scenario not finished after {limit} cycles")

    async def bring_up(self, ctx, limit=1500):
        chain = self.chain
        for _ in range(limit):
            if (ctx.get(chain.master_running) and
                    all(ctx.get(node.up_running) for node in chain.nodes) and
                    all(ctx.get(node.down_running) for node in chain.nodes[:-1])):
                return
            await ctx.tick()
        raise AssertionError(f"chain not running after {limit} cycles")

    async def recovered(self, ctx):
        limit = 2 * self.recovery_max
        for _ in range(limit):
            if self.up is not None:
                return
            await ctx.tick()
        raise AssertionError(f"line node 1 - node 2 not back in Run after {limit} cycles")

    async def inject(self, ctx, port, fault, *, after, codec_stream, duration):
        """Apply ``fault`` (field -> value of ``line_fault_layout``) on ``port`` (the chain's
        ``fault_down`` or ``fault_up``, element 1: the line above node 2) for ``duration``
        cycles, once ``after`` characters have crossed ``codec_stream``."""
        seen = 0
        while seen < after:
            _, _, valid, ready = await ctx.tick().sample(codec_stream.valid, codec_stream.ready)
            seen += valid and ready
        self.fault_start = ctx.get(self.chain.cycle)   # this cycle's samples are faulted
        for field, value in fault.items():
            ctx.set(getattr(port[1], field), value)
        await ctx.tick().repeat(duration)
        for field in fault:
            ctx.set(getattr(port[1], field), 0)

    def errors(self, ctx):
        out = {}
        for name, codec in self.codecs.items():
            counts = ctx.get(codec.errors)
            out[name] = {k: getattr(counts, k) for k in ERROR_CLASSES}
        return out

    def run(self, name):
        run_simulation(self.sim, name)

    def check_line(self, errors, detected_by, fault_class):
        """The fault was counted and recovered from: ``detected_by`` counted one error of
        ``fault_class``, its peer one of :data:`PEER_OUTCOMES`, no other codec any; both ends
        of the line went once through Error-Reset and Error-Wait (each exactly as long as its
        timer) back to Run within :func:`recovery_max`; the other links never left Run.
        Return the recovery time, cycles."""
        start = self.fault_start
        assert self.down is not None and self.up is not None, "the line must go down and up"
        assert self.down <= DETECT_MAX, f"detected {self.down} cycles after the fault"
        entered = {}
        for name in LINE:
            after = [(t, s) for t, s in self.trace[name] if t >= start]
            states = [s for _, s in after]
            assert states[:2] == [ER, EW] and states[-1] == RUN, (name, after)
            assert states.count(ER) == 1, f"{name} reset more than once: {after}"
            (t_er, _), (t_ew, _), (t_next, _) = after[:3]
            assert (t_ew - t_er, t_next - t_ew) == (self.timers["reset_cycles"],
                                                    self.timers["wait_cycles"]), (name, after)
            entered[name] = t_er
        peer = next(name for name in LINE if name != detected_by)
        assert only(errors[detected_by], fault_class), (detected_by, errors[detected_by])
        classes = [k for k, n in errors[peer].items() if n]
        assert sum(errors[peer].values()) == 1, (peer, errors[peer])
        outcome = (classes[0], entered[peer] - entered[detected_by])
        assert outcome in PEER_OUTCOMES, (peer, outcome)
        for name in (*OTHERS, "node3.down"):
            assert only(errors[name], None), (name, errors[name])
        for name in OTHERS:
            t_last, s_last = self.trace[name][-1]
            assert t_last < start and s_last == RUN, \
                f"{name} must be in Run before the fault and stay there: {self.trace[name]}"
        bound = self.recovery_max
        timers = self.timers["reset_cycles"] + self.timers["wait_cycles"]
        assert timers < self.up <= bound, f"recovery {self.up} cycles, bound {bound}"
        print(f"\nfault at cycle {start}: line down after {self.down} cycles, both ends in Run "
              f"after {self.up} cycles = {self.up * 20 / 1000:.2f} µs (bound {bound}); "
              f"{peer}: {outcome[0]} {outcome[1]} cycles after {detected_by}")
        return self.up


@pytest.mark.parametrize("name, fault, receiver_error, timers", [
    ("cut-standard-timers", {"clear_d": 0b111111, "clear_s": 0b111111}, "disconnect",
     STANDARD),
    ("d-wire-cut", {"clear_d": 0b111111}, "parity", SHORT),
])
def test_cut_on_the_way_down_is_counted_and_the_cut_package_never_delivered(
        name, fault, receiver_error, timers):
    """A 40-byte package to node 3 is cut between node 1 and node 2.

    Node 2's upstream codec sees the fault (both wires cut: no transition for 850 ns, a
    disconnect; the D wire alone: S still toggles, bits decode as zeros and a parity check
    fails at once), node 1's downstream codec then sees node 2 stop (see PEER_OUTCOMES).
    The cut of both wires runs at the standard's timers (6.4 µs, 12.8 µs).
    Node 3 receives the front of the package ended by EEP and drops it; node 1's codec spills
    the rest. The next package and a time-code cross the recovered line.
    """
    rng = np.random.default_rng(40)
    bench = FaultBench(timers)
    chain = bench.chain
    n1, _, n3 = chain.nodes
    cut, good, reply = (rng.integers(0, 256, size=proto.DATA_PAYLOAD).tolist() for _ in range(3))
    result = {}

    async def master(ctx):
        await bench.bring_up(ctx)
        await master_send(ctx, chain, proto.Header(3, 0, int(proto.PacketType.COMM_B), 1), cut)
        await bench.recovered(ctx)
        ctx.set(chain.time_in, 9)
        ctx.set(chain.tick_in, 1)
        result["tc_sent"] = ctx.get(chain.cycle)
        await ctx.tick()
        ctx.set(chain.tick_in, 0)
        await master_send(ctx, chain, proto.Header(3, 0, int(proto.PacketType.COMM_B), 2), good)

    async def fault_injector(ctx):
        await bench.inject(ctx, chain.fault_down, fault, after=FAULT_AFTER,
                           codec_stream=n1.down_codec.tx, duration=CUT_CYCLES)

    async def node3(ctx):
        header, payload = await node_receive(ctx, n3)
        assert (header, list(payload)) == (proto.Header(3, 0, proto.PacketType.COMM_B, 2), good), \
            "the first package node 3 gets must be the one sent after the recovery"
        await node_send(ctx, n3, proto.Header(0, 0, int(proto.PacketType.COMM_C), header.seq),
                        reply)

    async def master_rx(ctx):
        (packet,) = await master_receive(ctx, chain)
        assert proto.check_frame(packet) == (proto.Verdict.GOOD,
                                           proto.Header(0, 3, proto.PacketType.COMM_C, 2),
                                           bytes(reply))
        await ctx.tick().repeat(20)
        result["errors"] = bench.errors(ctx)
        result["stats"] = [read_stats(ctx, node.rx_stats) for node in chain.nodes]
        result["dropped"] = [ctx.get(node.dropped) for node in chain.nodes]
        result["tc"] = [(ctx.get(node.tc_time), ctx.get(node.tc_stamp)) for node in chain.nodes]
        bench.done = True

    bench.sim.add_testbench(master)
    bench.sim.add_testbench(fault_injector)
    bench.sim.add_testbench(node3)
    bench.sim.add_testbench(master_rx)
    bench.run(f"chain_fault_{name}")

    bench.check_line(result["errors"], "node2.up", receiver_error)
    # The cut package: counted as EEP at node 3, never delivered; nothing else was lost.
    assert result["stats"][2] == {"good": 1, "crc": 0, "length": 0, "eep": 1}
    assert result["stats"][:2] == [{"good": 0, "crc": 0, "length": 0, "eep": 0}] * 2
    assert result["dropped"] == [0, 0, 0], "the codec spills the rest, the router drops none"
    # The time-code sent after the recovery reached every node, one hop at a time.
    assert [t for t, _ in result["tc"]] == [9, 9, 9]
    hops = np.diff([result["tc_sent"], *(stamp for _, stamp in result["tc"])])
    assert ((hops >= HOP_MIN) & (hops <= HOP_MAX)).all(), hops


def test_bit_error_on_the_way_up_is_counted_and_the_cut_reply_ends_in_eep():
    """Node 3 answers a time-code with a 40-byte package; one bit of it is flipped between
    node 2 and node 1 (D and S inverted in one slot: one wrong bit, framing kept).

    Node 1's downstream codec finds the bad parity at the next character and never delivers
    the bad one; node 2's upstream codec then sees node 1 stop (see PEER_OUTCOMES). The master
    receives the front of the reply, exactly as sent, ended by EEP; node 2 spills the rest.
    The reply to the next time-code, sent after the recovery, arrives intact.
    """
    rng = np.random.default_rng(41)
    bench = FaultBench()
    chain = bench.chain
    n1, _, n3 = chain.nodes
    replies = {1: rng.integers(0, 256, size=proto.DATA_PAYLOAD).tolist(),
               2: rng.integers(0, 256, size=proto.DATA_PAYLOAD).tolist()}
    result = {}

    async def time_code(ctx, value):
        ctx.set(chain.time_in, value)
        ctx.set(chain.tick_in, 1)
        await ctx.tick()
        ctx.set(chain.tick_in, 0)

    async def master(ctx):
        await bench.bring_up(ctx)
        await time_code(ctx, 1)
        await bench.recovered(ctx)
        await time_code(ctx, 2)

    async def fault_injector(ctx):
        # D and S flipped for one bit period (slots 2 and 3 of 6): one bit's value inverted.
        await bench.inject(ctx, chain.fault_up, {"flip_d": 0b001100, "flip_s": 0b001100},
                           after=FAULT_AFTER, codec_stream=n1.down_codec.rx, duration=1)

    async def node3(ctx):
        for _ in range(2):
            await ctx.tick().until(n3.tc_strobe)
            seq = ctx.get(n3.tc_time)
            await node_send(ctx, n3, proto.Header(0, 0, int(proto.PacketType.COMM_A), seq),
                            replies[seq])

    async def master_rx(ctx):
        result["packets"] = await master_receive(ctx, chain, 2)
        await ctx.tick().repeat(20)
        result["errors"] = bench.errors(ctx)
        result["stats"] = [read_stats(ctx, node.rx_stats) for node in chain.nodes]
        result["dropped"] = [ctx.get(node.dropped) for node in chain.nodes]
        bench.done = True

    bench.sim.add_testbench(master)
    bench.sim.add_testbench(fault_injector)
    bench.sim.add_testbench(node3)
    bench.sim.add_testbench(master_rx)
    bench.run("chain_fault_bit_error")

    bench.check_line(result["errors"], "node1.down", "parity")
    cut, good = result["packets"]
    sent = proto.encode(proto.Header(0, 3, int(proto.PacketType.COMM_A), 1), replies[1])
    assert proto.check_frame(cut)[0] == proto.Verdict.EEP
    assert FAULT_AFTER <= len(cut) - 1 < len(sent) - 1
    assert cut[:-1] == sent[:len(cut) - 1], "the bad character must never be delivered"
    assert proto.check_frame(good) == (proto.Verdict.GOOD,
                                     proto.Header(0, 3, proto.PacketType.COMM_A, 2),
                                     bytes(replies[2]))
    assert result["stats"] == [{"good": 0, "crc": 0, "length": 0, "eep": 0}] * 3
    assert result["dropped"] == [0, 0, 0]
