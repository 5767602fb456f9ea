"""A link-level fault campaign: faults on the line of two codecs in Run, each judged on its own.

# Ref: ECSS-E-ST-50-12C §7.4 (parity), §8.5.2-§8.5.3 (link errors, Error-Reset), flow control
#      (FCTs, credit), §8.12 (time-codes: each one more than the last).

The simulator is the codec's bit-exact reference (:class:`~hdl.link.codec_ref.CodecRef`), two
of them back to back: equal to the gateware cycle for cycle on every output, under cuts and bit
errors too (tests/test_codec_ref.py, tests/test_link_faults.py), and with no other simulator of
the codec at hand that is faster per fault (docs/faults.md says why not the Verilated chain).

Traffic: each side streams frames back to back (2-byte sequence number, 1-byte length, 8-40
random bytes, CRC-16, EOP) and reads everything it receives; a sends a time-code every
``TC_PERIOD`` cycles. Each fault's window ends with a silence (both hosts end their frames and
offer nothing for the credit audit + ``AUDIT_MARGIN`` cycles), as the control cycle's links
fall silent between phases, so the codecs' credit audit looks at what the fault left. A
receiving host keeps a frame that ends in EOP with a good CRC (*accepted*), drops the others;
an accepted frame that is not exactly the frame sent under its sequence number is
*corrupted-accepted*, the failure that must never happen. A time-code that is not the last one
plus 1 (mod 64) is counted by the host (§8.12's rule, which our nodes apply).

A fault starts on a quiet link (both in Run for ``SETTLE`` cycles), on one line (a → b or
b → a), as masks on the line samples (``(clear, set, flip)`` per slot for D and S, like
:class:`~testbench.link.FaultyLine`). Kinds:

- ``bit``: D flipped for one bit period at the run rate (2 slots of the default 6; a glitch
  of one 3.33 ns sample is mostly absorbed by the receiver's second sample per bit, docs/link.md
  "Receiver margin"); ``burst``: 2-12 consecutive slots of D and/or S flipped at random;
  ``cut``: both lines low for 1-80 cycles (the disconnect time is 43);
  ``stuck-d`` / ``stuck-s``: one line held high or low for 1-80 cycles;
- ``lost-fct``: the next FCT on the line vanishes: the line holds its levels for the FCT's four
  bits, which removes them and nothing else (four is even, so the data-strobe phase is kept);
- ``lost-tc``: the same for the next time-code's 14 bits;
- ``node-reset``: the codec that sends on the line is reset (:meth:`CodecRef.reset`, every
  register to its power-on value, the link to Error-Reset) and its host drops the frame it was
  sending and the one it was receiving: the node's power-on, mid-traffic. Its own error
  counters restart from 0 with it; the campaign keeps their sum across the reset;
- ``master-stall``: the host that sends on the line stops offering and stops reading for
  ``cycles`` (``STALL_CYCLES``: shorter and longer than the credit timeout), wherever it is in
  its frame; its codec carries on (NULLs, FCTs). A stall inside a frame longer than the credit
  timeout is what the peer's ``credit_timeout`` is built to see (a starved open packet).

Per fault: which counters moved (the codecs' error classes, each host's CRC drops, EEP-ended
frames and time-code sequence breaks), frames corrupted-accepted, and the recovery time (from
the fault's first cycle until both codecs are back in Run and a frame has crossed each way).
"""

from __future__ import annotations

import copy
import math
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from mrm_cosim.hdl.link.codec_ref import CodecRef, char_fields, char_value
from mrm_cosim.protocol.crc import crc16
from mrm_cosim.protocol.link import ERROR_CLASSES, CharKind

__all__ = ["KINDS", "CUT_CYCLES", "STALL_CYCLES", "Fault", "LinkCampaign", "run_campaign",
           "summarize", "upper_bound_95", "table_markdown"]

KINDS = ("bit", "burst", "cut", "stuck-d", "stuck-s", "lost-fct", "lost-tc", "node-reset",
         "master-stall")
