# amaranth: UnusedElaboratable=no
"""The link's health reaches the master: every node reports its codecs' error totals, the
frames its depacketizer dropped and the packets its router discarded in every Comm A; the
master port's own codec errors and the frames the master drops are counted; a fault injected on
a line of the running closed loop is counted where it happened, the period it hit is reported,
and the loop recovers.

# Ref: ECSS-E-ST-50-12C §8.5.3 (link errors: disconnect, parity, escape, credit), §7.4 (one
#      inverted bit fails the parity check), §8.5.2 (recovery through Error-Reset).
"""

import numpy as np
import pytest
from amaranth import Signal
from amaranth.sim import Simulator

from mrm_cosim.cosim.closed_loop import FAULT_KINDS, LineFault
from mrm_cosim.hdl.link.chain import get_packet, line_fault_layout, put_packet
from mrm_cosim.hdl.link.chars import saturating_sum
from mrm_cosim.hdl.link.codec_ref import saturating_sum_ref
from mrm_cosim.protocol.link import ERROR_CLASSES
from mrm_cosim.protocol.packet import Header, PacketType
from mrm_cosim.hdl.node.core import NodeCore
from mrm_cosim.hdl.node.core_ref import NodeModel
from mrm_cosim.protocol.regs import LINK_HEALTH, RX_DROPS, parse_comm_a
from mrm_cosim.errors import InputError

from mrm_cosim.testbench import packet_ends, run_simulation
from .test_node_core import ENC

def test_saturating_sum_equals_its_reference():
    rng = np.random.default_rng(1)
    values = [Signal(16, name=f"v{i}") for i in range(5)]
    total = Signal(16)
    cases = [[0] * 5, [0xFFFF] * 5, [0xFFFF, 0, 0, 0, 0], [0xFFFE, 1, 0, 0, 0],
             [0xFFFE, 2, 0, 0, 0]] + [list(rng.integers(0, 1 << int(rng.integers(1, 17)), 5))
                                      for _ in range(40)]
    seen = []

    async def bench(ctx):
        for case in cases:
            for s, v in zip(values, case, strict=True):
                ctx.set(s, int(v))
            seen.append(ctx.get(total))

    from amaranth import Module

    m = Module()
    m.d.comb += total.eq(saturating_sum(values))
    sim = Simulator(m)
    sim.add_testbench(bench)
    sim.run()
    assert seen == [min(sum(int(v) for v in c), 0xFFFF) for c in cases]
    assert seen == [saturating_sum_ref(c) for c in cases]
    assert 0xFFFF in seen and any(0 < s < 0xFFFF for s in seen)


def _counters(rng, big=False):
    top = 0xFFFF if big else 40
    return ({f: int(rng.integers(0, top + 1)) for f in ERROR_CLASSES},
            {f: int(rng.integers(0, top + 1)) for f in ERROR_CLASSES},
            {f: int(rng.integers(0, top + 1)) for f in ("good", *RX_DROPS)},
            int(rng.integers(0, top + 1)))


