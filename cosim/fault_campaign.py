"""The fault campaign as a kind of sweep (``kind = "link-faults"``, issue 22 item 4).

A spec::

    [sweep]
    name = "link-faults"
    kind = "link-faults"

    [campaign]
    level = "link"          # two reference codecs back to back (cosim/link_faults.py)
    faults = 100000         # faults in all
    chunk = 500             # faults per point (a point: one link, its faults one by one)
    seed = 0
    kinds = ["bit", "cut"]  # default: every kind of cosim.link_faults.KINDS
    rx_fifo_depth = 64      # the codecs' FIFO (16: every lost FCT starves the sender)
    credit_timeout = 200    # cycles; the short timers of cosim.link_faults.SHORT_TIMERS
    credit_audit = 400      # cycles (0: off); each fault is judged after a silence this long

A point is a chunk: ``chunk`` faults on one link of its own, seeded by ``(seed, chunk index)``,
a pure function of the point (so serial, process and Dask executors give the same rows, and a
killed campaign resumes at the chunks it had not finished). Each fault is judged on its own
(the link settled before it, its window closed before the next: cosim/link_faults.py).

``level = "loop"``: closed-loop runs with line faults (:mod:`cosim.loop_campaign`).

Outputs beside the sweep's points.jsonl: summary.md (the per-kind table and the 95 % bound
on corrupted-but-accepted frames), summary.json (the same as data), recovery.png (recovery
time per kind), detectors.png (the first counter per kind).
"""

from __future__ import annotations

import hashlib
import json
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from mrm_cosim.errors import InputError

__all__ = ["CampaignSpec", "load_campaign", "expand_campaign", "run_campaign_point",
           "write_campaign_summary", "summarize_folder", "KIND"]

KIND = "link-faults"
LEVELS = ("link", "loop")
_LINK_KEYS = {"level", "faults", "chunk", "seed", "kinds", "rx_fifo_depth", "credit_timeout",
              "credit_audit"}
MAX_FAULTS = 10_000_000


@dataclass(frozen=True)
class CampaignSpec:
    """A validated campaign spec (see the module docstring)."""

    name: str
    level: str
    campaign: dict                  # the [campaign] table, defaults filled in
    kind: str = KIND
    seeds: tuple = field(default=())    # every point's seed, in order (the sweep sorts by it)

    def to_toml(self) -> str:
        from mrm_cosim.cosim.experiment_config import _dump_toml

        from mrm_cosim.cosim.loop_campaign import _KEYS

        keys = _LINK_KEYS if self.level == "link" else _KEYS
        return _dump_toml({"sweep": {"name": self.name, "kind": self.kind},
                           "campaign": {k: v for k, v in self.campaign.items() if k in keys}})