#: Cut and stuck durations drawn from, cycles: shorter and longer than the disconnect time.
CUT_CYCLES = (1, 3, 8, 13, 20, 30, 42, 44, 60, 80)
#: Master-stall durations drawn from, cycles: shorter and longer than the short credit
#: timeout (200 cycles, SHORT_TIMERS).
STALL_CYCLES = (10, 50, 150, 190, 210, 300, 600, 1500)
SHORT_TIMERS = {"reset_cycles": 60, "wait_cycles": 150, "credit_timeout": 200,
                "credit_audit": 400}
SETTLE = 40             # both in Run this long before a fault
TC_PERIOD = 97          # cycles between a's time-codes
QUIET = 150             # an undetected fault is judged after this many cycles
LIMIT = 6000            # a fault not recovered after this is a failure
DRAIN = 120             # cycles a drained copy runs before its credit balance is read
AUDIT_MARGIN = 10       # cycles of silence beyond the credit audit before a fault is judged
_DATA, _EOP, _EEP = CharKind.DATA.value, CharKind.EOP.value, CharKind.EEP.value
_HOST = ("crc_drop", "eep", "tc_sequence")


@dataclass
class Fault:
    kind: str
    line: str                   # "ab" or "ba"
    cycles: int = 1             # duration of cut / stuck, cycles
    seed: int = 0


@dataclass
class _Host:
    rng: np.random.Generator
    seq: int = 0
    queue: list = field(default_factory=list)
    sent: dict = field(default_factory=dict)      # seq -> frame bytes
    frame: list = field(default_factory=list)
    accepted: int = 0
    corrupted: int = 0
    counts: Counter = field(default_factory=Counter)
    last_tc: int | None = None
    frame_len: int = 0
    pausing: bool = False       # start no new frame (the control cycle's silence)
    idle: int = 0               # cycles in a row with nothing to offer while pausing

    def silent(self) -> bool:
        """Pausing and the last frame has gone: nothing to offer."""
        return self.pausing and not self.queue

    def in_frame(self) -> bool:
        """Part of the frame being sent has gone."""
        return 0 < len(self.queue) < self.frame_len

    def offer(self):
        if not self.queue:
            n = int(self.rng.integers(8, 41))
            body = [self.seq >> 8, self.seq & 0xFF, n] + [int(x) for x in
                                                          self.rng.integers(0, 256, n)]
            c = crc16(body)
            frame = bytes(body + [c >> 8, c & 0xFF])
            self.sent[self.seq] = frame
            self.sent.pop(self.seq - 64, None)
            self.seq = (self.seq + 1) & 0xFFFF
            self.queue = [char_value(_DATA, b) for b in frame] + [char_value(_EOP)]
            self.frame_len = len(self.queue)
        return self.queue[0]

    def receive(self, value, sent):
        """Take a received N-char; ``sent`` is the peer's frames by sequence number."""
        kind, data = char_fields(value)
        if kind == _DATA:
            self.frame.append(data)
            return
        frame, self.frame = bytes(self.frame), []
        if kind == _EEP:
            self.counts["eep"] += 1
        elif len(frame) < 5 or crc16(frame[:-2]) != (frame[-2] << 8 | frame[-1]):
            self.counts["crc_drop"] += 1
        else:
            self.accepted += 1
            if sent.get(frame[0] << 8 | frame[1]) != frame:
                self.corrupted += 1

    def drop(self):
        """A node reset: the frame being sent and the one being received are gone."""
        self.queue, self.frame, self.last_tc = [], [], None

    def time_code(self, value):
        t = value & 0x3F
        if self.last_tc is not None and t != (self.last_tc + 1) & 0x3F:
            self.counts["tc_sequence"] += 1
        self.last_tc = t


