"""The ``model`` backend: the closed loop with the nodes' bit-exact references at transaction level.

Same master, same plant, same plant step, same seed as :class:`cosim.closed_loop.ClosedLoop`
on the gateware; the gateware is replaced by

* one :class:`~hdl.node.core_ref.NodeModel` per node (period timer, ticks, joint engine, VDC,
  watchdog, replies), bit-exact and cycle-exact with :class:`~hdl.node.core.NodeCore` given
  the same events;
* one :class:`EncoderEvents` per node: the encoder interface (synchronizer, glitch filter,
  ×4 decoder, M/T velocity estimator) computed from the plant's per-cycle counts event by
  event, equal to :class:`~hdl.node.encoder_ref.EncoderModel` cycle for cycle;
* a link whose only job is the timeline: a packet's last character reaches node k
  ``9 + 11 (k − 1)`` cycles plus its frame time (10 line bits per data character, 4 per EOP,
  3 line bits per cycle at 150 Mbit/s) after the master's link is free (a time-code before
  it holds the link for 14 bits); the node's core then takes its payload one byte per cycle,
  one cycle more per word written through the engines' host port (13 for a Comm B, 3 for a
  Comm D, a PARAM's words), after any packet before it; a reply leaves the node's reply FSM
  when :meth:`NodeModel.reply_cycle <hdl.node.core_ref.NodeModel.reply_cycle>` says and
  reaches the master ``1 + 9 + 11 (k − 1)`` cycles plus its frame time later, or its frame
  time after the upstream link is free; a time-code reaches node k after ``12 k`` cycles
  (docs/link.md "Per-hop latency"). These are approximations: every node event (the
  observation port, :attr:`NodeModel.events <hdl.node.core_ref.NodeModel.events>`) lies
  within :data:`EVENT_TOLERANCE` cycles of the gateware's — 12 is the time-code's wait for
  the character on the line, at most 4 cycles per hop over three hops, which the packets
  behind it inherit; 6 measured over 20 ms of mrm3 (tests/test_node_events.py). The
  boundary, the commit and the VDC's durations are exact. The master's packets leave at the
  cycle they are due in both loops (a step is split there), as long as its compute times are
  at least a plant step (the default: 1,000 cycles); a shorter one is rounded up to the end of
  the step its trigger arrived in here, possibly to an earlier split point in the gateware
  loop.

Why the results are nonetheless the gateware's, bit for bit: the node acts on its own period
timer and on packet *contents* (docs/node.md "Timing"). The torque at every plant step and every
reply payload depend on when packets arrive only through conditions the model checks with a
margin: time-codes inside the sync window, Comm B after the snapshot, every Comm D before the
commit phase, the ARM before the boundary that should arm, no watchdog silence. A run where one
of these is near its edge, or a time-code resynchronises a node, is reported
(:attr:`ModelLoop.violations`, and :class:`ModelAssumptionError` with ``strict=True``); its
results may then differ from the gateware's by the latency error.

Lazy evaluation (``ModelLoop(..., lazy=True)``, the default). The plant samples the torque
words once per plant step (500 cycles, 10 control ticks), so a tick whose torque the next tick
overwrites before anything reads it (the plant's sample, a boundary's snapshot, a reply, the
watchdog's ramp) need not compute it. Such *dead* ticks run in one call per plant step and
node: in VDC and torque mode the joint's state is ``(q_des, v_des)`` from Part B, a function of
the committed Comm D words and the tick's time only, so only the last dead tick's Part B is
kept (applied by the next tick that computes); in PID mode the integral carries from tick to
tick and is updated on every one (exact integer arithmetic, same roundings, the clip where it
binds). Their velocity strobes are deferred and folded into the next real sample
(:meth:`EncoderEvents.defer`), and the encoder interfaces take the plant's count changes
(:meth:`Plant.encoder_changes <models.plant.Plant.encoder_changes>`) instead of per-cycle
arrays. ``lazy=False`` keeps the eager path (every tick, every strobe, per-cycle counts);
both give the same plant trace, torque words, replies and node state bit for bit
(tests/test_model_backend.py, 200 ms of the quintic per controller and a clipped PID
integral).
"""

from __future__ import annotations

import hashlib
import time

import numpy as np