def test_comm_a_reports_the_link_counters_as_the_request_found_them():
    """Random link counters (small, and large enough to saturate the sums) change between Comm
    A requests; each reply carries the upstream and downstream error totals (five classes
    summed), the depacketizer's dropped frames (CRC, length, EEP; not the good ones) and the
    router's discards as they stood at its request — equal to the reference model's reply,
    and to sums computed here."""
    rng = np.random.default_rng(3)
    plan = [_counters(rng, big=i % 2 == 1) for i in range(6)]
    dut = NodeCore(encoder=ENC)
    ends, replies = [], []

    def apply(ctx, counters):
        up, down, rx, dropped = counters
        for f in ERROR_CLASSES:
            ctx.set(getattr(dut.up_errors, f), up[f])
            ctx.set(getattr(dut.down_errors, f), down[f])
        for f, v in rx.items():
            ctx.set(getattr(dut.rx_stats, f), v)
        ctx.set(dut.dropped, dropped)

    async def master(ctx):
        for i, counters in enumerate(plan):
            apply(ctx, counters)
            await put_packet(ctx, dut.rx, Header(dest=1, src=0, type=int(PacketType.COMM_A),
                                                 seq=i), b"\0")
            replies.append(await get_packet(ctx, dut.tx))
            # counters that change after the request are not in this reply
            apply(ctx, _counters(rng, big=True))
            await ctx.tick().repeat(3)

    sim = Simulator(dut)
    sim.add_clock(20e-9)
    sim.add_testbench(packet_ends(dut.rx, ends), background=True)
    sim.add_testbench(master)
    run_simulation(sim, "node_core_link_health")

    model = NodeModel(encoder=ENC)
    for (header, payload), c, counters in zip(replies, ends, plan, strict=True):
        up, down, rx, dropped = counters
        model.set_link(up, down, rx, dropped)
        assert header.type == PacketType.COMM_A
        assert payload == model.packet(c, PacketType.COMM_A, b"\0", sample=lambda _c: (0, 0, 0))
        a = parse_comm_a(payload)
        expect = (min(sum(up.values()), 0xFFFF), min(sum(down.values()), 0xFFFF),
                  min(rx["crc"] + rx["length"] + rx["eep"], 0xFFFF), dropped)
        assert tuple(a[k] for k in LINK_HEALTH) == expect
        assert payload[33:] == bytes(7)
    reported = [parse_comm_a(p)["up_link_errors"] for _, p in replies]
    assert 0xFFFF in reported and any(0 < r < 0xFFFF for r in reported)


def test_line_fault_values_and_bad_input():
    slots = 6
    every = (1 << slots) - 1
    names = list(line_fault_layout(slots).members)

    def fields(value):
        return {n: (value >> (slots * i)) & every for i, n in enumerate(names) if
                (value >> (slots * i)) & every}

    assert fields(LineFault(1, "up", "cut", 0).value()) == {"clear_d": every, "clear_s": every}
    # One 6.67 ns bit at 150 Mbit/s: two slots of 3.33 ns (one slot of 6.67 ns at 3 slots).
    assert fields(LineFault(1, "up", "bit", 0).value()) == {"flip_d": 3, "flip_s": 3}
    assert fields(LineFault(1, "up", "stuck-d", 0).value()) == {"clear_d": every}
    assert LineFault(2, "down", "bit", 5).port == "fault_down2"
    assert set(FAULT_KINDS) == {"cut", "bit", "stuck-d"}
    for kwargs, field in [(dict(node=0), "fault.node"), (dict(direction="left"),
                                                          "fault.direction"),
                          (dict(kind="noise"), "fault.kind"), (dict(cycle=-1), "fault.cycle"),
                          (dict(cycles=0), "fault.cycles"), (dict(cycle=1.5), "fault.cycle")]:
        args = dict(node=1, direction="up", kind="bit", cycle=0, cycles=1) | kwargs
        with pytest.raises(InputError) as e:
            LineFault(**args)
        assert e.value.field == field


def test_the_model_backend_refuses_line_faults():
    from mrm_cosim.cosim.track import run_track

    with pytest.raises(InputError) as e:
        run_track(backend="model", duration=0.002, faults=[LineFault(1, "up", "bit", 10)])
    assert e.value.field == "faults"


@pytest.fixture(scope="module")
def faulted_run():
    """3-node VDC loop on the compiled gateware; one inverted bit on the line from node 2 up to
    node 1, 6 µs into period 2 (while the Comm A replies of nodes 2 and 3 cross it)."""
    from mrm_cosim.cosim.track import run_track

    fault = LineFault(node=2, direction="up", kind="bit", cycle=2 * 50_000 + 300)
    return run_track(controller="vdc", backend="compiled", duration=0.006, faults=[fault])