class LinkCampaign:
    """Two reference codecs ``a`` and ``b`` in Run with traffic both ways; faults one by one."""

    def __init__(self, seed: int = 0, **params):
        self.params = {**SHORT_TIMERS, **params}
        self.codecs = {"a": CodecRef(**self.params), "b": CodecRef(**self.params)}
        self.slots = self.codecs["a"].slots
        self.bit_slots = self.codecs["a"].run_div      # slots per bit in Run
        self.hosts = {w: _Host(np.random.default_rng([seed, i])) for i, w in enumerate("ab")}
        self.cycle = 0
        self.tc = 0
        self.masks = {}             # cycle -> {"ab"/"ba": ((clear, set, flip) D, ... S)}
        self.rng = np.random.default_rng([seed, 7])
        self.crossed = {"a": 0, "b": 0}     # frames accepted since the last count reset
        self.resets = {}            # cycle -> codec reset at its start ("a" / "b")
        self.stall = {}             # host -> first cycle it runs again
        self.base = {w: Counter() for w in "ab"}    # counts of codecs before their resets
        self.balance = None         # credit_balance() after the last judged fault

    # -- one cycle of both codecs and both hosts ----------------------------------------------
    def step(self):
        out = {w: c.outputs() for w, c in self.codecs.items()}
        fault = self.masks.pop(self.cycle, {})
        who = self.resets.pop(self.cycle, None)
        if who is not None:
            self.base[who].update(self.codecs[who].errors)
            self.codecs[who].reset()
            self.hosts[who].drop()
            out[who] = self.codecs[who].outputs()
        tick = out["a"].running and self.cycle % TC_PERIOD == 0
        if tick:
            self.tc = (self.tc + 1) & 0x3F
        for who, peer, key in (("a", "b", "ba"), ("b", "a", "ab")):
            o, h = out[who], self.hosts[who]
            live = self.stall.get(who, 0) <= self.cycle
            offering = live and not h.silent()
            h.idle = h.idle + 1 if h.silent() else 0
            payload = h.offer() if offering else 0
            if o.tx_ready and offering:
                h.queue.pop(0)
            if o.rx_valid and live:
                before = h.accepted
                h.receive(o.rx_payload, self.hosts[peer].sent)
                self.crossed[who] += h.accepted - before
            if o.tick_out:
                h.time_code(o.time_out)
            (cd, sd, fd), (cs, ss, fs) = fault.get(key, ((0, 0, 0), (0, 0, 0)))
            d = ((out[peer].d_out & ~cd) | sd) ^ fd
            s = ((out[peer].s_out & ~cs) | ss) ^ fs
            self.codecs[who].step(d_in=d, s_in=s, tx_valid=int(offering), tx_payload=payload,
                                  rx_ready=int(live),
                                  link_start=1, tick_in=int(who == "a" and tick),
                                  time_in=self.tc)
        self.cycle += 1

    def running(self) -> bool:
        return all(c.state == 5 for c in self.codecs.values())

    def bring_up(self, limit: int = 5000):
        while not self.running():
            self.step()
            if self.cycle > limit:
                raise RuntimeError("the link did not come up")

    def counters(self) -> dict:
        out = {}
        for w, c in self.codecs.items():
            out.update({f"{w}.{k}": v + self.base[w][k] for k, v in c.errors.items()})
            out.update({f"{w}.{k}": self.hosts[w].counts[k] for k in _HOST})
        return out

    # -- faults ---------------------------------------------------------------------------------
    def _bit_slots(self, line: str, token: str, horizon: int = 40):
        """Absolute slot numbers of the bits of the next FCT (``token`` "fct") or time-code
        ("tc") on ``line``, found by running a copy ahead; None if none comes in ``horizon``."""
        ahead = copy.deepcopy(self)
        ahead.masks = {}
        who = "a" if line == "ab" else "b"
        prev_x = None
        bits = []                   # (slot, D, S) of every bit the transmitter starts
        for _ in range(horizon):
            o = ahead.codecs[who].outputs()
            for i in range(self.slots):
                d, s = (o.d_out >> i) & 1, (o.s_out >> i) & 1
                if prev_x is not None and (d ^ s) != prev_x:
                    bits.append((ahead.cycle * self.slots + i, d, s))
                prev_x = d ^ s
            ahead.step()
        return _find_token(bits, token)

    def inject(self, fault: Fault) -> bool:
        """Queue ``fault``'s masks from the next cycle on; False if its target never came."""
        rng = np.random.default_rng([fault.seed, 11])
        n = self.slots
        start = self.cycle
        masks = {}

        def put(slot, which, op):
            c, i = divmod(slot, n)
            m = masks.setdefault(c, {}).setdefault(fault.line, [[0, 0, 0], [0, 0, 0]])
            m[which][op] |= 1 << i

        if fault.kind == "bit":
            first = start * n + int(rng.integers(0, 4 * n))
            for k in range(self.bit_slots):
                put(first + k, 0, 2)
        elif fault.kind == "burst":
            first = start * n + int(rng.integers(0, 4 * n))
            for k in range(int(rng.integers(2, 13))):
                for which in (0, 1):
                    if rng.random() < 0.5:
                        put(first + k, which, 2)
        elif fault.kind == "node-reset":
            self.resets[start] = "a" if fault.line == "ab" else "b"
        elif fault.kind == "master-stall":
            who = "a" if fault.line == "ab" else "b"
            self.stall[who] = start + fault.cycles
        elif fault.kind in ("cut", "stuck-d", "stuck-s"):
            which = {"cut": (0, 1), "stuck-d": (0,), "stuck-s": (1,)}[fault.kind]
            level = int(rng.integers(0, 2)) if fault.kind != "cut" else 0
            for c in range(start, start + fault.cycles):
                for w in which:
                    for i in range(n):
                        put(c * n + i, w, 1 if level else 0)
        else:
            found = self._bit_slots(fault.line, "fct" if fault.kind == "lost-fct" else "tc",
                                    horizon=40 if fault.kind == "lost-fct" else TC_PERIOD + 40)
            if found is None:
                return False
            first, last, d0, s0 = found
            for slot in range(first, last + 1):         # hold the levels before the token
                put(slot, 0, 1 if d0 else 0)
                put(slot, 1, 1 if s0 else 0)
        for c, lines in masks.items():
            self.masks[c] = {k: tuple(tuple(x) for x in v) for k, v in lines.items()}
        return True

    def credit_balance(self) -> tuple[int, int] | None:
        """What each receiver has granted minus what its sender holds, per direction (a → b,
        b → a), with nothing in flight: a copy of the link runs with both hosts stalled until
        the lines carry only NULLs. (0, 0) on a healthy link; the standard keeps no record of
        it, so a fault that shifts it without a credit error leaves a latent skew that only a
        later credit error or link restart reveals. None if the copy is not in Run."""
        c = copy.deepcopy(self)
        c.stall = {"a": c.cycle + 10**9, "b": c.cycle + 10**9}
        for _ in range(DRAIN):
            c.step()
        a, b = c.codecs["a"], c.codecs["b"]
        if not c.running():
            return None
        return b.rx_credit - a.tx_credit, a.rx_credit - b.tx_credit

    def judge(self, fault: Fault) -> dict:
        """Inject ``fault`` now and run until it is over; return its record. Its
        ``credit_skew`` is the change of :meth:`credit_balance` across the fault (per
        direction; None where the link was not in Run to measure it)."""
        self.settle()
        if self.balance is None:
            self.balance = self.credit_balance()
        before = self.counters()
        corrupted = sum(h.corrupted for h in self.hosts.values())
        t0 = self.cycle
        in_frame = self.hosts["a" if fault.line == "ab" else "b"].in_frame()
        if not self.inject(fault):
            return {"kind": fault.kind, "skipped": True}
        end = max([t0, *self.masks, *self.resets, *(c - 1 for c in self.stall.values())])
        went_down = False
        self.crossed = {"a": 0, "b": 0}
        audit = self.params.get("credit_audit", 0)
        while self.cycle - t0 < LIMIT:
            self.step()
            went_down |= not self.running()
            if self.cycle <= end:
                continue
            if went_down:
                self._pause(False)
                if self.running() and min(self.crossed.values()) >= 1:
                    break
                if not self.running():
                    self.crossed = {"a": 0, "b": 0}
            elif self.cycle - t0 >= max(QUIET, self.params["credit_timeout"] + 60,
                                        end - t0 + QUIET):
                # The control cycle's silence: both hosts end their frames and send nothing
                # until the credit audit has looked (a latent credit skew shows there).
                if not audit or min(h.idle for h in self.hosts.values()) > audit + AUDIT_MARGIN:
                    break
                self._pause(True)
        self._pause(False)
        after = self.counters()
        moved = {k: after[k] - before[k] for k in after if after[k] != before[k]}
        prev, self.balance = self.balance, self.credit_balance()
        skew = (None if prev is None or self.balance is None else
                [x - y for x, y in zip(self.balance, prev, strict=True)])
        return {"kind": fault.kind, "line": fault.line, "cycles": fault.cycles,
                "moved": moved, "went_down": went_down, "in_frame": in_frame,
                "recovered": self.cycle - t0 < LIMIT,
                "recovery_cycles": self.cycle - t0 if went_down else 0,
                "corrupted": sum(h.corrupted for h in self.hosts.values()) - corrupted,
                "credit_skew": skew}

    def _pause(self, on: bool):
        for h in self.hosts.values():
            h.pausing = on

    def settle(self):
        """Both in Run for SETTLE cycles with traffic flowing."""
        quiet = 0
        while quiet < SETTLE:
            self.step()
            quiet = quiet + 1 if self.running() else 0


