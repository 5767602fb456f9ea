"""The nodes of the ``model`` backend: the node core's reference with a fast tick loop, and its
encoder interface event by event.

* :class:`FastNode` — :class:`~hdl.node.core_ref.NodeModel` (bit-exact and cycle-exact with
  :class:`~hdl.node.core.NodeCore` given the same events) whose plain control ticks skip the
  general event loop and, with :attr:`FastNode.lazy`, whose unobserved ticks skip the torque
  (cosim/model.py, "Lazy evaluation"). The control law is the reference's
  (:class:`~hdl.node.joint_ref.JointModel`), called part by part.
* :class:`EncoderEvents` — the encoder interface (synchronizer, glitch filter, ×4 decoder,
  M/T velocity estimator) computed from the plant's count changes event by event, equal to
  :class:`~hdl.node.encoder_ref.EncoderModel` cycle for cycle.
"""

from __future__ import annotations

import numpy as np

from mrm_cosim.hdl.node.core_ref import _NEVER, _TIME_MAX, NodeModel
from mrm_cosim.hdl.node.encoder_ref import (
    AGE_MAX,
    DC_MAX,
    VEL_LATENCY,
    EncoderParams,
    velocity_word,
)
from mrm_cosim.protocol.joint_program import joint_microcode
from mrm_cosim.hdl.node.joint_ref import MODES as JOINT_MODES
from mrm_cosim.protocol.fixed import WORD_MAX
from mrm_cosim.protocol.regs import Config

__all__ = ["FastNode", "EncoderEvents"]

_PHASE = {(0, 0): 0, (1, 0): 1, (1, 1): 2, (0, 1): 3}
_CYCLES = tuple(joint_microcode().cycles(m) for m in JOINT_MODES)
_CYCLES_MAX = max(_CYCLES)
_TICK, _MODE, _TIMEOUT, _TAU_MIN, _TAU_MAX, _COMMIT, _STOP, _BRAKE, _PERIOD, _CFG_TC = (
    int(c) for c in (Config.TICK, Config.MODE, Config.TIMEOUT, Config.TAU_MIN, Config.TAU_MAX,
                     Config.COMMIT, Config.STOP_CYCLES, Config.BRAKE_CYCLES, Config.PERIOD,
                     Config.TC_DISCIPLINE))