def test_a_bit_error_in_the_closed_loop_is_counted_where_it_happened(faulted_run):
    result, s = faulted_run
    detail = s["link_error_detail"]
    per_node = detail["per_node"]
    # node 1's downstream codec received the bad bit: a parity error (§7.4); node 2's upstream
    # codec saw node 1 stop sending (its Error-Reset): a disconnect or parity error (§8.5.3)
    assert per_node["1"]["down_link_errors"] == 1
    assert per_node["2"]["up_link_errors"] == 1
    assert per_node["1"]["up_link_errors"] == 0 and per_node["2"]["down_link_errors"] == 0
    assert per_node["3"] == {k: 0 for k in LINK_HEALTH}
    # the reply cut by the error reached the master ended by EEP and was dropped
    assert detail["master_rx_dropped"] >= 1 and detail["master_port"] == 0
    assert s["link_errors"] == (detail["master_rx_dropped"] + detail["master_port"]
                                + sum(detail["nodes"].values()))
    # the period it hit lacks replies (an overrun); the links recovered and the next periods
    # are complete
    records = result.master.records
    assert [r.index for r in records if not r.complete] == [2]
    assert s["overruns"] == 1 and s["missing_replies"] >= 1
    assert all(r.complete for r in records[3:]) and len(records) == 6



@pytest.mark.parametrize("spec, words", [
    ("bit:up:2", "KIND:DIRECTION:NODE@TIME"),
    ("bit:up@1ms", "KIND:DIRECTION:NODE@TIME"),
    ("noise:up:2@1ms", "must be one of cut, bit, stuck-d"),
    ("bit:left:2@1ms", "'down' or 'up'"),
    ("bit:up:x@1ms", "must be a number"),
    ("bit:up:2@soon", "is not a time"),
    ("cut:down:2@1ms+long", "is not a time"),
    ("bit:up:4@1ms", "has 3 nodes"),
    ("bit:up:2@1.5ms", "after the run's end"),
])
def test_cli_refuses_bad_line_faults_naming_the_flag(tmp_path, capsys, spec, words):
    from mrm_cosim.mrm import cli

    out = tmp_path / "o"
    code = cli.main(["run", "track", "--backend", "compiled", "--duration", "0.001",
                     "--line-fault", spec, "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "--line-fault" in err and words in err
    assert not out.exists()


def test_cli_refuses_bit_level_faults_on_the_model_backend(tmp_path, capsys):
    """The model backend's link is at packet level: it takes cuts (cosim/model_link.py), not
    faults of single bits or wires."""
    from mrm_cosim.mrm import cli

    code = cli.main(["run", "track", "--backend", "model", "--duration", "0.001",
                     "--line-fault", "bit:up:1@0.5ms", "--out", str(tmp_path / "o"), "--quiet"])
    assert code == 2 and "'cut' faults only" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_line_fault_specs_parse_to_cycles():
    assert LineFault.parse("bit:up:2@2.006ms") == LineFault(2, "up", "bit", 100_300, 1)
    assert LineFault.parse("cut:down:3@10ms+2us") == LineFault(3, "down", "cut", 500_000, 100)
    assert LineFault.parse("stuck-d:up:1@0.001+20ns") == LineFault(1, "up", "stuck-d",
                                                                   50_000, 1)


def test_cli_track_with_a_line_fault_says_where_it_was_counted(tmp_path, capsys):
    """A 2 µs cut of the line above node 3 (towards it), after period 1's exchange: no reply is
    lost, both codecs of that line count it, the command says so and records the fault."""
    import json

    from mrm_cosim.mrm import cli

    out = tmp_path / "o"
    code = cli.main(["run", "track", "--backend", "compiled", "--duration", "0.003",
                     "--line-fault", "cut:down:3@1.1ms+2us", "--out", str(out)])
    captured = capsys.readouterr()
    stdout = captured.out
    assert code == 3 and "NOT A CLEAN RUN: 2 link errors" in captured.err   # exit 3: not clean
    assert "link faults counted at: node 2 downstream codec 1, node 3 upstream codec 1" in stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["link_errors"] == 2 and summary["overruns"] == 0
    assert json.loads((out / "config.json").read_text())["line_faults"] == \
        ["cut:down:3@1.1ms+2us"]