def _find_token(bits, token):
    """(first slot, last slot, D before, S before) of the next FCT / time-code in ``bits``, a
    list of (slot, D, S) of consecutive line bits. Framed at the first offset whose framing
    passes every parity check over the whole window (at least 60 bits)."""
    vals = [b[1] for b in bits]
    for start in range(1, min(15, len(vals) - 60)):
        found, ok = None, True
        pos, esc, prev = start, False, None
        while pos + 4 <= len(vals):
            flag = vals[pos + 1]
            length = 4 if flag else 10
            if pos + length > len(vals):
                break
            payload = vals[pos + 2:pos + length]
            if prev is not None and (vals[pos] ^ flag ^ (sum(prev) & 1)) != 1:
                ok = False
                break
            if found is None:
                if flag and payload == [1, 1]:
                    if token == "tc" and pos + 14 <= len(vals) and vals[pos + 5] == 0:
                        found = (bits[pos][0], bits[pos + 13][0], bits[pos - 1][1],
                                 bits[pos - 1][2])
                elif token == "fct" and flag and payload == [0, 0] and not esc:
                    found = bits[pos][0], bits[pos + 3][0], bits[pos - 1][1], bits[pos - 1][2]
            esc = bool(flag and payload == [1, 1])
            prev = payload
            pos += length
        if ok and found is not None:
            return found
    return None