from mrm_cosim.protocol import packet as ref
from mrm_cosim.hdl.node.core_ref import _NEVER, _TIME_MAX, NodeModel
from mrm_cosim.hdl.node.encoder_ref import VEL_LATENCY, velocity_word
from mrm_cosim.protocol.encoder import AGE_MAX, DC_MAX, EncoderParams, encoders_per_node
from mrm_cosim.protocol.fixed import (
    ACC, FORCE, GAIN, INVT, RHOT, SIG, THETA, TRIG, VEL, WORD_MAX, WORD_MIN, theta_group,
)
from mrm_cosim.protocol.joint_program import joint_microcode
from mrm_cosim.protocol.joint_program import MODES as JOINT_MODES
from mrm_cosim.hdl.node.joint_ref import JointModel
from mrm_cosim.protocol.regs import Config
from mrm_cosim.protocol.vdc_program import Y_TABLE, link_terms
from mrm_cosim.hdl.node.vdc_ref import VdcModel
from mrm_cosim.master.cycle import Master, Send
from mrm_cosim.models.plant import Plant
from mrm_cosim.models.robot import Robot
from mrm_cosim.errors import InputError
from mrm_cosim.units import CLOCK_HZ

from .closed_loop import LoopResult, startup_sends

__all__ = ["EncoderEvents", "FastNode", "FastVdc", "fast_joint_tick", "part_b", "pid_integral",
           "ModelLoop", "ModelAssumptionError", "LINK_UP_CYCLE", "EVENT_TOLERANCE"]

#: Cycle at which the modelled link reaches Run (the gateware: about 21.4 µs at standard timers).
LINK_UP_CYCLE = 1_100
_FIRST_HOP = 9          # master tx → node 1, cycles before the first character
_HOP = 11               # per further hop
_TC_HOP = 12            # time-code, per hop
_TC_LINE = 5            # a time-code's line time (ESC + data: 14 bits), cycles
_REPLY = 1              # reply FSM leaves Idle → reply's first character offered
#: The modelled node events' largest distance from the gateware's, in cycles (see the module
#: docstring; the boundary, the commit and the VDC's durations are exact).
EVENT_TOLERANCE = 12
_MARGIN = 500           # cycles of margin the model wants around every timing condition

_PHASE = {(0, 0): 0, (1, 0): 1, (1, 1): 2, (0, 1): 3}


class ModelAssumptionError(RuntimeError):
    """A model run left the conditions under which it equals the gateware."""