class FastNode(NodeModel):
    """:class:`~hdl.node.core_ref.NodeModel` with a faster event loop for plain control ticks
    (same behaviour; the ticks are what a long run spends its time on). The control law is the
    reference's own: :meth:`JointModel.part_a <hdl.node.joint_ref.JointModel.part_a>`,
    :meth:`~hdl.node.joint_ref.JointModel.part_b` and
    :meth:`~hdl.node.joint_ref.JointModel.pid_integral`.

    ``encoder``'s :meth:`EncoderEvents.tick_sample` serves the plain ticks.

    With :attr:`lazy` set, a plain tick whose torque nobody can observe (the next tick lands
    its own torque before any event or the caller reads it) skips the torque: in VDC and torque
    mode it only records the arguments of its Part B (:attr:`_deferred`, applied by the next
    tick that computes), in PID mode it updates the integral and the reference. The strobe,
    the watchdog, the overrun check and the landing time stay as they are. Torque words,
    state and replies equal the eager path's (``lazy=False``) bit for bit
    (tests/test_model_backend.py)."""

    _fast_sample = None
    _defer_sample = None
    lazy = False
    _deferred = None        # (tn, q_d0, q̇_d0, q̈_d0) of a Part B not yet applied to the joint

    def attach(self, encoder: EncoderEvents) -> None:
        self._sample = encoder.sample
        self._fast_sample = encoder.tick_sample
        self._defer_sample = encoder.defer
        self._defer_many = encoder.defer_range
        self._encoder = encoder
        self.encoder_preset = encoder.preset

    def _materialize(self) -> None:
        d = self._deferred
        if d is not None:
            self._deferred = None
            self.joint.part_b(d[0], d[1], d[2], d[3])

    def _param(self, bank: int, addr: int, w: int) -> None:
        self._materialize()                 # a host write comes after the Part B before it
        NodeModel._param(self, bank, addr, w)

    def _tick(self, now, sample, tt, ramped=False, hold=None):   # the event loop's ticks
        if hold or self.safe_stop_near(now + 1):
            self._materialize()
            NodeModel._tick(self, now, sample, tt, ramped, hold)
            return
        self._fast_tick(now, lambda c: sample(c)[:2], tt, ramped)

    def safe_stop_near(self, until: int) -> bool:
        """Whether the safe stop may act before cycle ``until``: STOP_CYCLES + BRAKE_CYCLES
        > 0 and the node tripped, or armed with its watchdog's trip (predicted from the last
        packet) within a margin of two ticks and the engine's longest program before
        ``until``. The fast paths (this class's plain ticks, the compiled kernel) do not
        model the hold; such a node runs on the reference's event loop
        (:class:`~hdl.node.core_ref.NodeModel`) until it is re-armed. With both zero (the
        reset values) the trip is the plain ramp the fast paths model."""
        cfg = self.config
        if not (cfg[_STOP] or cfg[_BRAKE]):
            return False
        if self.tripped:
            return True
        return self.armed and (self.last_packet + 2 + cfg[_TIMEOUT]
                               - 2 * cfg[_TICK] - _CYCLES_MAX - 2) <= until

    def run(self, until: int, sample=None) -> None:
        """As :meth:`NodeModel.run`; runs of plain ticks between the timer's other events
        skip the general event loop."""
        if sample is not None:
            self._sample = sample
        sample = self._sample
        if sample is None:
            NodeModel.run(self, until)
            return
        fast = self._fast_sample or (lambda c: sample(c)[:2])
        cfg = self.config
        tick = self._fast_tick
        dead = self._dead_tick if self.lazy else None
        count_only = self._defer_sample or (lambda c: fast(c)[0])
        batch = self._defer_sample is not None
        while True:
            if self.safe_stop_near(until):     # the safe stop: the reference's event loop
                NodeModel.run(self, until)
                break
            special = self.next_special()
            lim = special if special < until else until
            if cfg[_CFG_TC] and self._disciplined:
                # the disciplined period's tail (no tick) and the boundary are the reference's
                tail = self._lb + cfg[_PERIOD] + self.tc_loop[2] - cfg[_TICK] + 1
                if tail < lim:
                    lim = tail
            if dead is not None:
                step = cfg[_TICK]
                cyc = _CYCLES[cfg[_MODE]]
                # A tick is dead when the next one is in this run of plain ticks, starts after
                # it finished (no overrun) and, armed, lands its own torque (no watchdog trip
                # before) by cycle lim, where the caller or the next event may read the torque.
                # Disarmed both land 0; tripped neither lands, the ramp acts on the last real one.
                safe = step > cyc and (not self.armed or self.tripped)
                trip = self.last_packet + 2 + cfg[_TIMEOUT] - step - cyc
                land = lim - step - cyc - 1         # the next tick lands by lim
                if trip - 1 < land:
                    land = trip - 1
                while self._nt < lim:
                    nt = self._nt
                    if nt + step < lim and step > cyc and (safe or nt <= land):
                        landing = self._landing
                        if batch and not self.tripped and self._prime_due is None and \
                                (landing is None or landing[0] <= nt):
                            last = lim - step - 1 if safe else land
                            self._dead_run(nt, (last - nt) // step + 1, step, cyc)
                        else:
                            dead(nt, count_only, nt - self.d_base)
                    else:
                        tick(nt, fast, nt - self.d_base)
            else:
                while self._nt < lim:
                    nt = self._nt
                    tick(nt, fast, nt - self.d_base)
            if special >= until:
                break
            NodeModel.run(self, special + 1)
        if until > self._done:
            self._done = until

    def next_special(self) -> int:
        """The cycle of the next event of the node's timer that is not a plain tick (the
        boundary, the commit point, the cycle before an arming boundary): :meth:`run` hands
        it to the reference event loop, and the compiled kernel (:mod:`cosim.model_kernel`)
        runs only pieces that end before it. A step of the primitive generator is one, and so
        is the safe stop (:meth:`safe_stop_near`): the margin before a predicted trip, or −1
        while it may act (no plain piece at all), and a pending CONFIG record's cycle (a
        CONFIG acts the cycle after its last byte, :class:`~hdl.node.core_ref.NodeModel`)."""
        # (the model backend asks every node before every plain piece: one call, locals)
        cfg = self.config
        nb = self._nb
        special = nb
        lb = self._lb
        if self._commit_seen != lb:
            commit = lb + cfg[_COMMIT]
            if commit < special:
                special = commit
        if self.arm_pending and self._pre_seen != nb and nb - 1 < special:
            special = nb - 1
        if self.dmp_running and self._dmp_due < special and not (
                cfg[_CFG_TC] and self._disciplined and self._dmp_due - lb >= cfg[_PERIOD]):
            special = self._dmp_due                     # a step of the generator
        if self._tc_pending is not None and self._tc_pending[0] < special:
            special = self._tc_pending[0]               # the discipline's step applies
        if self._cfg_pending and self._cfg_pending[0][0] < special:
            special = self._cfg_pending[0][0]           # a CONFIG record acting
        if cfg[_STOP] or cfg[_BRAKE]:
            if self.tripped:
                return -1
            if self.armed:
                near = (self.last_packet + 2 + cfg[_TIMEOUT] - 2 * cfg[_TICK]
                        - _CYCLES_MAX - 2)
                if near < special:
                    return near
        return special

    def _dead_run(self, first: int, k: int, step: int, cyc: int) -> None:
        """``k`` dead ticks from cycle ``first``, ``step`` apart, at once: the state
        :meth:`_dead_tick` would leave (not tripped, no PRIME pending, the landing before
        ``first`` due by then). The torque between them is never observed; the strobes are
        deferred; VDC and torque mode keep only the last Part B, PID runs its integral."""
        last = first + (k - 1) * step
        landing = self._landing
        if landing is not None:
            self.torque = landing[1]
        val = None if self.armed else 0
        if k >= 2:
            self.torque = val
        self._landing = (last + cyc + 1, val)
        self._nt = last + step
        self._started = last
        self._busy_until = last + cyc + 1
        lb = self.d_base                  # the committed references are for this boundary
        d = self.d_words
        if self.config[_MODE] != 1:
            self._defer_many(first, last, step)
            tn = last - lb + step
            self._deferred = (tn if tn < _TIME_MAX else _TIME_MAX, d[1], d[2], d[3])
            return
        # PID: the integral on every tick (pid_integral, then Part B for the next tick), the
        # counts read along the encoder's visible edges, the strobes deferred
        self._materialize()
        j = self.joint
        integral, part_b = j.pid_integral, j.part_b
        qd0, vd0, ad0 = d[1], d[2], d[3]
        count_at = self._encoder.count_at
        for t in range(first, last + 1, step):
            integral(count_at(t))
            tn = t - lb + step
            part_b(tn if tn < _TIME_MAX else _TIME_MAX, qd0, vd0, ad0)
        self._defer_many(first, last, step)

    def _tick_begin(self, now: int, ramped: bool = False) -> int:
        """What every control tick does first, observed or not (the torque landing, the
        watchdog, the next tick, the trip ramp); returns the tick length."""
        landing = self._landing
        if landing is not None and now >= landing[0]:
            self.torque = landing[1]
            self._landing = None
        cfg = self.config
        if (self.armed and not self.tripped and now >= self.last_packet + 2 + cfg[_TIMEOUT]) \
                or self._prime_due is not None:
            self._watch(now)
        tick = cfg[_TICK]
        self._nt = now + tick
        if self.armed and self.tripped and not ramped:
            self._ramp()
        return tick

    def _tick_end(self, now: int, mode: int, tau) -> None:
        """The joint engine ran from ``now``: busy until its result lands; ``tau`` the torque
        word it lands (clipped here), None for a dead tick's (the next tick overwrites it)."""
        done = now + _CYCLES[mode]
        self._started = now
        self._busy_until = done + 1
        cfg = self.config
        if not self.armed:
            self._landing = (done + 1, 0)
        elif not (self.tripped or done >= self.last_packet + 2 + cfg[_TIMEOUT]):
            if tau is not None:
                lo, hi = cfg[_TAU_MIN], cfg[_TAU_MAX]
                tau = lo if tau < lo else hi if tau > hi else tau
            self._landing = (done + 1, tau)

    def _dead_tick(self, now: int, count_at, tt: int) -> None:
        """:meth:`_fast_tick` for a tick whose torque is overwritten before it is observed
        (``count_at(cycle)``: the count, the strobe deferred: :meth:`EncoderEvents.defer`)."""
        tick = self._tick_begin(now)
        count = count_at(now)
        if now < self._busy_until:
            self.overruns = min(self.overruns + 1, 0xFFFF)
            return
        mode = self.config[_MODE]
        tn = tt + tick
        if tn > _TIME_MAX:
            tn = _TIME_MAX
        d = self.d_words
        if mode == 1:
            self._materialize()
            self.joint.pid_integral(count)
            self.joint.part_b(tn, d[1], d[2], d[3])
        else:
            self._deferred = (tn, d[1], d[2], d[3])
        self._tick_end(now, mode, None)

    def _fast_tick(self, now: int, sample, tt: int, ramped: bool = False) -> None:
        tick = self._tick_begin(now, ramped)
        count, qd = sample(now)
        if now < self._busy_until:
            self.overruns = min(self.overruns + 1, 0xFFFF)
            return
        mode = self.config[_MODE]
        tn = tt + tick
        tn = tn if tn < _TIME_MAX else _TIME_MAX
        d = self.d_words
        j = self.joint
        self._materialize()
        tau = j.part_a(mode, count, qd, d[0], d[3])[0]
        if self.lazy:
            # Part B deferred like a dead tick's: every reader of (q_des, v_des) materializes
            # it first (the next computed tick, a host write, PID's dead ticks), and in VDC
            # and torque mode a dead tick next replaces it unread
            self._deferred = (tn, d[1], d[2], d[3])
        else:
            j.part_b(tn, d[1], d[2], d[3])
        self._tick_end(now, mode, tau)

    def torque_at(self, now: int) -> int:
        """:meth:`NodeModel.torque_at` with :meth:`_watch`'s usual no-op (no landing due, no
        trip, no PRIME pending) decided inline."""
        landing = self._landing
        if landing is not None and now >= landing[0]:
            self.torque = landing[1]
            self._landing = None
        if (self.armed and not self.tripped
                and now >= self.last_packet + 2 + self.config[_TIMEOUT]) \
                or self._prime_due is not None:
            self._watch(now)
        return self.torque


class EncoderEvents:
    """The node's encoder interface, event by event (equal to
    :class:`~hdl.node.encoder_ref.EncoderModel` on the same lines).

    Feed it the exact count of every cycle (:meth:`feed`, the plant's
    :class:`~models.encoder.EncoderCycles` ``counts`` column); query it at the control ticks
    (:meth:`sample`, which is also the velocity estimator's strobe). Only the cycles where a
    line changes cost Python time.

    Parameters
    ----------
    params : EncoderParams
    count0 : int
        The count the lines show from reset on (the interface counts from 0 there).
    """

    def __init__(self, params: EncoderParams, count0: int):
        self.p = params
        self.kv = params.kv
        self._kv_scale = params.kv * 2.0 ** 11        # velocity word ≈ num / den · this
        self._raw = int(count0)                 # last raw count fed
        self._known = -1                        # last cycle fed
        a, b = (((count0 & 3) >> 1) ^ (count0 & 1)), (count0 & 3) >> 1
        self._filt = [a, b]                     # filtered levels (decided so far)
        self._pair = (a, b)                     # decoder's pair (as of the last commit)
        self._pending = [[], []]                # per line: raw changes (cycle, level) unresolved
        self._visible: list[tuple[int, int]] = []   # (cycle visible, +1 / -1 / 0 illegal)
        self._vi = 0
        self.count = 0
        self.errors = 0
        self.velocity = 0
        self._e_last = 0                        # cycle the last edge became visible
        self._ref_t = 0                         # age_ref(c) = min(c - _ref_t, AGE_MAX)
        self._c_ref = 0
        self._moved = (-1, 0)                   # (cycle, _ref_t before) of the last MEASURE
        self._pipe: list = []                   # (cycle visible, case, num, den), in order
        self._taken = -2
        self._last = (0, 0)
        self._last_c = -1
        self.errors_at_last = 0
        self._min_window = params.min_window
        self._stop_cycles = params.stop_cycles
        self._due: list[int] = []               # deferred strobes (:meth:`defer`)
        self._due_gap = _NEVER                  # smallest gap between them

    def feed(self, start: int, counts: np.ndarray) -> None:
        """Raw counts of cycles ``start … start + len(counts) − 1`` (consecutive feeds)."""
        counts = np.asarray(counts)
        if start != self._known + 1:
            raise ValueError(f"feed must continue at cycle {self._known + 1}, not {start}")
        prev = np.empty_like(counts)
        prev[0] = self._raw
        prev[1:] = counts[:-1]
        idx = np.flatnonzero(counts != prev)
        changes = list(zip(idx.tolist(), counts[idx].tolist(), strict=True)) if len(idx) else ()
        self.feed_changes(start, len(counts), changes)

    def feed_changes(self, start: int, n: int, changes) -> None:
        """Cycles ``start … start + n − 1`` given as their count changes: ``(i, count)`` means
        the raw count is ``count`` from cycle ``start + i`` on (increasing ``i``, each a
        change; :meth:`models.plant.Plant.encoder_changes`). Same as :meth:`feed` on the
        per-cycle counts."""
        if start != self._known + 1:
            raise ValueError(f"feed must continue at cycle {self._known + 1}, not {start}")
        if changes:
            pending = self._pending
            o = self._raw
            for i, n_ in changes:
                lo = n_ if n_ < o else o
                if (lo & 3) in (0, 2):
                    pending[0].append((start + i, ((n_ & 3) >> 1) ^ (n_ & 1)))
                else:
                    pending[1].append((start + i, (n_ & 3) >> 1))
                o = n_
            self._raw = o
        self._known = start + n - 1
        if self._pending[0] or self._pending[1]:
            self._resolve()

    def _resolve(self) -> None:
        f = self.p.filter_cycles
        commits = []
        for line in (0, 1):
            pend = self._pending[line]
            keep = 0
            for j, (t, level) in enumerate(pend):
                nxt = pend[j + 1][0] if j + 1 < len(pend) else None
                if nxt is None and t + f - 1 > self._known:
                    keep = j
                    break
                keep = j + 1
                if level != self._filt[line] and (nxt is None or nxt - t >= f):
                    self._filt[line] = level
                    commits.append((t + f + 1, line, level))
            del pend[:keep]
        if not commits:
            return
        commits.sort()
        i = 0
        while i < len(commits):
            k = commits[i][0]
            pair = list(self._pair)
            while i < len(commits) and commits[i][0] == k:
                pair[commits[i][1]] = commits[i][2]
                i += 1
            pair = tuple(pair)
            d = (_PHASE[pair] - _PHASE[self._pair]) % 4
            self._pair = pair
            self._visible.append((k + 1, 0 if d == 2 else (1 if d == 1 else -1)))

    def sample(self, c: int) -> tuple[int, int, int]:
        """``(count, velocity, errors)`` visible in cycle ``c``, then the velocity strobe there
        (a second call for the same cycle returns the same values)."""
        count, velocity = self.tick_sample(c)
        return count, velocity, self.errors_at_last

    def tick_sample(self, c: int) -> tuple[int, int]:
        """:meth:`sample` without the error count (the control tick's path)."""
        if c == self._last_c:
            return self._last
        if self._due:
            self._flush(c)
            if c == self._last_c:
                return self._last
        return self._strobe(c)

    def defer(self, c: int) -> int:
        """The count visible in cycle ``c``, with the velocity strobe there deferred: it takes
        effect, exactly as :meth:`tick_sample` would have, before the next :meth:`sample` or
        :meth:`tick_sample` (for ticks that do not use the velocity; calls in cycle order)."""
        due = self._due
        if due and c - due[-1] < self._due_gap:
            self._due_gap = c - due[-1]
        due.append(c)
        return self.count_at(c)

    def count_at(self, c: int) -> int:
        """The count visible in cycle ``c`` (no strobe, nothing taken)."""
        vis = self._visible
        i = self._vi
        count = self.count
        while i < len(vis) and vis[i][0] <= c:
            count += vis[i][1]
            i += 1
        return count

    def defer_range(self, first: int, last: int, step: int) -> None:
        """:meth:`defer` for cycles ``first, first + step, …, last`` (counts not wanted)."""
        due = self._due
        gap = first - due[-1] if due else _NEVER
        if last > first and step < gap:
            gap = step
        if gap < self._due_gap:
            self._due_gap = gap
        due.extend(range(first, last + 1, step))

    def _flush(self, upto: int) -> None:
        """The deferred strobes, in order, before the strobe in cycle ``upto``.

        From a taken strobe ``p`` on, until the next visible edge, the count and the last edge
        do not change, so no strobe can MEASURE (``p`` moved the reference, or its window and
        ``dc`` stay as they were) and each one BOUNDs with the same numerator and a growing
        ``age_ref``, or STOPs once the edge is old enough. The velocity word is non-increasing
        in the denominator (checked over all 2^26 of them: ``y1 · 2^−p`` of
        :func:`~hdl.node.encoder_ref.reciprocal` never increases), so of a run of such clips
        only the last one acts, and after a STOP the velocity is 0: a run folds into one
        clip. Runs whose ages saturate, or strobes closer than :data:`VEL_LATENCY` (a result
        not yet visible at the next strobe), go one by one."""
        due = self._due
        vis = self._visible
        p = self._taken
        last = due[-1]
        if p == self._last_c and self._due_gap >= VEL_LATENCY and \
                due[0] - p >= VEL_LATENCY and upto - last >= VEL_LATENCY and \
                last - self._ref_t <= AGE_MAX and last - self._e_last <= AGE_MAX and \
                (self._vi >= len(vis) or upto < vis[self._vi][0]):
            self._due = []                      # the usual case: one run, no edge, fold it
            self._due_gap = _NEVER
            self._fold(due[0], last)
            return
        self._due = []
        self._due_gap = _NEVER
        m = len(due)
        i = 0
        while i < m:
            p = self._taken
            if p == self._last_c:
                vi = self._vi
                nxt = vis[vi][0] if vi < len(vis) else _NEVER
                g, prev = i, p
                while g < m and due[g] < nxt and due[g] - prev >= VEL_LATENCY:
                    prev = due[g]
                    g += 1
                if g > i and prev - self._ref_t <= AGE_MAX and prev - self._e_last <= AGE_MAX:
                    if g == m and upto < nxt and upto - prev >= VEL_LATENCY:
                        self._fold(due[i], prev)        # all of them: upto sees the last
                        return
                    if g - i >= 2:
                        self._fold(due[i], due[g - 2])
                        i = g - 1
                        continue
            self._strobe(due[i])
            i += 1

    def _fold(self, first: int, last: int) -> None:
        """Strobes ``first … last`` of a run (see :meth:`_flush`) with their results applied,
        as the strobe after them (at least :data:`VEL_LATENCY` later) would see them."""
        self._apply_pipe(first)                 # the result of the strobe before them
        if last - self._e_last >= self._stop_cycles:
            self.velocity = 0
        else:
            dc = self.count - self._c_ref
            if dc > DC_MAX:
                dc = DC_MAX
            elif dc < -DC_MAX - 1:
                dc = -DC_MAX - 1
            self._clip(abs(dc) + 1, last - self._ref_t)
        self._taken = last
        self._last_c = last                     # (no call comes for it: cycles only increase)
        self._last = (self.count, self.velocity)

    def _apply_pipe(self, c: int) -> None:
        pipe = self._pipe
        while pipe and pipe[0][0] <= c:
            _, case, num, den = pipe.pop(0)
            if case == 0:
                self.velocity = 0
            elif case == 1:
                self.velocity = velocity_word(num, den, self.kv)
            else:
                self._clip(num, den)

    def _clip(self, num: int, den: int) -> None:
        """BOUND: ``|velocity|`` at most the word of ``num / den``."""
        mag = abs(self.velocity)
        # The bound clips only an estimate above it; the reciprocal's relative error is
        # < 2.5e-5, so far below the bound the exact word need not be formed.
        if mag >= WORD_MAX or mag > num * self._kv_scale / (den or 1) * 0.999 - 2:
            v = velocity_word(num, den, self.kv)
            if mag > v:
                self.velocity = v if self.velocity > 0 else -v

    def preset(self, c: int, value: int) -> None:
        """CONFIG PRESET in cycle ``c`` (homing): the count and the reference count load
        ``value`` at the end of the cycle, as :meth:`EncoderModel.cycle
        <hdl.node.encoder_ref.EncoderModel.cycle>` with ``preset``. Call it after the strobe
        of cycle ``c``, if any (a read in cycle ``c`` still sees the old count); a decoder
        step in cycle ``c`` is lost to the preset but is an edge, and a MEASURE strobed in
        cycle ``c`` does not move the reference."""
        if self._due:
            self._flush(c)
        vis = self._visible
        if self._vi < len(vis) and vis[self._vi][0] <= c + 1:
            self._decode(c + 1)                             # visible by c + 1: decoded by c
        if self._moved[0] == c:
            self._ref_t = self._moved[1]
        self.count = self._c_ref = ((int(value) + 2**31) % 2**32) - 2**31

    def _decode(self, upto: int) -> None:
        """Take every decoder step visible by cycle ``upto`` into the count (an illegal step
        into the error counter), dropping taken steps from the list now and then."""
        vis = self._visible
        vi = self._vi
        while vi < len(vis) and vis[vi][0] <= upto:
            t, step = vis[vi]
            vi += 1
            if step:
                self.count += step
                self._e_last = t
            else:
                self.errors = min(self.errors + 1, 0xFFFF)
        if vi > 64:
            del vis[:vi]
            vi = 0
        self._vi = vi

    def _strobe(self, c: int) -> tuple[int, int]:
        vis = self._visible
        if self._vi < len(vis) and vis[self._vi][0] <= c:
            self._decode(c)
        pipe = self._pipe
        if pipe and pipe[0][0] <= c:
            self._apply_pipe(c)
        count = self.count
        out = (count, self.velocity)
        self._last = out
        self._last_c = c
        self.errors_at_last = self.errors
        if c != self._taken + 1:
            self._taken = c
            age_edge = c - self._e_last
            if age_edge > AGE_MAX:
                age_edge = AGE_MAX
            age_ref = c - self._ref_t
            if age_ref > AGE_MAX:
                age_ref = AGE_MAX
            dc = count - self._c_ref
            if dc > DC_MAX:
                dc = DC_MAX
            elif dc < -DC_MAX - 1:
                dc = -DC_MAX - 1
            window = age_ref - age_edge
            due = c + VEL_LATENCY
            if dc != 0 and window >= self._min_window:
                pipe.append((due, 1, dc, window))
                self._c_ref = count
                self._moved = (c, self._ref_t)
                self._ref_t = c + 2 - min(age_edge + 2, AGE_MAX)
            elif age_edge >= self._stop_cycles:
                pipe.append((due, 0, 0, 1))
            else:
                pipe.append((due, 2, abs(dc) + 1, age_ref))
        return out