def _whole(value, where: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise InputError(where, f"must be a whole number {lo}..{hi:,}, not {value!r}")
    return value


def load_campaign(data: dict, path: Path) -> CampaignSpec:
    """Validate a spec of kind ``link-faults`` (``data``: the parsed TOML)."""
    for key in data:
        if key not in ("sweep", "campaign"):
            raise InputError(key, "unknown table for kind = \"link-faults\"; known: campaign, "
                             "sweep")
    sw = data["sweep"]
    for key in sw:
        if key not in ("name", "kind"):
            raise InputError(f"sweep.{key}", "unknown key for kind = \"link-faults\" (the "
                             "campaign's keys are in [campaign]); known: kind, name")
    camp = data.get("campaign")
    if not isinstance(camp, dict):
        raise InputError("campaign", "kind = \"link-faults\" needs a [campaign] table")
    level = camp.get("level", "link")
    if level not in LEVELS:
        raise InputError("campaign.level", f"must be one of {', '.join(LEVELS)}, not {level!r}")
    name = sw.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise InputError("sweep.name", f"must be a non-empty string, not {name!r}")
    if level == "loop":
        from mrm_cosim.cosim.loop_campaign import check_loop_campaign

        checked = check_loop_campaign(camp, path.resolve().parent)
        return CampaignSpec(name, level, checked, seeds=tuple(checked["seeds"]))
    checked = _check_link(camp)
    return CampaignSpec(name, level, checked, seeds=tuple(range(_n_chunks(checked))))


def _check_link(camp: dict) -> dict:
    from mrm_cosim.cosim.link_faults import KINDS, SHORT_TIMERS

    for key in camp:
        if key not in _LINK_KEYS:
            raise InputError(f"campaign.{key}", "unknown key for level = \"link\"; known: "
                             f"{', '.join(sorted(_LINK_KEYS))}")
    out = {"level": "link",
           "faults": _whole(camp.get("faults", 1000), "campaign.faults", 1, MAX_FAULTS),
           "chunk": _whole(camp.get("chunk", 500), "campaign.chunk", 1, 100_000),
           "seed": _whole(camp.get("seed", 0), "campaign.seed", 0, 2**31 - 1),
           "rx_fifo_depth": _whole(camp.get("rx_fifo_depth", 64), "campaign.rx_fifo_depth", 16,
                                   4096),
           "credit_timeout": _whole(camp.get("credit_timeout", SHORT_TIMERS["credit_timeout"]),
                                    "campaign.credit_timeout", 0, 1_000_000),
           "credit_audit": _whole(camp.get("credit_audit", SHORT_TIMERS["credit_audit"]),
                                  "campaign.credit_audit", 0, 1_000_000)}
    if out["credit_audit"] == 1:
        raise InputError("campaign.credit_audit", "must be 0 (off) or at least 2 cycles, not 1")
    kinds = camp.get("kinds", list(KINDS))
    if not isinstance(kinds, list) or not kinds:
        raise InputError("campaign.kinds", f"must be a non-empty list of {', '.join(KINDS)}")
    for k in kinds:
        if k not in KINDS:
            raise InputError("campaign.kinds", f"unknown fault kind {k!r}; known: "
                             f"{', '.join(KINDS)}")
        if kinds.count(k) > 1:
            raise InputError("campaign.kinds", f"{k!r} is given twice")
    out["kinds"] = list(kinds)
    return out


def _n_chunks(camp: dict) -> int:
    return -(-camp["faults"] // camp["chunk"])


def _pid(task: dict) -> str:
    return hashlib.sha256(json.dumps(task, sort_keys=True).encode()).hexdigest()[:16]


def expand_campaign(spec: CampaignSpec) -> list[dict]:
    """The points: chunks of faults (link) or closed-loop runs (loop)."""
    if spec.level == "loop":
        from mrm_cosim.cosim.loop_campaign import expand_loop

        return expand_loop(spec)
    c = spec.campaign
    points = []
    for i in range(_n_chunks(c)):
        n = min(c["chunk"], c["faults"] - i * c["chunk"])
        task = {"level": "link", "n": n, "seed": c["seed"] * 1_000_000 + i,
                "kinds": c["kinds"], "params": {"rx_fifo_depth": c["rx_fifo_depth"],
                                                "credit_timeout": c["credit_timeout"],
                                                "credit_audit": c["credit_audit"]}}
        points.append({"id": _pid(task), "params": {"chunk": i}, "seed": i, "controller": "-",
                       "backend": "ref", "kind": KIND, "task": task})
    return points


def run_campaign_point(point: dict) -> dict:
    """One chunk: its fault rows (a pure function of ``point["task"]``)."""
    task = point["task"]
    if task["level"] == "loop":
        from mrm_cosim.cosim.loop_campaign import run_loop_point

        return run_loop_point(point)
    from mrm_cosim.cosim.link_faults import _worker

    t0 = time.perf_counter()
    rows = _worker((task["n"], task["seed"], tuple(task["kinds"]), task["params"]))
    return {"rows": rows, "wall_s": time.perf_counter() - t0}


def write_campaign_summary(out: Path, spec: CampaignSpec, rows: list[dict],
                           plots: bool = True, total: int | None = None) -> dict:
    """summary.md, summary.json and the plots of a finished (or partly finished) campaign."""
    if spec.level == "loop":
        from mrm_cosim.cosim.loop_campaign import write_loop_summary

        return write_loop_summary(out, spec, rows, plots, total)
    from mrm_cosim.cosim.link_faults import _detector, summarize, table_markdown
    from mrm_cosim.results import write_json

    ok = [r for r in rows if r["status"] == "ok"]
    faults = [f for r in ok for f in r["rows"]]
    summary = summarize(faults) if faults else []
    every = next((s for s in summary if s["kind"] == "all"), None)
    c = spec.campaign
    n_points = len(rows) if total is None else total
    lines = [f"# Fault campaign {spec.name} (link level)", "",
             f"{len(ok)} of {n_points} points ({len(faults):,} of {c['faults']:,} faults) "
             f"finished; seed {c['seed']}, {c['chunk']} faults a point, FIFO "
             f"{c['rx_fifo_depth']}, credit timeout {c['credit_timeout']} cycles, credit audit "
             f"{c['credit_audit']} cycles; kinds "
             f"{', '.join(c['kinds'])}.", ""]
    failed = [r for r in rows if r["status"] != "ok"]
    if failed:
        lines += [f"**{len(failed)} point(s) failed** (points.jsonl has the errors).", ""]
    if summary:
        lines += [table_markdown(summary), "",
                  f"{every['corrupted_accepted']} corrupted frames accepted in "
                  f"{every['injected']:,} faults: one-sided 95 % upper bound "
                  f"{every['bound95']:.2g} per fault. {every['unrecovered']} not recovered "
                  "within the limit.", ""]
        lines += ["## Undetected faults: harmless?", "",
                  "Faults no counter saw, per kind: how many took a link down or let a corrupted "
                  "frame through (both must be 0: undetected means harmless, by design).", "",
                  "| fault | undetected | took a link down | corrupted accepted |",
                  "|---|---|---|---|"]
        for kind in c["kinds"]:
            quiet = [f for f in faults if f["kind"] == kind and not f["moved"]]
            lines.append(f"| {kind} | {len(quiet)} | {sum(f['went_down'] for f in quiet)} | "
                         f"{sum(f['corrupted'] for f in quiet)} |")
        lines.append("")
        lines += _credit_lines(c["kinds"], faults)
        stall = [f for f in faults if f["kind"] == "master-stall"]
        if stall:
            lines += ["## Master stall by duration", "",
                      "| stall (cycles) | inside a frame | took the link down | "
                      "outside a frame | took it down |", "|---|---|---|---|---|"]
            for n in sorted({f["cycles"] for f in stall}):
                sel = [f for f in stall if f["cycles"] == n]
                inside = [f for f in sel if f["in_frame"]]
                outside = [f for f in sel if not f["in_frame"]]
                lines.append(f"| {n} | {len(inside)} | {sum(f['went_down'] for f in inside)} "
                             f"| {len(outside)} | {sum(f['went_down'] for f in outside)} |")
            lines.append("")
    (out / "summary.md").write_text("\n".join(lines))
    doc = {"name": spec.name, "level": "link", "campaign": c, "points": n_points,
           "finished": len(ok), "faults": len(faults), "summary": summary,
           "detectors": {k: dict(Counter(_detector(f) for f in faults if f["kind"] == k))
                         for k in c["kinds"]},
           "credit_skew_link_up": {k: sum(bool(f.get("credit_skew") and any(f["credit_skew"])
                                               and not f["went_down"])
                                          for f in faults if f["kind"] == k)
                                   for k in c["kinds"]}}
    write_json(out / "summary.json", doc)
    if plots and faults:
        _link_plots(out, spec, faults)
    return doc


def _credit_lines(kinds, faults: list[dict]) -> list[str]:
    """The table of faults that changed the link's credit balance (``credit_skew``): a skew no
    counter flagged is a fault absorbed silently until a later credit error pays for it."""
    measured = [f for f in faults if f.get("credit_skew") is not None]
    if not measured:
        return []
    lines = ["## Credit left unbalanced", "",
             "After each fault a drained copy of the link compares, per direction, the credit "
             "the receiver has granted with what the sender holds "
             "(`LinkCampaign.credit_balance`; 0 on a healthy link). A fault that changes it "
             "with the link up leaves a skew no counter keeps; it stays until a credit error or "
             "a restart, whose row then shows the opposite change (a restart settles every "
             "account: its change is the skew earlier faults left).", "",
             "| fault | measured | left a skew, link up | of them no counter moved | "
             "took the link down and settled an earlier skew |", "|---|---|---|---|---|"]
    for kind in kinds:
        sel = [f for f in measured if f["kind"] == kind]
        if not sel:
            continue
        up = [f for f in sel if any(f["credit_skew"]) and not f["went_down"]]
        down = [f for f in sel if any(f["credit_skew"]) and f["went_down"]]
        lines.append(f"| {kind} | {len(sel):,} | {len(up):,} | "
                     f"{sum(not f['moved'] for f in up):,} | {len(down):,} |")
    return [*lines, ""]


def summarize_folder(out) -> dict:
    """Write summary.md, summary.json and the plots of the campaign in folder ``out`` from
    what it has finished (a campaign still running or killed: its points.jsonl so far)."""
    from mrm_cosim.cosim.sweep import _finished, load_spec

    out = Path(out)
    spec = load_spec(out / "sweep.toml")
    done = _finished(out / "points.jsonl")
    points = expand_campaign(spec)
    rows = [done[p["id"]] for p in points if p["id"] in done]
    return write_campaign_summary(out, spec, rows, total=len(points))


def _link_plots(out: Path, spec: CampaignSpec, faults: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from mrm_cosim.cosim.link_faults import _detector

    kinds = [k for k in spec.campaign["kinds"] if any(f["kind"] == k for f in faults)]
    fig, ax = plt.subplots(figsize=(7.5, 3.8))
    data = [[0.02 * f["recovery_cycles"] for f in faults if f["kind"] == k and f["went_down"]]
            for k in kinds]
    ax.boxplot([d if d else [np.nan] for d in data], tick_labels=kinds, whis=(0, 100))
    ax.set_ylabel("recovery (µs, short timers)")
    ax.set_title(f"{spec.name}: recovery per fault kind, faults that took the link down "
                 f"({sum(map(len, data)):,})", fontsize=9)
    ax.tick_params(axis="x", labelsize=7, rotation=20)
    ax.grid(True, lw=0.3)
    fig.tight_layout()
    fig.savefig(out / "recovery.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    per = {k: Counter(_detector(f) if f["moved"] else "undetected" for f in faults
                      if f["kind"] == k) for k in kinds}
    totals = Counter()
    for c in per.values():
        totals.update(c)
    top = [d for d, _ in totals.most_common(7)]
    bottom = np.zeros(len(kinds))
    for d in top + ["other"]:
        vals = np.array([(per[k][d] if d != "other" else
                          sum(v for x, v in per[k].items() if x not in top)) /
                         max(1, sum(per[k].values())) for k in kinds])
        if not vals.any():
            continue
        ax.bar(kinds, vals, bottom=bottom, label=d)
        bottom += vals
    ax.set_ylabel("share of faults")
    ax.set_title(f"{spec.name}: first counter per fault kind", fontsize=9)
    ax.tick_params(axis="x", labelsize=7, rotation=20)
    ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    fig.savefig(out / "detectors.png", dpi=110)
    plt.close(fig)