def upper_bound_95(failures: int, trials: int) -> float:
    """One-sided 95 % upper bound on a per-trial probability (exact binomial; 3/n for 0)."""
    if trials == 0:
        return math.nan
    if failures == 0:
        return 1 - 0.05 ** (1 / trials)
    if failures >= trials:
        return 1.0
    lo, hi = failures / trials, 1.0
    for _ in range(60):
        mid = (lo + hi) / 2
        # P(X <= failures | p = mid)
        cdf = sum(math.comb(trials, k) * mid ** k * (1 - mid) ** (trials - k)
                  for k in range(failures + 1))
        lo, hi = (mid, hi) if cdf > 0.05 else (lo, mid)
    return hi


def draw(rng: np.random.Generator, kinds=KINDS) -> Fault:
    """One fault: kind, line and duration uniform over their choices."""
    kind = str(rng.choice(list(kinds)))
    cycles = (int(rng.choice(CUT_CYCLES)) if kind in ("cut", "stuck-d", "stuck-s") else
              int(rng.choice(STALL_CYCLES)) if kind == "master-stall" else 1)
    return Fault(kind, str(rng.choice(["ab", "ba"])), cycles, int(rng.integers(0, 2**31)))


def _worker(args) -> list[dict]:
    n, seed, kinds, params = args
    rng = np.random.default_rng([seed, 1])
    camp = LinkCampaign(seed, **params)
    camp.bring_up()
    rows = []
    while len(rows) < n:
        row = camp.judge(draw(rng, kinds))
        if not row.get("skipped"):
            rows.append(row)
    return rows


