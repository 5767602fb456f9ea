"""The closed-loop fault campaign (``kind = "link-faults"``, ``[campaign] level = "loop"``).

A point is one closed-loop run of the paper's quintic (the experiment config's robot, gains,
timing and plant; one controller, on the compiled or pysim gateware) with several line faults
(:class:`cosim.closed_loop.LineFault`: its kinds ``cut``, ``bit``, ``stuck-d``; the other kinds
of the link-level campaign have no injection point in the running chain), and the same run
without faults, its reference. Spec::

    [campaign]
    level = "loop"
    config = "table2"           # a package config or a path (robot, gains, timing, plant)
    controller = "vdc"
    backend = "compiled"        # or "pysim" (the model backend's link is ideal)
    seeds = [0, 1]              # one point per seed: the plant's draw and the faults' draw
    duration = 0.012            # s of closed loop per run (from period 0)
    window = [0.002, 0.010]     # s: the faults' slots cover this span, in whole periods
    faults_per_run = 4          # one slot each, equal, at least 2 periods long
    kinds = ["cut", "bit", "stuck-d"]
    cycles = [10, 2000]         # cut / stuck-d length range, cycles (bit: 1)

Spacing: slot ``k`` of a run spans whole periods; its fault starts at a random cycle of the
slot's first period (any phase of the A/B/C/D cycle) and is judged over the rest of the slot,
so each fault is judged on its own (the link recovers in tens of µs, the loop in a period or
two). Per fault:

- ``moved``: the counters that moved in its slot (the master's dropped frames and port codec,
  each node's link health from Comm A), and ``missing`` / ``overruns`` (the master's);
- ``corrupted``: frames the master accepted that crossed the faulty line while the fault
  lasted (an ``up`` fault above node ``k``: frames from nodes ``k`` and beyond, arriving from
  the fault's first cycle to ``SLACK`` cycles after its last) and differ from the reference
  run's frame of the same source, type and sequence number. Before the fault both runs are the
  same bit for bit; a frame on the line during the fault that is accepted with other bytes was
  changed on the way, or carries a state the fault already changed (a pessimistic count of the
  failure that must never happen). A ``down`` fault's frames go to the nodes, out of the
  master's sight: the link-level campaign judges those (the same codec and CRC);
- ``periods_lost`` (periods of the slot the master judged incomplete), ``recovery_ms`` (from
  the fault to the start of the first period after it from which every period of the slot is
  complete; 0 when none was lost);
- ``dev_rad``: the largest joint deviation from the reference over the slot, and
  ``dev_before_rad`` the deviation at the slot's start (what earlier faults of the run left).
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections import Counter
from pathlib import Path

import numpy as np

from mrm_cosim.errors import InputError

__all__ = ["check_loop_campaign", "expand_loop", "run_loop_point", "write_loop_summary",
           "run_probe"]

_KEYS = {"level", "config", "controller", "backend", "seeds", "duration", "window",
         "faults_per_run", "kinds", "cycles"}
#: Cycles after a fault's last in which a frame that crossed the line during it still arrives
#: (a frame of the chain's longest reply at 150 Mbit/s through every hop: ~100-200 cycles).
SLACK = 500
MAX_LOOP_DURATION = 2.0


def _number(v, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise InputError(where, f"must be a number, not {v!r}")
    return float(v)


def check_loop_campaign(camp: dict, base_dir: Path) -> dict:
    """Validate the [campaign] table of level "loop"; return it with defaults filled in."""
    from mrm_cosim.cosim.closed_loop import FAULT_KINDS
    from mrm_cosim.cosim.experiment_config import load
    from mrm_cosim.cosim.sweep import _config_path, _seeds
    from mrm_cosim.master.cycle import CONTROLLERS

    for key in camp:
        if key not in _KEYS:
            raise InputError(f"campaign.{key}", "unknown key for level = \"loop\"; known: "
                             f"{', '.join(sorted(_KEYS))}")
    source = camp.get("config", "table2")
    if not isinstance(source, str) or not source:
        raise InputError("campaign.config", f"must be a config name or path, not {source!r}")
    try:
        config = load(_config_path(source, base_dir))
    except InputError as exc:
        raise InputError("campaign.config", f"{exc.field}: {exc.message}") from None
    clocks = config.clocks
    if not clocks.common or clocks.discipline:
        # run_probe builds its loop on one clock, without the discipline's upload
        raise InputError("campaign.config", f"{source}: [clocks] (mode {clocks.mode!r}, "
                         f"discipline {clocks.discipline}): the loop campaign runs every node "
                         "on one clock and free-running timers; use a config without [clocks]")
    controller = camp.get("controller", "vdc")
    if controller not in CONTROLLERS:
        raise InputError("campaign.controller", f"unknown controller {controller!r}; known: "
                         f"{', '.join(CONTROLLERS)}")
    backend = camp.get("backend", "compiled")
    if backend not in ("compiled", "pysim"):
        raise InputError("campaign.backend", f"must be compiled or pysim (the model backend's "
                         f"link is ideal), not {backend!r}")
    try:
        seeds = _seeds(camp.get("seeds", [0]))
    except InputError as exc:
        raise InputError(exc.field.replace("sweep.", "campaign."), exc.message) from None
    duration = _number(camp.get("duration", 0.012), "campaign.duration")
    if not 0 < duration <= MAX_LOOP_DURATION:
        raise InputError("campaign.duration", f"must be in (0, {MAX_LOOP_DURATION}] s, not "
                         f"{duration!r}")
    period = config.timing.period_cycles
    from mrm_cosim.units import CLOCK_HZ

    window = camp.get("window", [0.002, duration - 0.002])
    if not isinstance(window, list) or len(window) != 2:
        raise InputError("campaign.window", f"must be [start, end] in s, not {window!r}")
    w0, w1 = (_number(w, "campaign.window") for w in window)
    if not 0 <= w0 < w1 <= duration:
        raise InputError("campaign.window", f"must satisfy 0 ≤ start < end ≤ duration "
                         f"({duration:g} s), not {window!r}")
    n = camp.get("faults_per_run", 4)
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise InputError("campaign.faults_per_run", f"must be a whole number ≥ 1, not {n!r}")
    p0 = math.ceil(round(w0 * CLOCK_HZ) / period)
    p1 = round(w1 * CLOCK_HZ) // period
    slot = (p1 - p0) // n
    if slot < 2:
        raise InputError("campaign.faults_per_run", f"{n} faults need {2 * n} whole periods in "
                         f"the window, it holds {max(0, p1 - p0)}: each fault is judged on "
                         "its own")
    kinds = camp.get("kinds", sorted(FAULT_KINDS))
    if not isinstance(kinds, list) or not kinds:
        raise InputError("campaign.kinds", f"must be a non-empty list of "
                         f"{', '.join(FAULT_KINDS)}")
    for k in kinds:
        if k not in FAULT_KINDS:
            raise InputError("campaign.kinds", f"unknown closed-loop fault kind {k!r}; known: "
                             f"{', '.join(FAULT_KINDS)} (the others are link-level only)")
    cycles = camp.get("cycles", [10, 2000])
    if (not isinstance(cycles, list) or len(cycles) != 2 or
            not all(isinstance(c, int) and not isinstance(c, bool) for c in cycles) or
            not 1 <= cycles[0] <= cycles[1] <= slot * period // 2):
        raise InputError("campaign.cycles", f"must be [min, max] whole cycles, 1 ≤ min ≤ max ≤ "
                         f"{slot * period // 2} (half a slot), not {cycles!r}")
    return {"level": "loop", "config": source, "controller": controller, "backend": backend,
            "seeds": list(seeds), "duration": duration, "window": [w0, w1],
            "faults_per_run": n, "kinds": list(kinds), "cycles": list(cycles),
            "slot_periods": slot, "first_period": p0, "resolved": config.to_dict()}


def draw_faults(camp: dict, seed: int) -> list[dict]:
    """The faults of the run of ``seed``: one per slot, kind, line and length at random."""
    rng = np.random.default_rng([seed, 22])
    from mrm_cosim.cosim.experiment_config import from_dict

    config = from_dict(camp["resolved"])
    from mrm_cosim.models.robot import load_robot

    n_nodes = load_robot(config.robot).n
    period = config.timing.period_cycles
    out = []
    for k in range(camp["faults_per_run"]):
        kind = str(rng.choice(camp["kinds"]))
        start = (camp["first_period"] + k * camp["slot_periods"]) * period
        lo, hi = camp["cycles"]
        out.append({"kind": kind, "node": int(rng.integers(1, n_nodes + 1)),
                    "direction": str(rng.choice(["down", "up"])),
                    "cycle": start + int(rng.integers(0, period)),
                    "cycles": 1 if kind == "bit" else int(rng.integers(lo, hi + 1)),
                    "slot": [start, start + camp["slot_periods"] * period]})
    return out


def expand_loop(spec) -> list[dict]:
    c = spec.campaign
    points = []
    for seed in c["seeds"]:
        task = {"level": "loop", "seed": seed,
                **{k: c[k] for k in ("controller", "backend", "duration", "resolved")},
                "faults": draw_faults(c, seed)}
        pid = hashlib.sha256(json.dumps(task, sort_keys=True).encode()).hexdigest()[:16]
        points.append({"id": pid, "params": {}, "seed": seed, "controller": c["controller"],
                       "backend": c["backend"], "kind": "link-faults", "task": task})
    return points


def run_probe(config, controller: str, backend: str, duration: float, seed: int, faults=()):
    """One closed-loop run as :func:`cosim.track.run_track` runs it, with a probe on the
    master: every accepted packet (cycle, period, source, type, payload) and the counters as
    they stood at each. Returns ``(LoopResult, packets, snapshots)``."""
    from mrm_cosim.cosim.closed_loop import ClosedLoop
    from mrm_cosim.cosim.table2 import _run_kwargs
    from mrm_cosim.cosim.track import (START_CYCLE, _trajectory, loop_backend, run_track)
    from mrm_cosim.master.cycle import Master
    from mrm_cosim.master.uploads import node_uploads, pid_gains
    from mrm_cosim.models.plant import make_plant
    from mrm_cosim.models.robot import load_robot
    from mrm_cosim.cosim.preview import paper_test_profile
    from mrm_cosim.units import CLOCK_HZ

    robot = load_robot(config.robot)
    gains, timing = config.gains, config.timing
    profile = _run_kwargs(run_track, config, robot).get("profile") or paper_test_profile(robot)
    safety = config.faults          # [safety]: the nodes' safe stop and the master's recovery
    uploads = node_uploads(robot, controller, gains, period_cycles=timing.period_cycles,
                           safe_stop=safety.safe_stop)
    packets, snaps = [], []
    holder = {}

    class Probe(Master):
        def on_packet(self, now, src, ptype, payload, seq=None):
            out = super().on_packet(now, src, ptype, payload, seq)
            packets.append((now, seq, src, int(ptype), bytes(payload)))
            be = holder["be"]
            snaps.append((now, _counters(self, be)))
            return out

    master = Probe(robot, controller, _trajectory(robot, profile), robot.counts_per_rev,
                   timing, lam=gains.lam,
                   pid=pid_gains(robot, gains.pid_1khz_hz, gains.pid_1khz_base_hz),
                   base_fb=gains.vdc_base_fb,
                   uploads=uploads, on_trip=safety.on_trip, rearm_blend=safety.rearm_blend)
    plant = make_plant(robot, config.plant, seed=seed)
    plant.reset(robot.home)
    start = -(-START_CYCLE // timing.period_cycles) * timing.period_cycles
    be = loop_backend(robot, backend, faults=faults)
    holder["be"] = be
    result = ClosedLoop(robot, be, master, plant, start, uploads).run(
        int(round(duration * CLOCK_HZ)))
    snaps.append((math.inf, _counters(master, be)))
    return result, packets, snaps, start


def _counters(master, be) -> dict:
    out = {"master.rx_dropped": int(be.crc_errors), "master.port": int(be.link_errors),
           "master.missing": int(master.missing), "master.overruns": int(master.overruns)}
    for node, c in master.node_link.items():
        for k, v in c.items():
            out[f"node{node}.{k}"] = int(v)
    return out


def _at(snaps, cycle) -> dict:
    """The counters as they stood before ``cycle`` (absolute)."""
    last = {}
    for now, c in snaps:
        if now >= cycle:
            break
        last = c
    return last


def run_loop_point(point: dict) -> dict:
    """One run with its faults and its reference; a row per fault."""
    from mrm_cosim.cosim.closed_loop import LineFault
    from mrm_cosim.cosim.experiment_config import from_dict
    from mrm_cosim.units import CLOCK_HZ

    task = point["task"]
    config = from_dict(task["resolved"])
    t0 = time.perf_counter()
    args = (config, task["controller"], task["backend"], task["duration"], task["seed"])
    ref, ref_packets, _, start = run_probe(*args)
    faults = [LineFault(f["node"], f["direction"], f["kind"], f["cycle"], f["cycles"])
              for f in task["faults"]]
    res, packets, snaps, _ = run_probe(*args, faults=faults)
    period = config.timing.period_cycles
    ref_frames = _keyed(ref_packets)
    got = _keyed(packets)
    rows = []
    for f in task["faults"]:
        a, b = start + f["slot"][0], start + f["slot"][1]
        t_fault = start + f["cycle"]
        before, after = _at(snaps, a), _at(snaps, b)
        moved = {k: after.get(k, 0) - before.get(k, 0) for k in after
                 if after.get(k, 0) != before.get(k, 0)}
        end = t_fault + f["cycles"] + SLACK
        corrupted = 0
        if f["direction"] == "up":
            corrupted = sum(1 for key, (now, payload) in got.items()
                            if t_fault <= now < end and key[1] >= f["node"]
                            and ref_frames.get(key, (0, None))[1] != payload)
        recs = [r for r in res.master.records if a <= r.start < b]
        lost = [r for r in recs if not r.complete]
        if lost:
            last_lost = max(r.start for r in lost)
            recovery = (last_lost + period - t_fault) / CLOCK_HZ * 1e3
        else:
            recovery = 0.0
        i0, i1 = (np.searchsorted(res.t, (x - start) / CLOCK_HZ) for x in (a, b))
        dev = float(np.abs(res.q[i0:i1] - ref.q[i0:i1]).max()) if i1 > i0 else 0.0
        before_dev = float(np.abs(res.q[i0] - ref.q[i0]).max()) if i0 < len(res.q) else 0.0
        rows.append({"kind": f["kind"], "node": f["node"], "direction": f["direction"],
                     "t_ms": f["cycle"] / CLOCK_HZ * 1e3, "cycles": f["cycles"],
                     "moved": moved, "detected": bool(moved), "corrupted": corrupted,
                     "periods_lost": len(lost), "recovery_ms": recovery, "dev_rad": dev,
                     "dev_before_rad": before_dev})
    return {"rows": rows, "trace_sha256": res.trace_sha256, "ref_sha256": ref.trace_sha256,
            "tripped_nodes": sorted(int(k) for k in res.master.tripped),
            "end_dev_rad": float(np.abs(res.q[-1] - ref.q[-1]).max()) if len(res.q) else 0.0,
            "max_dev_rad": float(np.abs(res.q - ref.q).max()) if len(res.q) else 0.0,
            "wall_s": time.perf_counter() - t0}


def _keyed(packets) -> dict:
    """(sequence number, source, type, n-th of them) -> (arrival cycle, payload)."""
    seen = Counter()
    out = {}
    for now, seq, src, ptype, payload in packets:
        key = (seq, src, ptype, seen[(seq, src, ptype)])
        seen[(seq, src, ptype)] += 1
        out[key] = (now, payload)
    return out


def _first_counter(row) -> str:
    m = {k: v for k, v in row["moved"].items() if not k.startswith("master.overruns")}
    if not m:
        return "none"
    return "+".join(sorted(m))


def loop_table(rows: list[dict]) -> str:
    """Per fault kind: injected, detected, counters, corrupted, periods lost, recovery, dev."""
    from mrm_cosim.cosim.link_faults import upper_bound_95

    lines = ["| fault | injected | detected | counters that moved (most common) | corrupted "
             "accepted | 95 % bound | periods lost (max) | recovery max (ms) | "
             "joint deviation max (µrad) |", "|---|---|---|---|---|---|---|---|---|"]
    for kind in sorted({r["kind"] for r in rows}) + ["all"]:
        sel = [r for r in rows if kind == "all" or r["kind"] == kind]
        by = Counter(_first_counter(r) for r in sel if r["detected"])
        corrupted = sum(r["corrupted"] for r in sel)
        lines.append(
            f"| {kind} | {len(sel)} | {sum(r['detected'] for r in sel)} | "
            f"{'; '.join(f'{k} {v}' for k, v in by.most_common(3))} | {corrupted} | "
            f"{upper_bound_95(corrupted, len(sel)):.2g} | "
            f"{max(r['periods_lost'] for r in sel)} | "
            f"{max(r['recovery_ms'] for r in sel):.3g} | "
            f"{1e6 * max(r['dev_rad'] for r in sel):.3g} |")
    return "\n".join(lines)


def write_loop_summary(out: Path, spec, rows: list[dict], plots: bool = True,
                       total: int | None = None) -> dict:
    from mrm_cosim.results import write_json

    ok = [r for r in rows if r["status"] == "ok"]
    faults = [dict(f, seed=r["seed"]) for r in ok for f in r["rows"]]
    c = spec.campaign
    total = len(rows) if total is None else total
    lines = [f"# Fault campaign {spec.name} (closed loop)", "",
             f"{len(ok)} of {total} runs ({len(faults)} faults) finished; config "
             f"{c['config']}, controller {c['controller']} on {c['backend']}, {c['duration']:g} s "
             f"a run, faults in {c['window'][0]:g}–{c['window'][1]:g} s, "
             f"{c['faults_per_run']} a run, one per {c['slot_periods']}-period slot.", ""]
    failed = [r for r in rows if r["status"] != "ok"]
    if failed:
        lines += [f"**{len(failed)} run(s) failed** (points.jsonl has the errors).", ""]
    if ok:
        lines += ["## Runs", "", "| seed | faults | nodes whose watchdog tripped | "
                  "largest joint deviation from the reference (µrad) | at the end (µrad) |",
                  "|---|---|---|---|---|"]
        for r in ok:
            lines.append(f"| {r['seed']} | {len(r['rows'])} | "
                         f"{', '.join(map(str, r.get('tripped_nodes', []))) or 'none'} | "
                         f"{1e6 * r['max_dev_rad']:.3g} | {1e6 * r.get('end_dev_rad', 0):.3g} |")
        lines.append("")
    if faults:
        lines += [loop_table(faults), "", "## Every fault", "",
                  "| seed | fault | at (ms) | cycles | counters that moved | corrupted | "
                  "periods lost | recovery (ms) | deviation (µrad): at the slot's start, "
                  "largest in it |", "|---|---|---|---|---|---|---|---|---|"]
        for f in faults:
            lines.append(f"| {f['seed']} | {f['kind']}:{f['direction']}:{f['node']} | "
                         f"{f['t_ms']:.4f} | {f['cycles']} | "
                         f"{', '.join(f'{k} {v}' for k, v in sorted(f['moved'].items())) or '–'}"
                         f" | {f['corrupted']} | {f['periods_lost']} | {f['recovery_ms']:.3g} | "
                         f"{1e6 * f['dev_before_rad']:.3g}, {1e6 * f['dev_rad']:.3g} |")
        lines.append("")
    (out / "summary.md").write_text("\n".join(lines))
    camp = {k: v for k, v in c.items() if k != "resolved"}
    doc = {"name": spec.name, "level": "loop", "campaign": camp, "points": total,
           "finished": len(ok), "faults": faults}
    write_json(out / "summary.json", doc)
    if plots and faults:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        kinds = sorted({f["kind"] for f in faults})
        fig, axes = plt.subplots(1, 2, figsize=(8, 3.4))
        for ax, key, label, scale in ((axes[0], "recovery_ms", "recovery (ms)", 1.0),
                                      (axes[1], "dev_rad", "joint deviation (µrad)", 1e6)):
            ax.boxplot([[scale * f[key] for f in faults if f["kind"] == k] for k in kinds],
                       tick_labels=kinds, whis=(0, 100))
            ax.set_ylabel(label)
            ax.grid(True, lw=0.3)
        fig.suptitle(f"{spec.name}: per fault kind ({len(faults)} faults)", fontsize=9)
        fig.tight_layout()
        fig.savefig(out / "loop_faults.png", dpi=110)
        plt.close(fig)
    return doc