def _frame_cycles(payload_len: int) -> int:
    """Line time of a frame (header 4 + payload + CRC 2 data characters, EOP), cycles."""
    return -(-((4 + payload_len + 2) * 10 + 4) // 3)


def _delivery_cycles(ptype: int, payload_len: int) -> int:
    """Cycles from a frame's last character at the node to its last payload byte taken by the
    core: a byte per cycle, and a cycle per word the core writes through an engine's host
    port (its ``rx.ready`` is low while the word waits; the engines are idle then)."""
    words = 0
    if ptype == ref.PacketType.COMM_B and payload_len == 40:
        words = 13
    elif ptype == ref.PacketType.COMM_D:
        words = min(3, max(0, payload_len // 3 - 1))
    elif ptype == ref.PacketType.PARAM:
        words = min(12, max(0, (payload_len - 3) // 3))
    return payload_len + words


def _sat(v: int) -> int:
    return WORD_MIN if v < WORD_MIN else WORD_MAX if v > WORD_MAX else v


def fast_joint_tick(j: JointModel, mode: int, q: int, qd: int, tn: int, tau_D: int, qd0: int,
                    vd0: int, ad0: int) -> int:
    """:meth:`JointModel.tick <hdl.node.joint_ref.JointModel.tick>` with every rounding
    written out (formats' binary points folded into constant shifts); returns ``τ``.

    ``mode``: 0 VDC, 1 PID, 2 torque. Bit-exact with the reference (tested on random words).
    Each statement is one ``fx``: the exact sum aligned to its finest LSB, rounded half up onto
    the destination's LSB, saturated to ±2^23 (written inline: this runs a million times per
    simulated second and node). LSBs: POS −4, CNT 0, VEL −19, ACC −14, FORCE −13, SGN −23, LAMC
    −30, LAM −12, IVS −8, IVLC −20, IM −20, VISC −16, GAIN −12, KP −24, KI −32, IHI 10, TS −26,
    CT −48, ANG −26, KC −6.
    """
    tau = _part_a(j, mode, q, qd, tau_D, ad0)
    part_b(j, tn, qd0, vd0, ad0)        # Part B: the reference for the next tick
    return tau


def _part_a(j: JointModel, mode: int, q: int, qd: int, tau_D: int, ad0: int) -> int:
    """Part A of :func:`fast_joint_tick`: the torque (and in PID mode the integral) from the
    joint's current reference ``(q_des, v_des)``; Part B is left to the caller."""
    p = j.params
    if q < -8388608:
        q = -8388608
    elif q > 8388607:
        q = 8388607
    q_des, v_des = j.q_des, j.v_des
    e = q_des - (q << 4)
    if e < -8388608:
        e = -8388608
    elif e > 8388607:
        e = 8388607
    if mode == 0:
        qdr = ((v_des << 15) + p.lamc * e + 16384) >> 15
        if qdr < -8388608:
            qdr = -8388608
        elif qdr > 8388607:
            qdr = 8388607
        qddr = ((ad0 << 17) + p.lam * (v_des - qd) + 65536) >> 17
        if qddr < -8388608:
            qddr = -8388608
        elif qddr > 8388607:
            qddr = 8388607
        sg = (p.ivs * v_des + ((p.ivlc * e) << 3) + 8) >> 4
        if sg < -8388608:
            sg = -8388608
        elif sg > 8388607:
            sg = 8388607
        tau = ((tau_D << 23) + ((p.th0 * qddr) << 2) + ((p.th1 * qdr) << 1) + p.th2 * sg
               + (p.th3 << 23) + ((p.kj * (qdr - qd)) << 5) + 4194304) >> 23
        if tau < -8388608:
            tau = -8388608
        elif tau > 8388607:
            tau = 8388607
    elif mode == 1:
        i_lo, i_hi = j.i_lo, j.i_hi
        tau = _sat(((tau_D << 23) + ((p.kp * e) << 8) + p.ki * i_lo + ((p.ki * i_hi) << 14)
                    + ((p.kd * (v_des - qd)) << 5) + (1 << 22)) >> 23)
        s = i_lo + q_des - (q << 4)
        c = _sat((s + (1 << 13)) >> 14)
        j.i_lo = _sat(s - (c << 14))
        hi = _sat(i_hi + c)
        j.i_hi = min(max(hi, p.ilo), p.ihi)
    else:
        tau = tau_D
    return tau


def part_b(j: JointModel, tn: int, qd0: int, vd0: int, ad0: int) -> None:
    """Part B of :func:`fast_joint_tick` (which calls it; dead ticks call it alone):
    ``(q_des, v_des)`` for the tick ``tn`` cycles after the start of the references' period."""
    p = j.params
    ts = (tn * p.cT + 2097152) >> 22
    if ts < -8388608:
        ts = -8388608
    elif ts > 8388607:
        ts = 8388607
    tsh = (tn * p.cTh + 2097152) >> 22
    if tsh < -8388608:
        tsh = -8388608
    elif tsh > 8388607:
        tsh = 8388607
    v0 = vd0 << 21
    v = (v0 + ad0 * ts + 1048576) >> 21
    j.v_des = -8388608 if v < -8388608 else 8388607 if v > 8388607 else v
    h = (v0 + ad0 * tsh + 1048576) >> 21
    if h < -8388608:
        h = -8388608
    elif h > 8388607:
        h = 8388607
    dq = (h * ts + 262144) >> 19
    if dq < -8388608:
        dq = -8388608
    elif dq > 8388607:
        dq = 8388607
    qq = ((qd0 << 28) + dq * p.Kc + 134217728) >> 28
    j.q_des = -8388608 if qq < -8388608 else 8388607 if qq > 8388607 else qq


def pid_integral(j: JointModel, q: int) -> None:
    """The PID integral's update of :func:`fast_joint_tick` alone (mode 1, count ``q``): what a
    tick whose torque nobody observes still has to do."""
    if q < -8388608:
        q = -8388608
    elif q > 8388607:
        q = 8388607
    s = j.i_lo + j.q_des - (q << 4)
    c = _sat((s + (1 << 13)) >> 14)
    j.i_lo = _sat(s - (c << 14))
    hi = _sat(j.i_hi + c)
    p = j.params
    j.i_hi = min(max(hi, p.ilo), p.ihi)


def _fx_src(dst: str, parts, fmt) -> list[str]:
    """Source lines computing ``dst = fx(parts, fmt)`` of :func:`hdl.node.vdc_ref.fx` for
    ``parts`` = [(Python expression, lsb)]: each part shifted onto the finest LSB, the exact sum
    rounded half up onto ``fmt``'s LSB and saturated to 24 bits (the same integers)."""
    low = min([lsb for _, lsb in parts] + [fmt.lsb])
    total = " + ".join(f"({e})" if lsb == low else f"(({e}) << {lsb - low})" for e, lsb in parts)
    r = fmt.lsb - low
    if r:
        total = f"({total} + {1 << (r - 1)}) >> {r}"
    return [f"{dst} = {total}",
            f"{dst} = -8388608 if {dst} < -8388608 else 8388607 if {dst} > 8388607 else {dst}"]


def _y_src(summands) -> str:
    """A :data:`~hdl.node.vdc_ref.Y_TABLE` entry as an expression over the local names
    ``a0 a1 a2``, ``P00 … P22`` and ``dw0 dw1 dw2`` (an exact sum, as ``VdcModel._link``'s
    ``y``)."""
    return " ".join(f"{'-' if sgn < 0 else '+'} {kind}{idx:02d}" if kind == "P" else
                    f"{'-' if sgn < 0 else '+'} {kind}{idx}" for sgn, kind, idx in summands)


def _fast_vdc_src() -> str:
    """Source of :class:`FastVdc`'s ``step`` and ``_link``: :class:`~hdl.node.vdc_ref.VdcModel`'s
    statements in the same order, each ``fx`` written out once for its formats (the shifts and
    rounding constants are the formats' binary points), loops unrolled, each regressor entry
    summed once for both the forces and the adaptation signal."""
    vv, aa = 2 * VEL.lsb, ACC.lsb
    src = ["def _link(self, i, V, V_r, dV, g):",
           "    th = self.theta[i]",
           "    p = self.params",
           "    K, rho, lower, upper = p.K[i], p.rho_T[i], p.lower[i], p.upper[i]",
           "    V0, V1, V2, V3, V4, V5 = V",
           "    R0, R1, R2, R3, R4, R5 = V_r"]
    body = []
    for k in range(3):
        m, n = 3 + (k + 1) % 3, 3 + (k + 2) % 3
        body += _fx_src(f"a{k}", [(f"dV[{k}]", aa), (f"V{m} * R{n - 3}", vv),
                                  (f"-V{n} * R{m - 3}", vv), (f"g[{k}]", aa)], ACC)
    for m in range(3):
        for n in range(3):
            body += _fx_src(f"P{m}{n}", [(f"V{3 + m} * R{3 + n}", vv)], ACC)
    body += [f"dw{k} = dV[{3 + k}]" for k in range(3)]
    body += [line for k in range(6)
             for line in _fx_src(f"e{k}", [(f"R{k}", VEL.lsb), (f"-V{k}", VEL.lsb)], VEL)]
    body += [f"th{j} = th[{j}]" for j in range(13)]
    body += [f"y{row}_{col} = {_y_src(s)}" for (row, col), s in sorted(Y_TABLE.items())]
    for row in range(6):
        parts = [(f"y{row}_{col} * th{col}", ACC.lsb + THETA[theta_group(col)].lsb)
                 for (_, col), _s in link_terms(row=row)]
        parts.append((f"K[{row}] * e{row}", GAIN.lsb + VEL.lsb))
        body += _fx_src(f"F{row}", parts, FORCE)
    for col in range(13):
        body += _fx_src(f"sig{col}", [(f"y{row}_{col} * e{row}", ACC.lsb + VEL.lsb)
                                      for (row, _), _s in link_terms(col=col)], SIG)
    for j in range(13):
        fmt = THETA[theta_group(j)]
        body += _fx_src(f"d{j}", [(f"rho[{j}] * sig{j}", RHOT[theta_group(j)].lsb + SIG.lsb)],
                        fmt)
        body += _fx_src(f"t{j}", [(f"th{j}", fmt.lsb), (f"d{j}", fmt.lsb)], fmt)
        body.append(f"t{j} = min(max(t{j}, lower[{j}]), upper[{j}])")
    body.append("return [" + ", ".join(f"F{r}" for r in range(6)) + "], ["
                + ", ".join(f"t{j}" for j in range(13)) + "]")
    src += ["    " + line for line in body]

    lr, lq, li = TRIG.lsb + ACC.lsb, 2 * VEL.lsb, VEL.lsb + INVT.lsb
    lv = TRIG.lsb + VEL.lsb
    body = ["c, s = x.cos_q, x.sin_q",
            "if not self.primed:",
            "    self.prev_C = list(x.V_rC)",
            "    self.prev_qd_r = x.qd_r",
            "    self.primed = True",
            "qd, qd_r, inv_T = x.qd, x.qd_r, self.params.inv_T",
            "C0, C1, C2, C3, C4, C5 = x.V_C",
            "Q0, Q1, Q2, Q3, Q4, Q5 = x.V_rC",
            "P0, P1, P2, P3, P4, P5 = self.prev_C",
            "G0, G1, G2 = x.g_C"]
    for out, vec, w in (("A", "C", "qd"), ("rA", "Q", "qd_r")):     # _link_a
        for base in (0, 3):
            body += _fx_src(f"{out}{base}", [(f"c * {vec}{base}", lv),
                                             (f"s * {vec}{base + 1}", lv)], VEL)
            body += _fx_src(f"{out}{base + 1}", [(f"-s * {vec}{base}", lv),
                                                 (f"c * {vec}{base + 1}", lv)], VEL)
        body.append(f"{out}2 = {vec}2")
        body += _fx_src(f"{out}5", [(f"{vec}5", VEL.lsb), (w, VEL.lsb)], VEL)
    body += _fx_src("gA0", [("c * G0", TRIG.lsb + ACC.lsb), ("s * G1", TRIG.lsb + ACC.lsb)], ACC)
    body += _fx_src("gA1", [("-s * G0", TRIG.lsb + ACC.lsb), ("c * G1", TRIG.lsb + ACC.lsb)],
                    ACC)
    for k in range(6):
        body += _fx_src(f"dC{k}", [(f"Q{k} * inv_T", li), (f"-P{k} * inv_T", li)], ACC)
    body += _fx_src("qdd_r", [("qd_r * inv_T", li), ("-self.prev_qd_r * inv_T", li)], ACC)
    for base in (0, 3):
        body += _fx_src(f"dA{base}", [(f"c * dC{base}", lr), (f"s * dC{base + 1}", lr),
                                      (f"qd * rA{base + 1}", lq)], ACC)
        body += _fx_src(f"dA{base + 1}", [(f"-s * dC{base}", lr), (f"c * dC{base + 1}", lr),
                                          (f"-qd * rA{base}", lq)], ACC)
    body.append("dA2 = dC2")
    body += _fx_src("dA5", [("dC5", ACC.lsb), ("qdd_r", ACC.lsb)], ACC)
    body += ["F_a, th_a = self._link(0, [A0, A1, A2, A3, A4, A5], "
             "[rA0, rA1, rA2, rA3, rA4, rA5], [dA0, dA1, dA2, dA3, dA4, dA5], [gA0, gA1, G2])",
             "F_b, th_b = self._link(1, x.V_C, x.V_rC, [dC0, dC1, dC2, dC3, dC4, dC5], x.g_C)",
             "self.theta = [th_a, th_b]",
             "self.prev_C = list(x.V_rC)",
             "self.prev_qd_r = x.qd_r",
             "return F_a, F_b"]
    src += ["def step(self, x):"] + ["    " + line for line in body]
    return "\n".join(src) + "\n"


_FAST_VDC: dict = {}
exec(compile(_fast_vdc_src(), "<FastVdc>", "exec"), _FAST_VDC)   # (source built above)


class FastVdc(VdcModel):
    """:class:`~hdl.node.vdc_ref.VdcModel` with its step written out for the formats
    (:func:`_fast_vdc_src`, generated once at import): the same sums, the same roundings
    (tested equal on random words, extremes included)."""

    step = _FAST_VDC["step"]
    _link = _FAST_VDC["_link"]


_CYCLES = tuple(joint_microcode().cycles(m) for m in JOINT_MODES)
_TICK, _MODE, _TIMEOUT, _TAU_MIN, _TAU_MAX, _COMMIT = (int(c) for c in (
    Config.TICK, Config.MODE, Config.TIMEOUT, Config.TAU_MIN, Config.TAU_MAX, Config.COMMIT))


class FastNode(NodeModel):
    """:class:`~hdl.node.core_ref.NodeModel` with its control tick on
    :func:`fast_joint_tick` (same behaviour; the tick is what a long run spends its time on).

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
            part_b(self.joint, d[0], d[1], d[2], d[3])

    def _param(self, bank: int, addr: int, w: int) -> None:
        self._materialize()                 # a host write comes after the Part B before it
        NodeModel._param(self, bank, addr, w)

    def _tick(self, now, sample, tt, ramped=False):       # the event loop's ticks
        self._fast_tick(now, lambda c: sample(c)[:2], tt, ramped)

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
            nb = self._nb
            special = nb
            if self._commit_seen != self._lb:
                commit = self._lb + cfg[_COMMIT]
                if commit < special:
                    special = commit
            if self.arm_pending and self._pre_seen != nb and nb - 1 < special:
                special = nb - 1
            lim = special if special < until else until
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
        # PID: the integral on every tick (pid_integral, then part_b's q_des; v_des only for
        # the last), the counts read along the encoder's visible edges, the strobes deferred
        self._materialize()
        j = self.joint
        p = j.params
        cT, cTh, Kc, ilo, ihi = p.cT, p.cTh, p.Kc, p.ilo, p.ihi
        qd0, v0, ad0 = d[1], d[2] << 21, d[3]
        q0 = qd0 << 28
        enc = self._encoder
        vis = enc._visible
        nv = len(vis)
        k = enc._vi
        count = enc.count
        i_lo, i_hi, q_des = j.i_lo, j.i_hi, j.q_des
        ts = 0
        for t in range(first, last + 1, step):
            while k < nv and vis[k][0] <= t:
                count += vis[k][1]
                k += 1
            q = -8388608 if count < -8388608 else 8388607 if count > 8388607 else count
            x = i_lo + q_des - (q << 4)
            c = (x + 8192) >> 14
            c = -8388608 if c < -8388608 else 8388607 if c > 8388607 else c
            i_lo = x - (c << 14)
            i_lo = -8388608 if i_lo < -8388608 else 8388607 if i_lo > 8388607 else i_lo
            c += i_hi
            c = -8388608 if c < -8388608 else 8388607 if c > 8388607 else c
            c = c if c > ilo else ilo                   # min(max(hi, ilo), ihi)
            i_hi = c if c < ihi else ihi
            tn = t - lb + step
            if tn > _TIME_MAX:
                tn = _TIME_MAX
            ts = (tn * cT + 2097152) >> 22
            ts = -8388608 if ts < -8388608 else 8388607 if ts > 8388607 else ts
            h = (tn * cTh + 2097152) >> 22
            h = -8388608 if h < -8388608 else 8388607 if h > 8388607 else h
            h = (v0 + ad0 * h + 1048576) >> 21
            h = -8388608 if h < -8388608 else 8388607 if h > 8388607 else h
            h = (h * ts + 262144) >> 19
            h = -8388608 if h < -8388608 else 8388607 if h > 8388607 else h
            h = (q0 + h * Kc + 134217728) >> 28
            q_des = -8388608 if h < -8388608 else 8388607 if h > 8388607 else h
        v = (v0 + ad0 * ts + 1048576) >> 21
        j.v_des = -8388608 if v < -8388608 else 8388607 if v > 8388607 else v
        j.i_lo, j.i_hi, j.q_des = i_lo, i_hi, q_des
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
            pid_integral(self.joint, count)
            part_b(self.joint, tn, d[1], d[2], d[3])
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
        tau = _part_a(j, mode, count, qd, d[0], d[3])
        if self.lazy:
            # Part B deferred like a dead tick's: every reader of (q_des, v_des) materializes
            # it first (the next computed tick, a host write, PID's dead ticks), and in VDC
            # and torque mode a dead tick next replaces it unread
            self._deferred = (tn, d[1], d[2], d[3])
        else:
            part_b(j, tn, d[1], d[2], d[3])
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


class ModelLoop:
    """The closed loop on the ``model`` backend (same interface and result as
    :class:`~cosim.closed_loop.ClosedLoop`).

    Parameters
    ----------
    robot : Robot
    master : Master
    plant : Plant
    start_cycle : int
        Cycle of period 0 (a multiple of the nodes' PERIOD, after start-up and uploads).
    uploads : list of (dest, type, payload)
    encoder : EncoderParams or sequence of EncoderParams, optional
        The nodes' encoder interface: one for every node or one per node, as
        :class:`hdl.system.System` takes it (default: the gateware's default for every node).
    strict : bool
        Raise :class:`ModelAssumptionError` at the first violated condition instead of
        recording it in :attr:`violations`.
    lazy : bool
        Compute only the ticks whose torque is observed (:attr:`FastNode.lazy`), feed the
        encoder interfaces the plant's count changes (:meth:`Plant.encoder_changes
        <models.plant.Plant.encoder_changes>`) instead of per-cycle arrays, and run the VDC on
        :class:`FastVdc`. ``False`` is the eager path: every tick computed, per-cycle counts,
        the reference :class:`~hdl.node.vdc_ref.VdcModel`; both give the same results bit
        for bit.
    """

    def __init__(self, robot: Robot, master: Master, plant: Plant, start_cycle: int, uploads,
                 encoder=None, strict: bool = False, lazy: bool = True):
        self.robot = robot
        self.n = robot.n
        self.master = master
        self.plant = plant
        self.step_cycles = round(plant.dt * CLOCK_HZ)
        if start_cycle % self.step_cycles:
            raise InputError("start_cycle", "must be a multiple of the plant step")
        self.start_cycle = start_cycle
        self.strict = strict
        self.violations: list[str] = []
        #: latest modelled arrival phase (cycles) of a time-code and of a Comm D, over the run
        self.phases = {"timecode": 0, "comm_d": 0}
        self.cycle = 0
        self.frames = []
        encs = encoders_per_node(encoder, self.n)
        self.lazy = bool(lazy)
        self.nodes = [FastNode(encoder=enc) for enc in encs]
        for node in self.nodes:
            node.lazy = self.lazy
            node.events = []                    # the observation port, for the timeline
            if self.lazy:
                v = node.vdc
                node.vdc = FastVdc(v.params, v.theta, v.prev_C, v.prev_qd_r, v.primed)
        counts = plant.encoder_counts().tolist()
        self.encoders = [EncoderEvents(enc, c) for enc, c in zip(encs, counts, strict=True)]
        for node, encoder in zip(self.nodes, self.encoders, strict=True):
            node.attach(encoder)
        self._samplers = [e.sample for e in self.encoders]
        self._static = np.array(counts, dtype=np.int64)
        self._uploads = list(uploads)
        self._seq = 0
        self._down_free = 0                     # master → node 1 link free from this cycle
        self._up_free = 0                       # node 1 → master link free from this cycle
        self._inbox: list[list] = [[] for _ in range(self.n)]   # (cycle, order, kind, data)
        self._replies: list = []                # (cycle at master, src, type, payload, seq)
        self._rx_free = [0] * self.n            # node k's core takes bytes from this cycle
        self._torque = np.zeros(self.n)

    # --- conditions ----------------------------------------------------------------------------
    def _violate(self, message: str) -> None:
        if self.strict:
            raise ModelAssumptionError(message)
        if len(self.violations) < 100:
            self.violations.append(message)

    # --- link --------------------------------------------------------------------------------
    def _queue(self, action: Send, now: int) -> None:
        """The master hands ``action`` to its link port in cycle ``now``."""
        if action.kind == "timecode":
            t = max(now, self._down_free)
            for k in range(self.n):
                self._inbox[k].append((t + _TC_HOP * (k + 1), 0, "timecode", action.time))
            self._down_free = t + _TC_LINE          # the packets behind it wait for it
            return
        t = max(now, self._down_free) + _frame_cycles(len(action.payload))
        self._down_free = t
        dests = range(self.n) if action.dest == ref.BROADCAST else [action.dest - 1]
        for k in dests:
            if 0 <= k < self.n:
                taken = max(t + _FIRST_HOP + _HOP * k, self._rx_free[k]) + \
                    _delivery_cycles(action.ptype, len(action.payload))
                self._rx_free[k] = taken + 1
                self._inbox[k].append((taken, 1, "packet",
                                       (action.ptype, action.payload, action.seq)))

    def _reply(self, k: int, ready: int, ptype: int, payload: bytes, seq: int) -> None:
        """Queue a reply leaving node ``k``'s reply FSM in cycle ``ready``; like the
        gateware's, its header echoes the request's ``seq``."""
        t = max(ready + _REPLY + _FIRST_HOP + _HOP * k, self._up_free) + \
            _frame_cycles(len(payload))
        self._up_free = t
        self._replies.append((t, k + 1, ptype, payload, seq))

    # --- one chunk of cycles -----------------------------------------------------------------
    def _check_packet(self, k: int, node: NodeModel, c: int, ptype: int) -> None:
        if c < self.start_cycle:
            if ptype == ref.PacketType.CONFIG and c >= self.start_cycle - _MARGIN:
                self._violate(f"node {k + 1}: CONFIG {c - self.start_cycle} cycles before "
                              "period 0 (an ARM may miss its boundary)")
            return
        cfg = node.config
        ph = node.phase(c)
        if ptype == ref.PacketType.COMM_D:
            self.phases["comm_d"] = max(self.phases["comm_d"], ph)
        if ptype == ref.PacketType.COMM_D and node.armed:
            if abs(ph - cfg[Config.COMMIT]) < _MARGIN:
                self._violate(f"node {k + 1}: Comm D at phase {ph}, within {_MARGIN} cycles of "
                              f"the commit phase {cfg[Config.COMMIT]} (cycle {c})")
        elif ptype in (ref.PacketType.COMM_A, ref.PacketType.COMM_B) and (
                (ptype == ref.PacketType.COMM_B and ph < 100)
                or ph > cfg[Config.PERIOD] - _MARGIN):
            # (a Comm A request leaves the master with the time-code: it cannot overtake the
            # boundary; a Comm B needs the boundary's CORDIC, 60 cycles, in the VDC first)
            self._violate(f"node {k + 1}: {ref.PacketType(ptype).name} at phase {ph} "
                          f"(cycle {c}), too near a boundary")
        if node.armed and c - node.last_packet > cfg[Config.TIMEOUT] - _MARGIN:
            self._violate(f"node {k + 1}: {c - node.last_packet} cycles without a packet "
                          f"(watchdog timeout {cfg[Config.TIMEOUT]})")

    def _run_nodes(self, end: int) -> None:
        """Every node's events of cycles < ``end``; torque words output in cycle ``end − 1``."""
        for k, node in enumerate(self.nodes):
            sample = self._samplers[k]
            box = self._inbox[k]
            if box:
                box.sort(key=lambda e: (e[0], e[1]))
                i = 0
                while i < len(box) and box[i][0] < end:
                    c, _, kind, data = box[i]
                    i += 1
                    node.run(c, sample)
                    if kind == "timecode":
                        ph_before = node.phase(c) if c < node.next_boundary() else 0
                        window = node.config[Config.SYNC_WINDOW]
                        if c >= self.start_cycle:
                            self.phases["timecode"] = max(self.phases["timecode"], ph_before)
                        if node.timecode(c, data, sample):
                            self._violate(f"node {k + 1}: time-code at phase {ph_before} "
                                          f"(cycle {c}) resynchronised the timer")
                        elif window - ph_before < min(_MARGIN, window // 2):
                            self._violate(f"node {k + 1}: time-code at phase {ph_before}, "
                                          f"near the sync window {window}")
                        continue
                    ptype, payload, seq = data
                    node.run(c + 1)
                    self._check_packet(k, node, c, ptype)
                    reply = node.packet(c, ptype, payload, sample=sample)
                    if reply is not None:
                        self._reply(k, node.reply_cycle(c, ptype), ptype, reply, seq)
                del box[:i]
            node.run(end - 1, sample)
            self._torque[k] = FORCE.decode(node.torque_at(end - 1))
            if node.events:
                self._node_events(k, node, end)

    def _node_events(self, k: int, node: NodeModel, end: int) -> None:
        """Node ``k``'s observation-port strobes before cycle ``end`` to the master (later
        ones, such as a MARK still ahead, wait for their chunk)."""
        later = []
        for c, flag in node.events:
            if c < end:
                self.master.on_node_event(c, k + 1, flag.name)
            else:
                later.append((c, flag))
        node.events = later

    def _chunk(self, n: int, counts: np.ndarray | list | None) -> None:
        """``n`` cycles; ``counts``: per-cycle counts (n, joints), per-joint change lists
        (lazy path) or None (the lines at rest)."""
        start = self.cycle
        end = start + n
        if self.lazy:
            for k, enc in enumerate(self.encoders):
                enc.feed_changes(start, n, () if counts is None else counts[k])
        else:
            for k, enc in enumerate(self.encoders):
                enc.feed(start, np.full(n, self._static[k]) if counts is None else counts[:, k])
        self._run_nodes(end)
        if self._replies:
            self._replies.sort(key=lambda r: r[0])
            i = 0
            while i < len(self._replies) and self._replies[i][0] < end:
                c, src, ptype, payload, seq = self._replies[i]
                i += 1
                self.frames.append((c, src, ptype))
                if not self.master.stale(ptype, seq):       # else counted late
                    self.master.on_packet(c, src, ptype, bytes(payload))
            del self._replies[:i]
        self.cycle = end

    # --- the run -------------------------------------------------------------------------------
    def run(self, duration_cycles: int, progress=None) -> LoopResult:
        """Start-up and ``duration_cycles`` of closed loop; the trace, as
        :meth:`cosim.closed_loop.ClosedLoop.run` returns it. ``progress(t_sim, t_total)`` is
        called every simulated millisecond, as there."""
        s = self.step_cycles
        uploads_sent = False
        steps = duration_cycles // s
        t_rec = np.zeros(steps)
        q_rec = np.zeros((steps, self.n))
        tau_rec = np.zeros((steps, self.n))
        while self.cycle < self.start_cycle:
            if self.cycle >= LINK_UP_CYCLE and not uploads_sent:
                sends, self._seq = startup_sends(self._uploads, self.master, self.plant.q,
                                                 self._seq)
                for a in sends:
                    self._queue(a, self.cycle)
                uploads_sent = True
            self._chunk(s, None)
        if not uploads_sent:
            raise InputError("start_cycle", "the link did not come up before period 0")
        for k, node in enumerate(self.nodes):
            if node.config[Config.PERIOD] != self.master.timing.period_cycles or \
                    self.start_cycle % node.config[Config.PERIOD]:
                self._violate(f"node {k + 1}: PERIOD {node.config[Config.PERIOD]} and period 0 "
                              f"at cycle {self.start_cycle} are not the master's grid")
        self.master.begin(self.start_cycle)
        t_window = time.perf_counter()
        poll, step = self.master.poll, self.plant.step
        next_due = self.master.next_due
        for i in range(steps):
            for action in poll(self.cycle):
                self._queue(action, self.cycle)
            # packets the master computes by a cycle inside the step leave then (as the
            # gateware loop splits its step there)
            due = next_due()
            while due is not None and due < self.cycle + s:
                for action in poll(due):
                    self._queue(action, due)
                due = next_due()
            tau = self._torque.copy()
            step(tau)
            cyc = self.plant.encoder_changes() if self.lazy else self.plant.encoder_cycles().counts
            t_rec[i] = (self.cycle - self.start_cycle) / CLOCK_HZ
            q_rec[i] = self.plant.q
            tau_rec[i] = tau
            self._chunk(s, cyc)
            if progress is not None and (i + 1) % 100 == 0:
                progress((i + 1) * s / CLOCK_HZ, steps * s / CLOCK_HZ)
        self.master.finish(self.cycle)
        window = time.perf_counter() - t_window
        for k, node in enumerate(self.nodes):
            if node.tripped:
                self._violate(f"node {k + 1}: the watchdog tripped")
        digest = hashlib.sha256()
        digest.update(q_rec.tobytes())
        digest.update(tau_rec.tobytes())
        return LoopResult(t_rec, q_rec, tau_rec, self.master, 0, 0, self.frames,
                          digest.hexdigest(), window_wall_s=window)
