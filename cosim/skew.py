"""Where each joint's period starts, against the master's and against the other joints'
(issue 21 item 3: the time-code's job is to keep them together).

The master starts period ``p`` at cycle ``start + p · PERIOD`` and sends the time-code then;
node ``k`` starts its own period at its timer's boundary (phase 0; the snapshot Comm A
reports, the velocity the VDC is given) and strobes ``BOUNDARY`` and ``TIMECODE`` on its
observation port, which every backend hands to the master (:attr:`PeriodRecord.node_events
<master.cycle.PeriodRecord.node_events>`: the first strobe of each name in each period).

From those, per period ``p`` and node ``k``:

* the **start offset** ``b[p, k]``: node ``k``'s boundary minus the master's period start, in
  cycles of the 50 MHz reference, taken at the master's start nearest to it (a node running
  early starts a period a few cycles before the master does: that strobe lands in the
  master's previous record, and counts here as a negative offset of period ``p``);
* the **time-code latency** ``c[p, k]``: the time-code's arrival at node ``k`` minus the
  master's period start (the chain's forwarding: 12 cycles a hop on the default link).

:func:`period_skew` reports, over the run, each node's largest ``|b|`` and its RMS (against
the master), and the spread ``max_k b − min_k b`` of each period (between the joints): its
largest value and RMS; the time-code latencies' range per node; and how many (period, node)
pairs had no boundary strobe. With every node and the master on one clock and the timers
started by one reset — today's simulation — the offsets are 0 in every period; they move
when a node's timer is re-synchronised, or runs from a clock of its own.
"""

from __future__ import annotations

import math

import numpy as np

from mrm_cosim.units import CLOCK_HZ

__all__ = ["start_offsets", "period_skew"]


def start_offsets(records, n_nodes: int, period_cycles: int, name: str = "BOUNDARY",
                  strobes=None) -> np.ndarray:
    """``(periods, n_nodes)`` float array, one row per record of ``records`` (the master's
    periods): each node's strobe ``name`` minus the master's period start, cycles (NaN where
    a period has none) — the module's ``b`` (``"BOUNDARY"``: the strobe nearest each start) or
    ``c`` (``"TIMECODE"``: the first in the period).

    ``strobes``: every ``(cycle, node)`` of ``name`` in the run (the master's
    :attr:`~master.cycle.Master.boundary_strobes`); without it, the records' first strobe of
    each period (an early boundary late in the master's previous period is then not seen)."""
    records = [r for r in records if r.start is not None]
    out = np.full((len(records), n_nodes), np.nan)
    if not records:
        return out
    first = records[0]
    base = first.start - first.index * period_cycles         # period 0's start
    row_of = {r.index: i for i, r in enumerate(records)}
    if strobes is None:
        strobes = [(cycle, node) for r in records
                   for (ev, node), cycle in r.node_events.items() if ev == name]
    for cycle, node in strobes:
        if not 1 <= node <= n_nodes:
            continue
        if name == "BOUNDARY":
            p = math.floor((cycle - base) / period_cycles + 0.5)         # the nearest start
        else:
            p = (cycle - base) // period_cycles
        i = row_of.get(p)
        if i is None:
            continue
        off = cycle - (base + p * period_cycles)
        k = node - 1
        prev = out[i, k]
        # two strobes for one start: the boundary nearer it, the first time-code
        if math.isnan(prev) or (abs(off) < abs(prev) if name == "BOUNDARY" else off < prev):
            out[i, k] = off
    return out


def period_skew(records, n_nodes: int, period_cycles: int,
                clock_hz: float = float(CLOCK_HZ), strobes=None) -> dict:
    """The run's period-start skew (module docstring), for ``summary.json``: cycles of the
    reference clock and ns. ``strobes`` as :func:`start_offsets`'.

    Returns
    -------
    dict
        ``periods``; ``node_vs_master``: ``max_abs_cycles``, ``rms_cycles`` (all nodes) and
        ``per_node`` (a list, node 1 first, of the same two); ``between_nodes``:
        ``max_cycles``, ``rms_cycles`` of each period's spread; the same in ns
        (``*_ns``); ``timecode_latency_cycles``: per node ``[min, max]`` (None where none
        arrived); ``missing``: (period, node) pairs with no boundary strobe.
    """
    b = start_offsets(records, n_nodes, period_cycles, strobes=strobes)
    c = start_offsets(records, n_nodes, period_cycles, "TIMECODE")
    ns = 1e9 / clock_hz

    def stats(x) -> tuple[float | None, float | None]:
        x = x[~np.isnan(x)]
        if x.size == 0:
            return None, None
        return float(np.abs(x).max()), float(np.sqrt(np.mean(x * x)))

    def with_ns(mx, rms, key_max="max_abs") -> dict:
        return {f"{key_max}_cycles": mx, "rms_cycles": rms,
                f"{key_max}_ns": None if mx is None else mx * ns,
                "rms_ns": None if rms is None else rms * ns}

    full = b[~np.isnan(b).any(axis=1)] if b.size else b
    spread = full.max(axis=1) - full.min(axis=1) if full.size else np.zeros(0)
    latency = []
    for k in range(n_nodes):
        col = c[:, k][~np.isnan(c[:, k])] if c.size else np.zeros(0)
        latency.append([float(col.min()), float(col.max())] if col.size else None)
    return {
        "periods": int(b.shape[0]),
        "node_vs_master": {**with_ns(*stats(b)),
                           "per_node": [with_ns(*stats(b[:, k])) for k in range(n_nodes)]},
        "between_nodes": with_ns(*stats(spread), key_max="max"),
        "timecode_latency_cycles": latency,
        "missing": int(np.isnan(b).sum()),
    }