def run_campaign(n_faults: int, *, seed: int = 0, workers: int = 1, kinds=KINDS,
                 params: dict | None = None) -> tuple[list[dict], float]:
    """``n_faults`` faults over ``workers`` processes (each its own link, seeded by
    ``(seed, worker)``); return the rows and the wall time, s."""
    params = params or {}
    t0 = time.perf_counter()
    shares = [n_faults // workers + (k < n_faults % workers) for k in range(workers)]
    jobs = [(n, seed * 1000 + k, tuple(kinds), params) for k, n in enumerate(shares) if n]
    if workers == 1:
        rows = [r for job in jobs for r in _worker(job)]
    else:
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(workers) as pool:
            rows = [r for part in pool.map(_worker, jobs) for r in part]
    return rows, time.perf_counter() - t0


def _detector(row) -> str:
    moved = row["moved"]
    if not moved:
        return "none"
    # The first detector: the receiving codec's class on the faulty line, else anything.
    rx, tx = ("b", "a") if row["line"] == "ab" else ("a", "b")

    def classes(who, skip=()):
        return sorted(k.split(".")[1] for k in moved if k.startswith(who + ".") and
                      k.split(".")[1] in ERROR_CLASSES and k.split(".")[1] not in skip)

    # The receiving codec's classes; else the sending codec's (a lost FCT is seen by the
    # codec that sent it, as credit_timeout), its disconnect being only the echo; else hosts.
    own = classes(rx) or classes(tx, skip=("disconnect",))
    return "+".join(own) if own else "+".join(sorted(moved))


def summarize(rows: list[dict]) -> list[dict]:
    """Per fault kind: injected, detected, by which counter, corrupted-accepted, recovery."""
    out = []
    for kind in KINDS + ("all",):
        sel = [r for r in rows if kind == "all" or r["kind"] == kind]
        if not sel:
            continue
        det = [r for r in sel if r["moved"]]
        rec = np.array([r["recovery_cycles"] for r in sel if r["went_down"]]) * 0.02
        by = Counter(_detector(r) for r in det)
        corrupted = sum(r["corrupted"] for r in sel)
        out.append({
            "kind": kind, "injected": len(sel), "detected": len(det),
            "undetected": len(sel) - len(det),
            "by": ", ".join(f"{k} {v}" for k, v in by.most_common(4)),
            "corrupted_accepted": corrupted,
            "unrecovered": sum(not r["recovered"] for r in sel),
            "bound95": upper_bound_95(corrupted, len(sel)),
            "rec_p50": float(np.percentile(rec, 50)) if rec.size else math.nan,
            "rec_p95": float(np.percentile(rec, 95)) if rec.size else math.nan,
            "rec_max": float(rec.max()) if rec.size else math.nan,
        })
    return out


def table_markdown(summary: list[dict]) -> str:
    """The summary as a Markdown table (recovery in µs at 50 MHz)."""
    lines = ["| fault | injected | detected | undetected | first counter (receiving codec) | "
             "corrupted accepted | 95 % bound | recovery p50 / p95 / max (µs) |",
             "|---|---|---|---|---|---|---|---|"]
    for s in summary:
        lines.append(f"| {s['kind']} | {s['injected']} | {s['detected']} | {s['undetected']} | "
                     f"{s['by']} | {s['corrupted_accepted']} | {s['bound95']:.1e} | "
                     f"{s['rec_p50']:.2f} / {s['rec_p95']:.2f} / {s['rec_max']:.2f} |")
    return "\n".join(lines)
