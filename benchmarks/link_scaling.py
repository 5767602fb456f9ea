"""How far the link scales: the A/B/C/D exchange time of a VDC period for N = 1…16 nodes.

Run on purpose (not a test): ``python benchmarks/link_scaling.py [--measure] [--plot PNG]
[--json]``. The exchange is computed from the measured per-hop latency and the packets'
line time; ``--measure`` also runs the closed loop on the model backend for 3 (``mrm3``) and 6
(``mrm6``) nodes (``mrm run track --backend model --controller vdc --duration 0.01``) and
prints the computed and the measured phase ends side by side. docs/scaling.md has the table,
the plot and where every figure comes from.

The computation, per period (cycles of 20 ns from the period start; node k = 1…N):

* time-code, then the broadcast Comm A request: node k takes it at
  ``T_tc + F(1) + h₁ + h (k − 1) + 1``; it answers a cycle later, the reply's first character
  is offered one cycle after that;
* replies travel up ``h₁ + h (k − 1)`` and take ``F(40)`` of line time; they share the master's
  upstream link, so each one ends at ``max(its own path, the previous one's end) + F(40)``;
* the master computes ``kinematics_cycles`` after the last Comm A, then sends N Comm B (40
  bytes each) back to back and the broadcast Comm C request; node k's Comm B is in its core
  ``k F(40) + h₁ + h (k − 1) + 40 + 13`` after they start (a byte a cycle and 13 word writes,
  docs/node.md), and its VDC passes its MARK ``V`` = 282 cycles after the next cycle;
* node k answers Comm C when it has both the request and the MARK; replies share the upstream
  link as for Comm A; the master computes ``force_cycles`` after the last one, then sends N
  Comm D (40 bytes; in the core after 40 + 3 word writes: ``g_C``). The exchange ends when
  node N has its Comm D.

Figures: ``F(p) = ⌈((4 + p + 2)·10 + 4) / 3⌉`` — header 4, payload p, CRC 2 data characters of
``DATA_BITS`` = 10 line bits and an EOP of ``CONTROL_BITS`` = 4 (:mod:`hdl.link.chars`), 3 line
bits per 20 ns cycle at 150 Mbit/s; ``T_tc = ⌈TIME_BITS / 3⌉`` = 5 (the time-code's line time,
the request waits behind it); ``h₁`` = 9, ``h`` = 11: the measured first-character latencies of
docs/link.md "Per-hop latency" (master → node 1, node k → node k + 1); the request payloads
are one byte (:class:`master.cycle.Master` sends ``b"\\0"``), the replies, Comm B and Comm D
``PAYLOAD`` = 40 bytes (:mod:`protocol.regs`); the master's compute times are
:class:`master.cycle.MasterTiming`'s defaults (20 µs each). Nothing is imported from the
model backend's internals: it is what the computation is checked against.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from mrm_cosim.master.cycle import MasterTiming
from mrm_cosim.protocol.link import CONTROL_BITS, DATA_BITS, TIME_BITS
from mrm_cosim.protocol.packet import CRC_BYTES, HEADER_BYTES
from mrm_cosim.protocol.regs import COMM_B_WORDS, PAYLOAD
from mrm_cosim.units import CLOCK_HZ

#: Line bits per 20 ns cycle at 150 Mbit/s.
LINE_BITS_PER_CYCLE = 3
#: docs/link.md "Per-hop latency": first character, master tx → node 1 rx, and per further hop.
FIRST_HOP = 9
HOP = 11
#: The broadcast requests (Comm A, Comm C) carry one byte.
REQUEST_PAYLOAD = 1
#: docs/node.md: the VDC passes its MARK (forces ready) 282 cycles after its start.
VDC_MARK = 282
#: Word writes through an engine's host port while a packet is taken in (docs/node.md):
#: Comm B's 13 words into the VDC, Comm D's three gravity words g_C.
COMM_B_WRITES = len(COMM_B_WORDS)
COMM_D_WRITES = 3
#: Node addresses 1..254 (255 is the broadcast): the packet header's limit on N.
MAX_ADDRESS = 254
US_PER_CYCLE = 1e6 / CLOCK_HZ


def frame_cycles(payload: int) -> int:
    """Line time of a packet with ``payload`` bytes (header, payload, CRC, EOP), cycles."""
    bits = (HEADER_BYTES + payload + CRC_BYTES) * DATA_BITS + CONTROL_BITS
    return -(-bits // LINE_BITS_PER_CYCLE)


@dataclass(frozen=True)
class Exchange:
    """Phase ends of one VDC period, cycles from the period start (names as ``phases_us``)."""

    n: int
    A: int          # last Comm A reply in
    B: int          # Comm B sent
    C: int          # last Comm C reply in
    D: int          # Comm D sent
    end: int        # node N has its Comm D

    def us(self) -> dict:
        return {k: getattr(self, k) * US_PER_CYCLE for k in ("A", "B", "C", "D", "end")}


def exchange(n: int, timing: MasterTiming | None = None, vdc_mark: int = VDC_MARK) -> Exchange:
    """The A/B/C/D exchange of ``n`` nodes (see the module docstring)."""
    if n < 1 or n > MAX_ADDRESS:
        raise ValueError(f"n must be in 1..{MAX_ADDRESS}, not {n!r}")
    timing = timing or MasterTiming()
    F, F1 = frame_cycles(PAYLOAD), frame_cycles(REQUEST_PAYLOAD)
    t_tc = -(-TIME_BITS // LINE_BITS_PER_CYCLE)
    down = [FIRST_HOP + HOP * k for k in range(n)]       # first character to node k + 1

    def replies(ready):           # reply FSM leaves Idle at ready[k]; shared upstream link
        end = 0
        for k in range(n):
            end = max(ready[k] + 1 + down[k], end) + F
        return end

    rx_a = [t_tc + F1 + down[k] + REQUEST_PAYLOAD for k in range(n)]
    a_done = replies([t + 1 for t in rx_a])
    b_sent = a_done + timing.kinematics_cycles
    rx_b = [b_sent + (k + 1) * F + down[k] + PAYLOAD + COMM_B_WRITES for k in range(n)]
    rx_c = [b_sent + n * F + F1 + down[k] + REQUEST_PAYLOAD for k in range(n)]
    c_done = replies([max(rx_c[k], rx_b[k] + 1 + vdc_mark) + 1 for k in range(n)])
    d_sent = c_done + timing.force_cycles
    rx_d = d_sent + n * F + down[n - 1] + PAYLOAD + COMM_D_WRITES
    return Exchange(n, a_done, b_sent, c_done, d_sent, rx_d)


def largest_n(limit_cycles: int, timing: MasterTiming | None = None) -> int:
    """Largest N whose exchange ends by ``limit_cycles`` (0 if not even one node fits)."""
    best = 0
    for n in range(1, MAX_ADDRESS + 1):
        if exchange(n, timing).end > limit_cycles:
            break
        best = n
    return best


def measure(robot: str, out: Path) -> dict:
    """Run the model backend for ``robot`` and return its measured phase ends, µs.

    ``A`` … ``D`` are ``summary.json``'s ``phases_us``; ``end`` is the mean over complete
    periods of the last node's ``RX_D`` in ``timeline.json``.
    """
    cmd = [sys.executable, "-m", "mrm_cosim.mrm.cli", "run", "track", "--backend", "model",
           "--robot", robot, "--controller", "vdc", "--duration", "0.01", "--out", str(out)]
    subprocess.run(cmd, check=True, capture_output=True)
    return read_measured(out)


def read_measured(out: Path) -> dict:
    """Measured phase ends (µs) of a finished ``mrm run track`` result folder."""
    summary = json.loads((out / "summary.json").read_text())
    timeline = json.loads((out / "timeline.json").read_text())
    phases = summary["phases_us"]
    ends = [max(ev["RX_D"] for ev in rec["node_events"].values()) - rec["start_cycle"]
            for rec in timeline if rec["complete"]]
    return {"n": len(phases["commit"]), **{k: phases[k] for k in "ABCD"},
            "end": sum(ends) / len(ends) * US_PER_CYCLE}


def table(ns=range(1, 17), timing: MasterTiming | None = None) -> str:
    """Markdown table of the computed exchange for each N."""
    timing = timing or MasterTiming()
    period_us = timing.period_cycles * US_PER_CYCLE
    lines = ["| N | last A in (µs) | B sent | last C in | D sent | node N has D (µs) | "
             "share of 1 ms |", "|---|---|---|---|---|---|---|"]
    for n in ns:
        e = exchange(n, timing).us()
        lines.append(f"| {n} | {e['A']:.2f} | {e['B']:.2f} | {e['C']:.2f} | {e['D']:.2f} | "
                     f"{e['end']:.2f} | {100 * e['end'] / period_us:.1f} % |")
    return "\n".join(lines) + "\n"


def plot(path: Path, measured: list[dict], timing: MasterTiming | None = None,
         commit_cycles: int = 10_000) -> None:
    """The exchange over N (1…16 and on to the largest N of the period), with the measured
    runs, the commit phase and the period."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    timing = timing or MasterTiming()
    n_max = largest_n(timing.period_cycles, timing)
    ns = list(range(1, n_max + 6))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, upto in zip(axes, (16, ns[-1]), strict=True):
        sub = [n for n in ns if n <= upto]
        for key, label in (("A", "last Comm A in"), ("C", "last Comm C in"),
                           ("end", "node N has Comm D")):
            ax.plot(sub, [exchange(n, timing).us()[key] for n in sub], marker="." if
                    upto == 16 else None, label=label)
        for m in measured:
            ax.plot([m["n"]] * 2, [m["C"], m["end"]], "kx", markersize=8)
        ax.axhline(commit_cycles * US_PER_CYCLE, color="tab:red", ls="--", lw=1,
                   label="commit phase (200 µs)")
        if upto > 16:
            ax.axhline(timing.period_cycles * US_PER_CYCLE, color="k", lw=1, label="1 ms period")
            ax.axvline(n_max, color="gray", ls=":", lw=1)
            ax.annotate(f"N = {n_max}", (n_max, 500), rotation=90, ha="right")
        ax.set_xlabel("nodes N")
        ax.set_ylabel("µs from the period start")
        ax.grid(alpha=0.3)
    axes[0].set_title("A/B/C/D exchange, N = 1…16 (× measured, model backend)")
    axes[1].set_title("up to the 1 ms period")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--measure", action="store_true",
                   help="also run mrm3 and mrm6 on the model backend and compare")
    p.add_argument("--plot", type=Path, help="write the plot to this PNG")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    args = p.parse_args(argv)
    timing = MasterTiming()
    measured = []
    if args.measure:
        with tempfile.TemporaryDirectory() as tmp:
            measured = [measure(robot, Path(tmp) / robot) for robot in ("mrm3", "mrm6")]
    result = {"exchange_us": {n: exchange(n, timing).us() for n in range(1, 17)},
              "largest_n_period": largest_n(timing.period_cycles, timing),
              "largest_n_commit_200us": largest_n(10_000, timing),
              "measured_us": measured,
              "computed_us": [exchange(m["n"], timing).us() for m in measured]}
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        print(table(timing=timing))
        print(f"largest N within the 1 ms period: {result['largest_n_period']}; "
              f"with Comm D before the default commit phase (200 µs): "
              f"{result['largest_n_commit_200us']}")
        for m, c in zip(measured, result["computed_us"], strict=True):
            diffs = ", ".join(f"{k} {m[k]:.2f}/{c[k]:.2f}" for k in ("A", "B", "C", "D", "end"))
            print(f"N = {m['n']} measured/computed µs: {diffs}")
    if args.plot:
        plot(args.plot, measured, timing)
    return 0


if __name__ == "__main__":
    sys.exit(main())
