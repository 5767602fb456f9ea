"""The ``model`` backend's inner loop as integer code numba can compile: a node's plain control
ticks, its joint engine's arithmetic and its encoder interface, on arrays.

These functions are line-for-line translations of the readable references, which stay the
source of truth and the oracle: :class:`~hdl.node.joint_ref.JointModel` (``part_a``,
``part_b``, ``pid_integral``), :class:`cosim.model_node.EncoderEvents` and the lazy tick loop of
:meth:`cosim.model_node.FastNode.run`. Every name below says which method it stands for.
:mod:`cosim.model_kernel` compiles them (``numba.njit``) and wires them to the backend; its
tests run them against the references bit for bit.

Exactness. Every value is a Python ``int`` in the references and an ``int64`` here. The widest
intermediate is the PID torque's sum, ``k_i · I_hi`` (two 24-bit words, ≤ 2^46) shifted 14
bits left, ≤ 2^60 with the other four summands below 2^55 (checked for every rounding point and
PID gain shift by ``tests/test_model_kernel.py``); the velocity word's ``num · y1 · K_v`` is
below 2^46. Right shifts of negative values are arithmetic in both (floor), the ``& 3`` of a
negative count is two's complement in both, and the one float expression (the encoder's
``_clip`` pre-check) is the same IEEE operations in the same order.

State layout: one ``int64`` row per node (the ``N_*`` and ``E_*`` indices), the joint's words
and rounding points in a parameter row (``P_*``), and the encoder's queues in fixed buffers
with a length in the state row (overflow raises, it is never silent).
"""

from __future__ import annotations

import math

import numpy as np

from mrm_cosim.hdl.node.encoder_ref import VEL_LATENCY as _VEL_LATENCY
from mrm_cosim.models import compliant_kernel_src as compliant_src
from mrm_cosim.models import plant_kernel_src as plant_src
from mrm_cosim.models.encoder import _FEW_CHANGES
from mrm_cosim.protocol.encoder import AGE_MAX as _AGE_MAX
from mrm_cosim.protocol.encoder import DC_MAX as _DC_MAX
from mrm_cosim.protocol.cordic import ATAN as _ATAN_LIST
from mrm_cosim.protocol.cordic import GUARD as _GUARD
from mrm_cosim.protocol.cordic import ITERATIONS as _ITERATIONS
from mrm_cosim.protocol.cordic import X0 as _X0
from mrm_cosim.protocol.cordic import ZGUARD as _ZGUARD
from mrm_cosim.protocol.encoder import RECIP_TABLE
from mrm_cosim.protocol.fixed import FORCE as _FORCE
from mrm_cosim.protocol.fixed import WORD_MAX as _WORD_MAX
from mrm_cosim.protocol.fixed import WORD_MIN as _WORD_MIN

def borrow(a):
    """``a`` itself. Compiled (:func:`cosim.model_kernel.borrowed`), the same array without its
    reference count: numba increments and decrements an array's count (an atomic instruction
    each) at every call that takes it and every view made of it, and the tick loop's calls
    take six arrays each; the views and calls below an entry point that borrows its arrays
    skip those. Only the entry points called from Python borrow (their caller holds the
    arrays for the whole call), and none returns an array."""
    return a


# --- node state row (FastNode / NodeModel fields the plain ticks read or write) -------------
N_NT, N_TORQUE, N_TORQUE_NONE = 0, 1, 2
N_LAND_C, N_LAND_V, N_LAND = 3, 4, 5            # N_LAND: 0 none, 1 a word, 2 a dead tick's None
N_STARTED, N_BUSY, N_OVERRUNS = 6, 7, 8
N_DEF, N_DEF_TN, N_DEF_Q, N_DEF_V, N_DEF_A = 9, 10, 11, 12, 13      # the deferred Part B
N_QDES, N_VDES, N_ILO, N_IHI = 14, 15, 16, 17
N_ARMED, N_TRIPPED, N_PRIME, N_PRIME_DUE, N_PRIME_SET = 18, 19, 20, 21, 22
N_LAST_PACKET, N_DBASE = 23, 24
N_D0 = 25                                       # d_words: 25..28
N_TICK, N_MODE, N_TIMEOUT, N_TAU_MIN, N_TAU_MAX, N_RAMP = 29, 30, 31, 32, 33, 34
# a plain commit the kernel takes (:func:`node_plain`): its cycle (NEVER: none), then the
# pending Comm D's words and boundary (d_next, d_next_base) it puts in d_words and d_base
N_COMMIT_C, N_DN_BASE = 35, 36
N_DN0 = 37                                      # d_next: 37..40
N_SIZE = 41

# --- joint parameter row ---------------------------------------------------------------------
P_CT, P_CTH, P_KC, P_LAMC, P_LAM, P_IVS, P_IVLC, P_KJ = 0, 1, 2, 3, 4, 5, 6, 7
P_TH0, P_TH1, P_TH2, P_TH3, P_KP, P_KI, P_KD, P_ILO, P_IHI = 8, 9, 10, 11, 12, 13, 14, 15, 16
P_CYC = 17                                      # cycles of the three modes: 17..19
P_SH = 20                                       # rounding points: shifts then r, 6 slots each
PARAM_WORDS = ("cT", "cTh", "Kc", "lamc", "lam", "ivs", "ivlc", "kj", "th0", "th1", "th2",
               "th3", "kp", "ki", "kd", "ilo", "ihi")
#: The rounding points of hdl/node/joint_ref.py, in this order (6 slots each: 5 shifts, r).
POINTS = ("E", "QDR", "QDDR", "SG", "TAU_VDC", "TAU_PID", "I_CARRY", "I_LO", "I_HI", "TAU_D",
          "TS", "VD", "DQ", "QD")
(X_E, X_QDR, X_QDDR, X_SG, X_TAU_VDC, X_TAU_PID, X_I_CARRY, X_I_LO, X_I_HI, X_TAU_D, X_TS,
 X_VD, X_DQ, X_QD) = (P_SH + 6 * i for i in range(len(POINTS)))
P_SIZE = P_SH + 6 * len(POINTS)

# --- encoder state row (EncoderEvents fields) -------------------------------------------------
E_RAW, E_KNOWN, E_FILT0, E_FILT1, E_PAIR0, E_PAIR1, E_VI, E_NVIS = 0, 1, 2, 3, 4, 5, 6, 7
E_COUNT, E_ERRORS, E_VEL, E_ELAST, E_REFT, E_CREF, E_MOVED_C, E_MOVED_R = \
    8, 9, 10, 11, 12, 13, 14, 15
E_NPIPE, E_TAKEN, E_LAST_COUNT, E_LAST_VEL, E_LAST_C, E_ERR_LAST = 16, 17, 18, 19, 20, 21
E_MINWIN, E_STOP, E_NDUE, E_DUE_GAP, E_KV, E_FILTER, E_NPEND0, E_NPEND1 = \
    22, 23, 24, 25, 26, 27, 28, 29
E_SIZE = 30

WORD_MIN, WORD_MAX = -(1 << 23), (1 << 23) - 1
TIME_MAX = (1 << 23) - 1
FORCE_LSB = 2.0 ** _FORCE.lsb           # FORCE.decode(w) = ldexp(w, lsb): exact, as w · 2^lsb
NEVER = 1 << 62
AGE_MAX = _AGE_MAX
DC_MAX = _DC_MAX
VEL_LATENCY = _VEL_LATENCY
RECIP = np.array(RECIP_TABLE, dtype=np.int64)


# --- the joint engine (JointModel) ----------------------------------------------------------
def fx(P, x, v0, v1, v2, v3, v4):
    """One rounding point (``fx_point`` of joint_ref.py): summands aligned on the finest LSB,
    one rounding half up, saturation (slots ``x … x + 4`` the shifts, ``x + 5`` the rounding
    shift). Unused summands are 0."""
    r = P[x + 5]
    v = ((v0 << P[x]) + (v1 << P[x + 1]) + (v2 << P[x + 2]) + (v3 << P[x + 3])
         + (v4 << P[x + 4]) + _half(r)) >> r
    return WORD_MIN if v < WORD_MIN else WORD_MAX if v > WORD_MAX else v


def _half(r):
    return (1 << (r - 1)) if r else 0


def saturate(v):
    return WORD_MIN if v < WORD_MIN else WORD_MAX if v > WORD_MAX else v


def part_a(N, P, mode, q, qd, tau_d, ad0):
    """:meth:`JointModel.part_a`: the torque (and PID's integral update)."""
    q = saturate(q)
    vdes = N[N_VDES]
    e = fx(P, X_E, N[N_QDES], -q, 0, 0, 0)
    qdr = fx(P, X_QDR, vdes, P[P_LAMC] * e, 0, 0, 0)
    if mode == 0:
        qddr = fx(P, X_QDDR, ad0, P[P_LAM] * (vdes - qd), 0, 0, 0)
        sg = fx(P, X_SG, P[P_IVS] * vdes, P[P_IVLC] * e, 0, 0, 0)
        return fx(P, X_TAU_VDC, tau_d + P[P_TH3], P[P_TH0] * qddr, P[P_TH1] * qdr,
                  P[P_TH2] * sg, P[P_KJ] * (qdr - qd))
    if mode == 1:
        tau = fx(P, X_TAU_PID, tau_d, P[P_KP] * e, P[P_KI] * N[N_ILO], P[P_KI] * N[N_IHI],
                 P[P_KD] * (vdes - qd))
        pid_integral(N, P, q)
        return tau
    return fx(P, X_TAU_D, tau_d, 0, 0, 0, 0)


def pid_integral(N, P, q):
    """:meth:`JointModel.pid_integral`."""
    q = saturate(q)
    c = fx(P, X_I_CARRY, N[N_ILO], N[N_QDES], -q, 0, 0)
    N[N_ILO] = fx(P, X_I_LO, N[N_ILO], N[N_QDES], -q, -c, 0)
    ihi = fx(P, X_I_HI, N[N_IHI], c, 0, 0, 0)
    lo, hi = P[P_ILO], P[P_IHI]
    N[N_IHI] = min(max(ihi, lo), hi)


def part_b(N, P, tn, qd0, vd0, ad0):
    """:meth:`JointModel.part_b`: the reference for the next tick."""
    ts = fx(P, X_TS, tn * P[P_CT], 0, 0, 0, 0)
    tsh = fx(P, X_TS, tn * P[P_CTH], 0, 0, 0, 0)
    N[N_VDES] = fx(P, X_VD, vd0, ad0 * ts, 0, 0, 0)
    h = fx(P, X_VD, vd0, ad0 * tsh, 0, 0, 0)
    dq = fx(P, X_DQ, h * ts, 0, 0, 0, 0)
    N[N_QDES] = fx(P, X_QD, qd0, dq * P[P_KC], 0, 0, 0)


# --- the encoder interface (EncoderEvents) --------------------------------------------------
def velocity_word(num, den, kv):
    """:func:`hdl.node.encoder_ref.velocity_word` (with :func:`~.reciprocal`)."""
    den = max(1, min(den, AGE_MAX))
    p = 0
    while den >> (p + 1):
        p += 1
    m17 = (den << (25 - p)) >> 9
    y0 = RECIP[(m17 >> 8) & 0xFF]
    d = (1 << 17) - ((m17 * y0) >> 16)
    y1 = y0 + ((y0 * d) >> 17)
    s = p + 6
    return saturate(((num * y1) * kv + (1 << (s - 1))) >> s)


def _phase(a, b):
    return 2 * b + (a ^ b)              # (0,0) 0, (1,0) 1, (1,1) 2, (0,1) 3


def enc_feed_changes(E, pend, vis, start, n, cyc, cnt):
    """:meth:`EncoderEvents.feed_changes` (``start`` already checked by the caller); the
    changes as two arrays, cycles in the step and new counts."""
    _enc_feed(E, pend, vis, start, n, cyc, cnt, 0)


def _enc_feed(E, pend, vis, start, n, cyc, cnt, offset):
    """:func:`enc_feed_changes` with the changes' cycles ``cyc − offset`` (no new array)."""
    m = cyc.shape[0]
    if m:
        o = E[E_RAW]
        for j in range(m):
            n_ = cnt[j]
            lo = n_ if n_ < o else o
            line = 0 if (lo & 3) == 0 or (lo & 3) == 2 else 1
            k = E[E_NPEND0 + line]
            if k >= pend.shape[1]:
                raise RuntimeError("encoder kernel: pending-change buffer full")
            pend[line, k, 0] = start + (cyc[j] - offset)
            pend[line, k, 1] = (((n_ & 3) >> 1) ^ (n_ & 1)) if line == 0 else (n_ & 3) >> 1
            E[E_NPEND0 + line] = k + 1
            o = n_
        E[E_RAW] = o
    E[E_KNOWN] = start + n - 1
    if E[E_NPEND0] or E[E_NPEND1]:
        _enc_resolve(E, pend, vis)


def _enc_resolve(E, pend, vis):
    f = E[E_FILTER]
    known = E[E_KNOWN]
    cap = pend.shape[1]
    com = np.empty((2, cap, 2), dtype=np.int64)     # per line: (cycle, level) committed
    ncom = np.zeros(2, dtype=np.int64)
    for line in range(2):
        m = E[E_NPEND0 + line]
        keep = 0
        for j in range(m):
            t = pend[line, j, 0]
            level = pend[line, j, 1]
            has_next = j + 1 < m
            if not has_next and t + f - 1 > known:
                keep = j
                break
            keep = j + 1
            if level != E[E_FILT0 + line] and (not has_next or pend[line, j + 1, 0] - t >= f):
                E[E_FILT0 + line] = level
                com[line, ncom[line], 0] = t + f + 1
                com[line, ncom[line], 1] = level
                ncom[line] += 1
        for j in range(keep, m):
            pend[line, j - keep, 0] = pend[line, j, 0]
            pend[line, j - keep, 1] = pend[line, j, 1]
        E[E_NPEND0 + line] = m - keep
    # commits in (cycle, line) order, grouped by cycle
    i0 = 0
    i1 = 0
    while i0 < ncom[0] or i1 < ncom[1]:
        if i1 >= ncom[1] or (i0 < ncom[0] and com[0, i0, 0] <= com[1, i1, 0]):
            k = com[0, i0, 0]
        else:
            k = com[1, i1, 0]
        a, b = E[E_PAIR0], E[E_PAIR1]
        if i0 < ncom[0] and com[0, i0, 0] == k:
            a = com[0, i0, 1]
            i0 += 1
        if i1 < ncom[1] and com[1, i1, 0] == k:
            b = com[1, i1, 1]
            i1 += 1
        d = (_phase(a, b) - _phase(E[E_PAIR0], E[E_PAIR1])) % 4
        E[E_PAIR0] = a
        E[E_PAIR1] = b
        nv = E[E_NVIS]
        if nv >= vis.shape[0]:
            _enc_compact(E, vis)
            nv = E[E_NVIS]
            if nv >= vis.shape[0]:
                raise RuntimeError("encoder kernel: visible-step buffer full")
        vis[nv, 0] = k + 1
        vis[nv, 1] = 0 if d == 2 else (1 if d == 1 else -1)
        E[E_NVIS] = nv + 1


def _enc_compact(E, vis):
    vi = E[E_VI]
    nv = E[E_NVIS]
    for j in range(vi, nv):
        vis[j - vi, 0] = vis[j, 0]
        vis[j - vi, 1] = vis[j, 1]
    E[E_NVIS] = nv - vi
    E[E_VI] = 0


def enc_tick_sample(E, vis, pipe, due, c):
    """:meth:`EncoderEvents.tick_sample`; the result in ``E[E_LAST_COUNT]``, ``E[E_LAST_VEL]``."""
    if c == E[E_LAST_C]:
        return
    if E[E_NDUE]:
        _enc_flush(E, vis, pipe, due, c)
        if c == E[E_LAST_C]:
            return
    _enc_strobe(E, vis, pipe, c)


def enc_count_at(E, vis, c):
    """The count visible in cycle ``c``, without taking anything (``defer``'s count)."""
    i = E[E_VI]
    count = E[E_COUNT]
    nv = E[E_NVIS]
    while i < nv and vis[i, 0] <= c:
        count += vis[i, 1]
        i += 1
    return count


def enc_defer(E, vis, due, c):
    """:meth:`EncoderEvents.defer`."""
    nd = E[E_NDUE]
    if nd and c - due[nd - 1] < E[E_DUE_GAP]:
        E[E_DUE_GAP] = c - due[nd - 1]
    if nd >= due.shape[0]:
        raise RuntimeError("encoder kernel: deferred-strobe buffer full")
    due[nd] = c
    E[E_NDUE] = nd + 1
    return enc_count_at(E, vis, c)


def enc_defer_range(E, due, first, last, step):
    """:meth:`EncoderEvents.defer_range`."""
    nd = E[E_NDUE]
    gap = first - due[nd - 1] if nd else NEVER
    if last > first and step < gap:
        gap = step
    if gap < E[E_DUE_GAP]:
        E[E_DUE_GAP] = gap
    k = (last - first) // step + 1
    if nd + k > due.shape[0]:
        raise RuntimeError("encoder kernel: deferred-strobe buffer full")
    for j in range(k):
        due[nd + j] = first + j * step
    E[E_NDUE] = nd + k


def _enc_flush(E, vis, pipe, due, upto):
    """:meth:`EncoderEvents._flush`."""
    m = E[E_NDUE]
    p = E[E_TAKEN]
    last = due[m - 1]
    vi = E[E_VI]
    nv = E[E_NVIS]
    if p == E[E_LAST_C] and E[E_DUE_GAP] >= VEL_LATENCY and \
            due[0] - p >= VEL_LATENCY and upto - last >= VEL_LATENCY and \
            last - E[E_REFT] <= AGE_MAX and last - E[E_ELAST] <= AGE_MAX and \
            (vi >= nv or upto < vis[vi, 0]):
        E[E_NDUE] = 0
        E[E_DUE_GAP] = NEVER
        _enc_fold(E, pipe, due[0], last)
        return
    E[E_NDUE] = 0
    E[E_DUE_GAP] = NEVER
    i = 0
    while i < m:
        p = E[E_TAKEN]
        if p == E[E_LAST_C]:
            vi = E[E_VI]
            nxt = vis[vi, 0] if vi < E[E_NVIS] else NEVER
            g = i
            prev = p
            while g < m and due[g] < nxt and due[g] - prev >= VEL_LATENCY:
                prev = due[g]
                g += 1
            if g > i and prev - E[E_REFT] <= AGE_MAX and prev - E[E_ELAST] <= AGE_MAX:
                if g == m and upto < nxt and upto - prev >= VEL_LATENCY:
                    _enc_fold(E, pipe, due[i], prev)
                    return
                if g - i >= 2:
                    _enc_fold(E, pipe, due[i], due[g - 2])
                    i = g - 1
                    continue
        _enc_strobe(E, vis, pipe, due[i])
        i += 1


def _enc_fold(E, pipe, first, last):
    """:meth:`EncoderEvents._fold`."""
    _enc_apply_pipe(E, pipe, first)
    if last - E[E_ELAST] >= E[E_STOP]:
        E[E_VEL] = 0
    else:
        dc = E[E_COUNT] - E[E_CREF]
        if dc > DC_MAX:
            dc = DC_MAX
        elif dc < -DC_MAX - 1:
            dc = -DC_MAX - 1
        _enc_clip(E, abs(dc) + 1, last - E[E_REFT])
    E[E_TAKEN] = last
    E[E_LAST_C] = last
    E[E_LAST_COUNT] = E[E_COUNT]
    E[E_LAST_VEL] = E[E_VEL]


def _enc_apply_pipe(E, pipe, c):
    """:meth:`EncoderEvents._apply_pipe`."""
    n = E[E_NPIPE]
    j = 0
    while j < n and pipe[j, 0] <= c:
        case = pipe[j, 1]
        if case == 0:
            E[E_VEL] = 0
        elif case == 1:
            E[E_VEL] = velocity_word(pipe[j, 2], pipe[j, 3], E[E_KV])
        else:
            _enc_clip(E, pipe[j, 2], pipe[j, 3])
        j += 1
    if j:
        for i in range(j, n):
            for f in range(4):
                pipe[i - j, f] = pipe[i, f]
        E[E_NPIPE] = n - j


def _enc_clip(E, num, den):
    """:meth:`EncoderEvents._clip`."""
    vel = E[E_VEL]
    mag = abs(vel)
    kv_scale = float(E[E_KV]) * 2048.0
    if mag >= WORD_MAX or mag > float(num) * kv_scale / float(den or 1) * 0.999 - 2:
        v = velocity_word(num, den, E[E_KV])
        if mag > v:
            E[E_VEL] = v if vel > 0 else -v


def enc_decode(E, vis, upto):
    """:meth:`EncoderEvents._decode`."""
    vi = E[E_VI]
    nv = E[E_NVIS]
    while vi < nv and vis[vi, 0] <= upto:
        t = vis[vi, 0]
        st = vis[vi, 1]
        vi += 1
        if st:
            E[E_COUNT] += st
            E[E_ELAST] = t
        else:
            E[E_ERRORS] = min(E[E_ERRORS] + 1, 0xFFFF)
    E[E_VI] = vi
    if vi > 64:
        _enc_compact(E, vis)


def _enc_strobe(E, vis, pipe, c):
    """:meth:`EncoderEvents._strobe` (its result in ``E[E_LAST_COUNT]``, ``E[E_LAST_VEL]``)."""
    if E[E_VI] < E[E_NVIS] and vis[E[E_VI], 0] <= c:
        enc_decode(E, vis, c)
    if E[E_NPIPE] and pipe[0, 0] <= c:
        _enc_apply_pipe(E, pipe, c)
    count = E[E_COUNT]
    E[E_LAST_COUNT] = count
    E[E_LAST_VEL] = E[E_VEL]
    E[E_LAST_C] = c
    E[E_ERR_LAST] = E[E_ERRORS]
    if c != E[E_TAKEN] + 1:
        E[E_TAKEN] = c
        age_edge = min(c - E[E_ELAST], AGE_MAX)
        age_ref = min(c - E[E_REFT], AGE_MAX)
        dc = count - E[E_CREF]
        if dc > DC_MAX:
            dc = DC_MAX
        elif dc < -DC_MAX - 1:
            dc = -DC_MAX - 1
        window = age_ref - age_edge
        due = c + VEL_LATENCY
        n = E[E_NPIPE]
        if n >= pipe.shape[0]:
            raise RuntimeError("encoder kernel: velocity pipeline buffer full")
        pipe[n, 0] = due
        if dc != 0 and window >= E[E_MINWIN]:
            pipe[n, 1] = 1
            pipe[n, 2] = dc
            pipe[n, 3] = window
            E[E_CREF] = count
            E[E_MOVED_C] = c
            E[E_MOVED_R] = E[E_REFT]
            E[E_REFT] = c + 2 - min(age_edge + 2, AGE_MAX)
        elif age_edge >= E[E_STOP]:
            pipe[n, 1] = 0
            pipe[n, 2] = 0
            pipe[n, 3] = 1
        else:
            pipe[n, 1] = 2
            pipe[n, 2] = abs(dc) + 1
            pipe[n, 3] = age_ref
        E[E_NPIPE] = n + 1


def enc_preset(E, vis, pipe, due, c, value):
    """:meth:`EncoderEvents.preset` (``value`` already wrapped to 32 bits)."""
    if E[E_NDUE]:
        _enc_flush(E, vis, pipe, due, c)
    if E[E_VI] < E[E_NVIS] and vis[E[E_VI], 0] <= c + 1:
        enc_decode(E, vis, c + 1)
    if E[E_MOVED_C] == c:
        E[E_REFT] = E[E_MOVED_R]
    E[E_COUNT] = value
    E[E_CREF] = value


# --- the node's plain ticks (FastNode, lazy) -------------------------------------------------
def _land(N, now):
    if N[N_LAND] and now >= N[N_LAND_C]:
        if N[N_LAND] == 1:
            N[N_TORQUE] = N[N_LAND_V]
            N[N_TORQUE_NONE] = 0
        else:
            N[N_TORQUE_NONE] = 1
        N[N_LAND] = 0


def _watch(N, now):
    """:meth:`NodeModel._watch`."""
    _land(N, now)
    if N[N_ARMED] and not N[N_TRIPPED]:
        trip = N[N_LAST_PACKET] + 2 + N[N_TIMEOUT]
        if now >= trip:
            N[N_TRIPPED] = 1
            N[N_PRIME_DUE] = trip + 1
            N[N_PRIME_SET] = 1
    if N[N_PRIME_SET] and now >= N[N_PRIME_DUE]:
        N[N_PRIME] = 1
        N[N_PRIME_SET] = 0


def _ramp(N):
    """:meth:`NodeModel._ramp` (never on a dead tick's unobserved torque: a tripped node has
    no dead ticks)."""
    ramp = N[N_RAMP]
    t = N[N_TORQUE]
    N[N_TORQUE] = 0 if abs(t) <= ramp else t - ramp if t > 0 else t + ramp


def _tick_begin(N, now):
    """:meth:`FastNode._tick_begin` (not ramped: the boundary's tick is the event loop's)."""
    _land(N, now)
    if (N[N_ARMED] and not N[N_TRIPPED] and now >= N[N_LAST_PACKET] + 2 + N[N_TIMEOUT]) \
            or N[N_PRIME_SET]:
        _watch(N, now)
    tick = N[N_TICK]
    N[N_NT] = now + tick
    if N[N_ARMED] and N[N_TRIPPED]:
        _ramp(N)
    return tick


def _tick_end(N, P, now, mode, tau, dead):
    """:meth:`FastNode._tick_end` (``dead``: the torque is a dead tick's None)."""
    done = now + P[P_CYC + mode]
    N[N_STARTED] = now
    N[N_BUSY] = done + 1
    if not N[N_ARMED]:
        N[N_LAND_C] = done + 1
        N[N_LAND_V] = 0
        N[N_LAND] = 1
    elif not (N[N_TRIPPED] or done >= N[N_LAST_PACKET] + 2 + N[N_TIMEOUT]):
        N[N_LAND_C] = done + 1
        if dead:
            N[N_LAND] = 2
        else:
            lo, hi = N[N_TAU_MIN], N[N_TAU_MAX]
            N[N_LAND_V] = lo if tau < lo else hi if tau > hi else tau
            N[N_LAND] = 1


def materialize(N, P):
    """:meth:`FastNode._materialize`."""
    if N[N_DEF]:
        N[N_DEF] = 0
        part_b(N, P, N[N_DEF_TN], N[N_DEF_Q], N[N_DEF_V], N[N_DEF_A])


def _defer_b(N, tn):
    N[N_DEF] = 1
    N[N_DEF_TN] = tn
    N[N_DEF_Q] = N[N_D0 + 1]
    N[N_DEF_V] = N[N_D0 + 2]
    N[N_DEF_A] = N[N_D0 + 3]


def _dead_tick(N, P, E, vis, due, now, tt):
    """:meth:`FastNode._dead_tick`."""
    tick = _tick_begin(N, now)
    count = enc_defer(E, vis, due, now)
    if now < N[N_BUSY]:
        N[N_OVERRUNS] = min(N[N_OVERRUNS] + 1, 0xFFFF)
        return
    mode = N[N_MODE]
    tn = min(tt + tick, TIME_MAX)
    if mode == 1:
        materialize(N, P)
        pid_integral(N, P, count)
        part_b(N, P, tn, N[N_D0 + 1], N[N_D0 + 2], N[N_D0 + 3])
    else:
        _defer_b(N, tn)
    _tick_end(N, P, now, mode, 0, True)


def _fast_tick(N, P, E, vis, pipe, due, now, tt):
    """:meth:`FastNode._fast_tick` (lazy: Part B deferred)."""
    tick = _tick_begin(N, now)
    enc_tick_sample(E, vis, pipe, due, now)
    if now < N[N_BUSY]:
        N[N_OVERRUNS] = min(N[N_OVERRUNS] + 1, 0xFFFF)
        return
    mode = N[N_MODE]
    tn = min(tt + tick, TIME_MAX)
    materialize(N, P)
    tau = part_a(N, P, mode, E[E_LAST_COUNT], E[E_LAST_VEL], N[N_D0], N[N_D0 + 3])
    _defer_b(N, tn)
    _tick_end(N, P, now, mode, tau, False)


def _dead_run(N, P, E, vis, due, first, k, step, cyc):
    """:meth:`FastNode._dead_run`."""
    last = first + (k - 1) * step
    if N[N_LAND]:
        if N[N_LAND] == 1:
            N[N_TORQUE] = N[N_LAND_V]
            N[N_TORQUE_NONE] = 0
        else:
            N[N_TORQUE_NONE] = 1
    armed = N[N_ARMED]
    if k >= 2:
        N[N_TORQUE_NONE] = 1 if armed else 0
        if not armed:
            N[N_TORQUE] = 0
    N[N_LAND_C] = last + cyc + 1
    N[N_LAND] = 2 if armed else 1
    N[N_LAND_V] = 0
    N[N_NT] = last + step
    N[N_STARTED] = last
    N[N_BUSY] = last + cyc + 1
    lb = N[N_DBASE]
    if N[N_MODE] != 1:
        enc_defer_range(E, due, first, last, step)
        N[N_DEF] = 1
        N[N_DEF_TN] = min(last - lb + step, TIME_MAX)
        N[N_DEF_Q] = N[N_D0 + 1]
        N[N_DEF_V] = N[N_D0 + 2]
        N[N_DEF_A] = N[N_D0 + 3]
        return
    materialize(N, P)
    qd0, vd0, ad0 = N[N_D0 + 1], N[N_D0 + 2], N[N_D0 + 3]
    i = E[E_VI]
    nv = E[E_NVIS]
    count = E[E_COUNT]
    for t in range(first, last + 1, step):
        while i < nv and vis[i, 0] <= t:
            count += vis[i, 1]
            i += 1
        pid_integral(N, P, count)
        part_b(N, P, min(t - lb + step, TIME_MAX), qd0, vd0, ad0)
    enc_defer_range(E, due, first, last, step)


def node_plain(N, P, E, vis, pipe, due, lim):
    """The plain ticks before ``lim`` (:func:`node_ticks`), and the commit of ``N[N_COMMIT_C]``
    if it lies before ``lim``: as :meth:`KernelNode.run <cosim.model_kernel.KernelNode.run>`
    takes a plain commit point ``c`` (:meth:`~cosim.model_kernel.KernelNode._commit_in_row`),
    the ticks before ``c``, the tick in cycle ``c``, then the pending Comm D's words into
    ``d_words`` and ``d_base`` (:meth:`NodeModel._take_d <hdl.node.core_ref.NodeModel._take_d>`
    with the generator's references not selected). Only such a commit is armed (a fast run's,
    :meth:`cosim.model.ModelBackend._fast_begin`), and the object's side follows the run
    (:meth:`~cosim.model_kernel.KernelNode.end_commit`)."""
    N = borrow(N)
    P = borrow(P)
    E = borrow(E)
    vis = borrow(vis)
    pipe = borrow(pipe)
    due = borrow(due)
    c = N[N_COMMIT_C]
    if c < lim:
        node_ticks(N, P, E, vis, pipe, due, c)
        node_ticks(N, P, E, vis, pipe, due, c + 1)
        N[N_COMMIT_C] = NEVER
        N[N_DBASE] = N[N_DN_BASE]
        for j in range(4):
            N[N_D0 + j] = N[N_DN0 + j]
    node_ticks(N, P, E, vis, pipe, due, lim)


def node_ticks(N, P, E, vis, pipe, due, lim):
    """The lazy branch of :meth:`FastNode.run`'s loop for the plain ticks before ``lim``."""
    step = N[N_TICK]
    cyc = P[P_CYC + N[N_MODE]]
    safe = step > cyc and (not N[N_ARMED] or N[N_TRIPPED])
    trip = N[N_LAST_PACKET] + 2 + N[N_TIMEOUT] - step - cyc
    land = lim - step - cyc - 1
    if trip - 1 < land:
        land = trip - 1
    while N[N_NT] < lim:
        nt = N[N_NT]
        if nt + step < lim and step > cyc and (safe or nt <= land):
            if not N[N_TRIPPED] and not N[N_PRIME_SET] and \
                    (N[N_LAND] == 0 or N[N_LAND_C] <= nt):
                last = lim - step - 1 if safe else land
                _dead_run(N, P, E, vis, due, nt, (last - nt) // step + 1, step, cyc)
            else:
                _dead_tick(N, P, E, vis, due, nt, nt - N[N_DBASE])
        else:
            _fast_tick(N, P, E, vis, pipe, due, nt, nt - N[N_DBASE])


def torque_at(N, now):
    """:meth:`FastNode.torque_at`."""
    _land(N, now)
    if (N[N_ARMED] and not N[N_TRIPPED] and now >= N[N_LAST_PACKET] + 2 + N[N_TIMEOUT]) \
            or N[N_PRIME_SET]:
        _watch(N, now)
    return N[N_TORQUE]


def any_trip(NS, c):
    """Whether a node of rows ``NS`` has tripped, or armed sees its watchdog's trip by cycle
    ``c`` (:meth:`ModelBackend.brake <cosim.model.ModelBackend.brake>`'s test of a node whose
    state the kernel holds, for every node at once)."""
    for k in range(NS.shape[0]):
        if NS[k, N_TRIPPED] or (NS[k, N_ARMED] and
                                c >= NS[k, N_LAST_PACKET] + 2 + NS[k, N_TIMEOUT]):
            return True
    return False


def _count_at(q0, v0, half_acc, k, step, m):
    """``_count_changes``' ``count(m)``: the count sampled in cycle ``m`` of the step."""
    s = (m + 1) * step
    return math.floor((q0 + s * (v0 + half_acc * s)) * k)


def _bisect(q0, v0, half_acc, k, step, lo, hi, c_before, c_hi, cyc, cnt, e, stack):
    """``_count_changes``' recursive ``bisect`` with an explicit stack (same samples, same
    order): the changes of the monotonic samples ``lo … hi`` into ``cyc``/``cnt`` from
    ``e``; returns the new length."""
    top = 0
    stack[0, 0], stack[0, 1], stack[0, 2], stack[0, 3] = lo, hi, c_before, c_hi
    top = 1
    while top:
        top -= 1
        lo, hi, c_before, c_hi = stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3]
        while c_before != c_hi:
            if lo == hi:
                cyc[e] = hi
                cnt[e] = c_hi
                e += 1
                break
            mid = (lo + hi) // 2
            c_mid = _count_at(q0, v0, half_acc, k, step, mid)
            # the call bisect(lo, mid, c_before, c_mid) first, then this frame goes on at
            # (mid + 1, hi, c_mid, c_hi): push the rest, run the call
            stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3] = mid + 1, hi, c_mid, c_hi
            top += 1
            hi, c_hi = mid, c_mid
    return e


def step_changes(M, K, dt, cycles, CHC, CHN, NCH):
    """:func:`models.encoder.count_changes_lists` of one plant step, every joint: the changes'
    cycles into ``CHC[j]``, their counts into ``CHN[j]``, their number into ``NCH[j]``.
    ``M`` rows: the step's start angles, start velocities, accelerations, end angles; ``K``:
    counts/rad. The same float operations in the same order as the reference, the same samples
    (bisection where a joint has few changes, every cycle where it has many). Returns 0, or
    ``j + 1`` if joint ``j`` moved more than one count in a cycle (the caller then lets the
    reference raise its :class:`~models.encoder.EncoderOverspeed`)."""
    M, K, CHC, CHN, NCH = borrow(M), borrow(K), borrow(CHC), borrow(CHN), borrow(NCH)
    scratch = np.empty(SCRATCH, dtype=np.int64)
    return _step_changes(M, 0, 1, 2, 3, K, dt, cycles, CHC, CHN, NCH, scratch)


#: :func:`_step_changes`' scratch words: the bisection's stack (64 × 4), the explicit samples (5)
SCRATCH = 64 * 4 + 5


def _step_changes(A, r0, r1, r2, r3, K, dt, cycles, CHC, CHN, NCH, scratch):
    """:func:`step_changes` on rows ``r0 … r3`` of ``A`` (the start angles, start velocities,
    accelerations, end angles), its stack and sample list in ``scratch`` (``SCRATCH`` words:
    the fast path's are in the blob, :func:`blob_views`, so a step allocates nothing)."""
    n = A.shape[1]
    step = dt / cycles
    cap = CHC.shape[1]
    stack = scratch[:256].reshape((64, 4))
    explicit = scratch[256:261]
    for j in range(n):
        NCH[j] = 0
        q0, v0, acc, q1, k = A[r0, j], A[r1, j], A[r2, j], A[r3, j], K[j]
        c0 = math.floor(q0 * k)
        c1 = math.floor(q1 * k)
        turning = acc != 0.0 and 0.0 < -v0 / acc < dt
        if c0 == c1 and not turning:
            continue
        cyc, cnt = CHC[j], CHN[j]
        e = 0
        if abs(c1 - c0) > _FEW_CHANGES or (turning and abs(v0) * dt * k > 1.0):
            # cycle_counts_sampled: q0 + s · (v0 + 0.5 · acc · s), the last sample q1
            half_acc = 0.5 * acc
            prev = c0
            for m in range(cycles):
                if m == cycles - 1:
                    c = c1
                else:
                    s = (m + 1) * step
                    c = math.floor((q0 + s * (v0 + half_acc * s)) * k)
                if c != prev:
                    if c - prev > 1 or prev - c > 1:
                        return j + 1
                    if e >= cap:
                        raise RuntimeError("model kernel: count-change buffer full")
                    cyc[e] = m
                    cnt[e] = c
                    e += 1
                    prev = c
            NCH[j] = e
            continue
        half_acc = 0.5 * acc
        ne = 1
        explicit[0] = cycles - 1
        if turning:
            m_turn = int(-v0 / acc / step) - 1
            for m in range(m_turn - 1, m_turn + 3):
                if 0 <= m < cycles and m != cycles - 1:
                    explicit[ne] = m
                    ne += 1
        explicit[:ne].sort()
        prev, lo = c0, 0
        for i in range(ne):
            x = explicit[i]
            if lo <= x - 1:
                c_hi = _count_at(q0, v0, half_acc, k, step, x - 1)
                e = _bisect(q0, v0, half_acc, k, step, lo, x - 1, prev, c_hi, cyc, cnt, e,
                            stack)
                prev = c_hi
            c_x = c1 if x == cycles - 1 else _count_at(q0, v0, half_acc, k, step, x)
            if c_x != prev:
                cyc[e] = x
                cnt[e] = c_x
                e += 1
            prev, lo = c_x, x + 1
        prev = c0
        for i in range(e):
            if cnt[i] - prev > 1 or prev - cnt[i] > 1:
                return j + 1
            prev = cnt[i]
        NCH[j] = e
    return 0


def plain_step(NS, PS, ES, VIS, PIPE, DUE, PEND, plain, start, n, offset, CHC, CHN, NCH,
               CUR, tau_out):
    """One piece of a plant step for every node: the step's count changes (:func:`step_changes`)
    in cycles ``offset … offset + n − 1`` into each encoder (:meth:`EncoderEvents.feed_changes`;
    ``CUR[k]``, the first change not fed yet, moves on), then, for the nodes marked ``plain``
    (no event but plain ticks before ``start + n − 1``), :meth:`FastNode.run` to ``start + n −
    1`` and the torque output in that cycle into ``tau_out`` (N·m: the FORCE word times 2^−13,
    as ``FORCE.decode``). Returns True if a plain node's torque there is a dead tick's, which
    nothing may observe (a bug: the caller raises)."""
    NS = borrow(NS)
    PS = borrow(PS)
    ES = borrow(ES)
    VIS = borrow(VIS)
    PIPE = borrow(PIPE)
    DUE = borrow(DUE)
    PEND = borrow(PEND)
    plain = borrow(plain)
    CHC = borrow(CHC)
    CHN = borrow(CHN)
    NCH = borrow(NCH)
    CUR = borrow(CUR)
    tau_out = borrow(tau_out)
    return _plain_step(NS, PS, ES, VIS, PIPE, DUE, PEND, plain, False, start, n, offset, CHC,
                       CHN, NCH, CUR, tau_out)


def _plain_step(NS, PS, ES, VIS, PIPE, DUE, PEND, plain, every, start, n, offset, CHC, CHN,
                NCH, CUR, tau_out):
    """:func:`plain_step`; ``every``: every node is plain (``plain`` is not read)."""
    end = start + n
    bad = False
    for k in range(NS.shape[0]):
        j0 = CUR[k]
        m = NCH[k]
        while j0 < m and CHC[k, j0] < offset:
            j0 += 1
        j = j0
        while j < m and CHC[k, j] < offset + n:
            j += 1
        CUR[k] = j
        _enc_feed(ES[k], PEND[k], VIS[k], start, n, CHC[k, j0:j], CHN[k, j0:j], offset)
        if every or plain[k]:
            node_plain(NS[k], PS[k], ES[k], VIS[k], PIPE[k], DUE[k], end - 1)
            tau_out[k] = float(torque_at(NS[k], end - 1)) * FORCE_LSB
            if NS[k, N_TORQUE_NONE]:
                bad = True
    return bad


# --- the VDC unit's per-link computation (VdcModel._link, hdl/node/vdc_ref.py) --------------
# Exactness: every word is 24 bits; a regressor entry is a sum of at most three summands
# (< 2^25.6), a product with a THETA, GAIN or error word < 2^48.6, a row's or column's sum of
# them < 2^52.3, and the widest rounding point (the force row: the first group's sum shifted 8
# bits left) < 2^61 (tests/test_model_kernel.py checks the bounds on the tables and runs
# saturated words against the reference).


def _vdc_point(fmt, *lsbs):
    """``fx_point(fmt, *lsbs)``'s left shifts and right shift (at import time, in Python)."""
    low = min(*lsbs, fmt.lsb)
    return tuple(lsb - low for lsb in lsbs) + (fmt.lsb - low,)


def _vdc_tables():
    from mrm_cosim.protocol.fixed import ACC, FORCE, GAIN, RHOT, SIG, THETA, VEL
    from mrm_cosim.protocol.fixed import theta_group
    from mrm_cosim.protocol.vdc_program import Y_TABLE

    def index(kind, idx):
        return {"a": 0, "P": 3 + 3 * (idx // 10) + idx % 10, "dw": 12}[kind] + \
            (0 if kind == "P" else idx)

    terms = [(r, c, sgn, index(kind, idx)) for (r, c), summands in sorted(Y_TABLE.items())
             for sgn, kind, idx in summands]
    pts = {
        "A": _vdc_point(ACC, ACC.lsb, 2 * VEL.lsb),
        "P": _vdc_point(ACC, 2 * VEL.lsb),
        "VEL": _vdc_point(VEL, VEL.lsb),
        "F": _vdc_point(FORCE, *(ACC.lsb + fmt.lsb for fmt in THETA), GAIN.lsb + VEL.lsb),
        "SIG": _vdc_point(SIG, ACC.lsb + VEL.lsb),
    }
    delta = [_vdc_point(THETA[g], RHOT[g].lsb + SIG.lsb) for g in range(3)]
    theta = [_vdc_point(THETA[g], THETA[g].lsb) for g in range(3)]
    return (np.array(terms, dtype=np.int64),
            np.array([theta_group(j) for j in range(13)], dtype=np.int64),
            np.array(pts["A"], dtype=np.int64), np.array(pts["P"], dtype=np.int64),
            np.array(pts["VEL"], dtype=np.int64), np.array(pts["F"], dtype=np.int64),
            np.array(pts["SIG"], dtype=np.int64), np.array(delta, dtype=np.int64),
            np.array(theta, dtype=np.int64))


(VDC_TERMS, VDC_GROUP, VDC_PT_A, VDC_PT_P, VDC_PT_VEL, VDC_PT_F, VDC_PT_SIG, VDC_PT_DELTA,
 VDC_PT_THETA) = _vdc_tables()


def _vdc_step_points():
    """The rounding points of :meth:`VdcModel.step <hdl.node.vdc_ref.VdcModel.step>` around
    its links (``_ROT``, ``_VEL``, ``_ACC``, ``_DIFF``, ``_DA`` of hdl/node/vdc_ref.py)."""
    from mrm_cosim.protocol.fixed import ACC, INVT, TRIG, VEL

    return tuple(np.array(_vdc_point(*a), dtype=np.int64) for a in (
        (VEL, TRIG.lsb + VEL.lsb), (ACC, TRIG.lsb + ACC.lsb), (VEL, VEL.lsb), (ACC, ACC.lsb),
        (ACC, VEL.lsb + INVT.lsb), (ACC, TRIG.lsb + ACC.lsb, 2 * VEL.lsb)))


VDC_PT_ROTV, VDC_PT_ROTA, VDC_PT_SUMV, VDC_PT_SUMA, VDC_PT_DIFF, VDC_PT_DA = _vdc_step_points()
#: :func:`vdc_step`'s packed input (offsets into ``X``) and output (into ``out``).
(VX_TH, VX_K, VX_RHO, VX_LO, VX_HI, VX_INVT, VX_PREV_C, VX_PREV_QDR, VX_PRIMED, VX_QDR, VX_VC,
 VX_VRC, VX_QD, VX_COS, VX_SIN, VX_G, VX_SIZE) = (0, 26, 38, 64, 90, 116, 117, 123, 124, 125,
                                                  126, 132, 138, 139, 140, 141, 144)
VO_F, VO_TH, VO_SIZE = 0, 12, 38
WORD_LO, WORD_HI = _WORD_MIN, _WORD_MAX


def _vround(v, r):
    """A rounding point's end: half up by ``r`` bits, then the 24-bit saturation."""
    if r:
        v = (v + (1 << (r - 1))) >> r
    return WORD_LO if v < WORD_LO else WORD_HI if v > WORD_HI else v


def vdc_link(th, K, rho, lower, upper, V, Vr, dV, g, F, new):
    """:meth:`VdcModel._link <hdl.node.vdc_ref.VdcModel._link>` of one link: its parameter
    words ``th`` (13), the gains ``K`` (6), ``rho`` (13), the bounds ``lower``/``upper`` (13)
    and the inputs ``V``, ``Vr``, ``dV`` (6), ``g`` (3); the force words into ``F`` (6), the
    adapted estimates into ``new`` (13)."""
    w = np.empty(15, dtype=np.int64)
    pa, pp, pv, pf, ps = VDC_PT_A, VDC_PT_P, VDC_PT_VEL, VDC_PT_F, VDC_PT_SIG
    for k in range(3):
        w[k] = _vround(((dV[k] + g[k]) << pa[0])
                       + ((V[3 + (k + 1) % 3] * Vr[(k + 2) % 3]
                           - V[3 + (k + 2) % 3] * Vr[(k + 1) % 3]) << pa[1]), pa[2])
    for m in range(3):
        for n in range(3):
            w[3 + 3 * m + n] = _vround((V[3 + m] * Vr[3 + n]) << pp[0], pp[1])
    for k in range(3):
        w[12 + k] = dV[3 + k]
    e = np.empty(6, dtype=np.int64)
    for k in range(6):
        e[k] = _vround((Vr[k] - V[k]) << pv[0], pv[1])
    y = np.zeros((6, 13), dtype=np.int64)      # absent entries stay 0 and add nothing
    for t in range(VDC_TERMS.shape[0]):
        if VDC_TERMS[t, 2] > 0:
            y[VDC_TERMS[t, 0], VDC_TERMS[t, 1]] += w[VDC_TERMS[t, 3]]
        else:
            y[VDC_TERMS[t, 0], VDC_TERMS[t, 1]] -= w[VDC_TERMS[t, 3]]
    sums = np.zeros(3, dtype=np.int64)
    for row in range(6):
        sums[:] = 0
        for col in range(13):
            sums[VDC_GROUP[col]] += y[row, col] * th[col]
        F[row] = _vround((sums[0] << pf[0]) + (sums[1] << pf[1]) + (sums[2] << pf[2])
                         + ((K[row] * e[row]) << pf[3]), pf[4])
    for j in range(13):
        v = 0
        for row in range(6):
            v += y[row, j] * e[row]
        gr = VDC_GROUP[j]
        sig = _vround(v << ps[0], ps[1])
        d = _vround((rho[j] * sig) << VDC_PT_DELTA[gr, 0], VDC_PT_DELTA[gr, 1])
        t = _vround((th[j] + d) << VDC_PT_THETA[gr, 0], VDC_PT_THETA[gr, 1])
        new[j] = min(max(t, lower[j]), upper[j])


def vdc_link_packed(X, out):
    """:func:`vdc_link` on its inputs packed into one array ``X`` (79 words: ``th``, ``K``,
    ``rho``, ``lower``, ``upper``, ``V``, ``Vr``, ``dV``, ``g``, in that order), the force words
    then the adapted estimates into ``out`` (19): one array to build and one to read back from
    Python instead of eleven."""
    vdc_link(X[0:13], X[13:19], X[19:32], X[32:45], X[45:58], X[58:64], X[64:70], X[70:76],
             X[76:79], out[0:6], out[6:19])


def _vp1(v0, pt):
    """A one-summand rounding point (``fx_point`` with one LSB)."""
    return _vround(v0 << pt[0], pt[1])


def _vp2(v0, v1, pt):
    """A two-summand rounding point."""
    return _vround((v0 << pt[0]) + (v1 << pt[1]), pt[2])


def _vdc_link_a(c, s, V, qd, out):
    """``_link_a`` of vdc_ref.py: ``Rz(q)ᵀ`` per block plus ``z q̇``, VEL words."""
    out[0] = _vp1(c * V[0] + s * V[1], VDC_PT_ROTV)
    out[1] = _vp1(c * V[1] - s * V[0], VDC_PT_ROTV)
    out[2] = V[2]
    out[3] = _vp1(c * V[3] + s * V[4], VDC_PT_ROTV)
    out[4] = _vp1(c * V[4] - s * V[3], VDC_PT_ROTV)
    out[5] = _vp1(V[5] + qd, VDC_PT_SUMV)


def vdc_step(X, out):
    """:meth:`VdcModel.step <hdl.node.vdc_ref.VdcModel.step>` on its state and inputs packed
    into ``X`` (the ``VX_*`` offsets: both links' estimates, gains, ρT, bounds, ``inv_T``, the
    previous {C} velocity and ``q̇_r``, primed, then the run's inputs): the forces of Link a and
    Link b into ``out[VO_F:]`` (12), the adapted estimates of both into ``out[VO_TH:]`` (26).
    The caller keeps ``prev_C``, ``prev_qd_r`` and ``primed`` as the reference sets them."""
    X, out = borrow(X), borrow(out)
    c = X[VX_COS]
    s = X[VX_SIN]
    qd = X[VX_QD]
    qdr = X[VX_QDR]
    VC = X[VX_VC:VX_VC + 6]
    VrC = X[VX_VRC:VX_VRC + 6]
    gC = X[VX_G:VX_G + 3]
    if X[VX_PRIMED]:
        prevC = X[VX_PREV_C:VX_PREV_C + 6]
        pqdr = X[VX_PREV_QDR]
    else:
        prevC = VrC
        pqdr = qdr
    VA = np.empty(6, dtype=np.int64)
    VrA = np.empty(6, dtype=np.int64)
    _vdc_link_a(c, s, VC, qd, VA)
    _vdc_link_a(c, s, VrC, qdr, VrA)
    gA = np.empty(3, dtype=np.int64)
    gA[0] = _vp1(c * gC[0] + s * gC[1], VDC_PT_ROTA)
    gA[1] = _vp1(c * gC[1] - s * gC[0], VDC_PT_ROTA)
    gA[2] = gC[2]
    inv_t = X[VX_INVT]
    dC = np.empty(6, dtype=np.int64)
    for k in range(6):
        dC[k] = _vp1(inv_t * (VrC[k] - prevC[k]), VDC_PT_DIFF)
    qddr = _vp1(inv_t * (qdr - pqdr), VDC_PT_DIFF)
    dA = np.zeros(6, dtype=np.int64)
    for base in (0, 3):
        d0 = dC[base]
        d1 = dC[base + 1]
        dA[base] = _vp2(c * d0 + s * d1, qd * VrA[base + 1], VDC_PT_DA)
        dA[base + 1] = _vp2(c * d1 - s * d0, -qd * VrA[base], VDC_PT_DA)
    dA[2] = dC[2]
    dA[5] = _vp1(dC[5] + qddr, VDC_PT_SUMA)
    vdc_link(X[VX_TH:VX_TH + 13], X[VX_K:VX_K + 6], X[VX_RHO:VX_RHO + 13],
             X[VX_LO:VX_LO + 13], X[VX_HI:VX_HI + 13], VA, VrA, dA, gA,
             out[VO_F:VO_F + 6], out[VO_TH:VO_TH + 13])
    vdc_link(X[VX_TH + 13:VX_TH + 26], X[VX_K + 6:VX_K + 12], X[VX_RHO + 13:VX_RHO + 26],
             X[VX_LO + 13:VX_LO + 26], X[VX_HI + 13:VX_HI + 26], VC, VrC, dC, gC,
             out[VO_F + 6:VO_F + 12], out[VO_TH + 13:VO_TH + 26])


# --- the whole plain plant step in one call (ModelBackend's fast path) -----------------------
#: Buffer sizes per node (changes of one plant step are ≤ 500 per line; the queues empty at
#: every observed tick, at least once a plant step). Overflow raises.
PEND_CAP, VIS_CAP, PIPE_CAP, DUE_CAP = 2048, 2048, 64, 4096
#: Count changes of one joint in one plant step (at most one per cycle: 500 at 10 µs).
CHANGE_CAP = 1024
#: The int64 blob (:class:`cosim.model_kernel.KernelArrays`): a header (``H_N`` nodes,
#: ``H_CYCLES`` cycles per plant step; ``H_STOP``, ``H_MORE_LIM``, ``H_SOON``, ``H_PLAIN_LIM``:
#: the fast run's bounds, :func:`fast_step`'s steps run on; ``H_PIN_FN``, ``H_PIN_MODEL``:
#: pinocchio from compiled code, :mod:`cosim.pin_shim`'s ``mrm_pin`` and the plant's model
#: there, 0 where the caller calls ``pin`` itself; ``H_RUN_STICK``, ``H_RUN_CACHED``: the
#: steps run on that took the stick-slip path through ``mrm_pin`` and through the cache, added
#: up until the caller clears them), then the arrays of :func:`blob_views`, one after the
#: other. The float64 blob: ``F_H``, ``F_HH`` (the plant step and its half), ``F_FRICTION``
#: (1.0 with friction), then the counts per rad (n), the torque outputs (n) and
#: :func:`_pin_step`'s scratch (n for ``aba``'s or ``nonLinearEffects``' vector, n·n for
#: ``crba``'s matrix).
H_N, H_CYCLES, H_STOP, H_MORE_LIM, H_SOON, H_PLAIN_LIM = 0, 1, 2, 3, 4, 5
H_PIN_FN, H_PIN_MODEL, H_RUN_STICK, H_RUN_CACHED = 6, 7, 8, 9
#: :func:`fast_step_compliant`'s run (its caller's): the row of its first step (noise row 0),
#: the first row it does not run on (the step with node events, or the end of the run), and
#: the end of the steps whose noise is drawn; ``H_RUN_PIN``: the steps either entry point ran
#: on with pinocchio from compiled code, added up until the caller clears it
H_C_FIRST, H_C_PLAIN_END, H_C_DRAWN_END, H_RUN_PIN, H_SIZE = 10, 11, 12, 13, 16
F_H, F_HH, F_FRICTION, F_SIZE = 0, 1, 2, 4


def f_size(n):
    """The float64 blob's length for ``n`` joints."""
    return F_SIZE + 3 * n + n * n


def pin_call(fn, model, which, q, v, tau, out):
    """:mod:`cosim.pin_shim`'s ``mrm_pin(model, which, q, v, tau, out)`` at address ``fn``
    (``which``: 0 ``aba``, 1 ``nonLinearEffects``, 2 ``crba``; float64 arrays, contiguous).
    Compiled (:func:`cosim.model_kernel.pin_called`), a call through the pointer; here,
    through ctypes."""
    import ctypes

    dp = ctypes.POINTER(ctypes.c_double)
    f = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_int64, dp, dp, dp, dp)(int(fn))
    f(int(model), int(which), q.ctypes.data_as(dp), v.ctypes.data_as(dp),
      tau.ctypes.data_as(dp), out.ctypes.data_as(dp))


def blob_views(IB):
    """The kernel's arrays as views of the int64 blob ``IB``: ``N, P, E, PEND, VIS, PIPE, DUE,
    CHC, CHN, NCH, CUR, SCR`` (shapes as :class:`cosim.model_kernel.KernelArrays`)."""
    n = IB[H_N]
    o = H_SIZE
    N = IB[o:o + n * N_SIZE].reshape((n, N_SIZE))
    o += n * N_SIZE
    P = IB[o:o + n * P_SIZE].reshape((n, P_SIZE))
    o += n * P_SIZE
    E = IB[o:o + n * E_SIZE].reshape((n, E_SIZE))
    o += n * E_SIZE
    PEND = IB[o:o + n * 2 * PEND_CAP * 2].reshape((n, 2, PEND_CAP, 2))
    o += n * 2 * PEND_CAP * 2
    VIS = IB[o:o + n * VIS_CAP * 2].reshape((n, VIS_CAP, 2))
    o += n * VIS_CAP * 2
    PIPE = IB[o:o + n * PIPE_CAP * 4].reshape((n, PIPE_CAP, 4))
    o += n * PIPE_CAP * 4
    DUE = IB[o:o + n * DUE_CAP].reshape((n, DUE_CAP))
    o += n * DUE_CAP
    CHC = IB[o:o + n * CHANGE_CAP].reshape((n, CHANGE_CAP))
    o += n * CHANGE_CAP
    CHN = IB[o:o + n * CHANGE_CAP].reshape((n, CHANGE_CAP))
    o += n * CHANGE_CAP
    NCH = IB[o:o + n]
    o += n
    CUR = IB[o:o + n]
    o += n
    SCR = IB[o:o + SCRATCH]
    return N, P, E, PEND, VIS, PIPE, DUE, CHC, CHN, NCH, CUR, SCR


def fast_step(IB, F, S, a, M, rec, i, start, mode, C, pre_next, X):
    """One whole plant step with no event anywhere in it (:meth:`ModelBackend.fast_path
    <cosim.model.ModelBackend.fast_path>`), after :func:`models.plant_kernel_src.pre_free` and
    pinocchio: the rest of the plant step, the trace row ``i`` (``rec[0, i]`` the angles,
    ``rec[1, i]`` the torques that drove the step), the step's count changes
    (:func:`step_changes`) and every node's plain ticks to the step's last cycle with the
    torques they output there (:func:`plain_step`, every node plain).

    The rest of the plant step, as :meth:`Plant._step_kernel
    <models.plant.Plant._step_kernel>`: ``mode`` 1, ``a`` = ``pin.aba``'s accelerations:
    :func:`~models.plant_kernel_src.free_end`; ``mode`` 2, ``a`` = ``pin.nonLinearEffects``'
    bias and ``M`` = ``pin.crba``'s matrix: :func:`~models.plant_kernel_src.stuck`, else
    :func:`~models.plant_kernel_src.likely_pattern`; ``mode`` 0: the end velocities are
    already in ``S[NEW]``; mode 3: as mode 2 on the bias and matrix the stick-slip cache ``X``
    holds (:func:`stick_cached`: pinocchio's last ``nonLinearEffects`` and ``crba``, which ran on
    the very ``S[QM]`` and ``S[VM]`` of this step); then :func:`~models.plant_kernel_src.finish`.
    Mode 2 fills the cache (:func:`stick_cache`).

    With ``pre_next`` (the caller will run the next step on this path too), the step done, the
    next step's :func:`~models.plant_kernel_src.pre_free` on the torques the nodes output
    (``C`` the plant's constants): one call from Python less per step. Exactly the caller's
    own next ``pre_free`` call, on the same arrays.

    Returns 0; 1 if the free step does not hold (nothing else done: the caller calls again in
    mode 2; 5 where the cache holds this step's bias and matrix: mode 3) or 4 if the likely
    pattern does not (the caller runs the general solve and calls again in mode 0); 2 if a
    joint moved more than one count in a cycle (the plant has stepped, the nodes have not); 3
    as :func:`plain_step`'s True. With ``pre_next`` and the step done, ``8 · (code + 2)``:
    ``code`` the next step's ``pre_free`` result (−1, 0, 1), or 2 where it is 0 and the cache
    holds the next step's bias and matrix (mode 3 for it).
    ``pre_next`` −1: the plant's part only (the trace row and the count changes, returns 0
    or 2): the caller runs the nodes (:meth:`ModelBackend._fast
    <cosim.model.ModelBackend._fast>`'s last step with a node event).

    Steps run on: where the caller would run the next step as a plain step next
    (``IB[H_PLAIN_LIM]``, the run's bounds: :func:`_run_on`), it is run here too, with the
    caller's ``pre_next`` for it, where its code is 2 and its stuck test holds on the cache's
    bias and matrix (from its ``finish``; else the caller runs it: mode 3, the solve) and,
    with pinocchio from compiled code (``IB[H_PIN_FN]``, :func:`_pin_step`), where its code
    is 1 or 0 (the caller's own calls, ``aba``, or ``nonLinearEffects`` and ``crba``, made
    here); and so on. ``k`` such steps add ``64 · k`` to the last one's return value, which
    is that of row ``i + k`` (rows ``i + 1 … i + k``, each ``IB[H_CYCLES]`` cycles after the
    one before): exactly the caller's own calls for them (:meth:`ModelBackend._fast
    <cosim.model.ModelBackend._fast>`), without a return to Python each. Only a step run on
    through ``mrm_pin`` returns 4 with ``k`` (the likely pattern failed: the caller runs the
    general solve on the cache's matrix, then mode 0, for row ``i + k``). The steps run on
    that took the stick-slip path are counted in ``IB[H_RUN_STICK]`` (through ``mrm_pin``)
    and ``IB[H_RUN_CACHED]`` (on the cache)."""
    IB = borrow(IB)
    F = borrow(F)
    S = borrow(S)
    a = borrow(a)
    M = borrow(M)
    rec = borrow(rec)
    C = borrow(C)
    X = borrow(X)
    r = _fast_step_one(IB, F, S, a, M, rec, i, start, mode, C, pre_next, X)
    k = 0
    s = IB[H_CYCLES]
    n = S.shape[1]
    dyn = IB[H_PIN_FN] != 0
    while r == 32 or (dyn and (r == 24 or r == 16)):
        j = i + k + 1
        c = start + (k + 1) * s
        more = _run_on(IB, j, c, s)
        if more < 0:
            break
        if r == 32:
            if not _stick_from(S, X[1 + 2 * n:1 + 3 * n],
                               X[1 + 3 * n:1 + 3 * n + n * n].reshape((n, n)), F[F_H]):
                break
            IB[H_RUN_CACHED] += 1
            k += 1
            r = _finish_step(IB, F, S, rec, j, c, C, more, X)
        else:
            k += 1
            IB[H_RUN_PIN] += 1
            r = _pin_step(IB, F, S, rec, j, c, C, more, X, r == 24)
            if r == 4:
                break
    return r + 64 * k


def _pin_step(IB, F, S, rec, i, start, C, pre_next, X, free):
    """:func:`fast_step`'s step run on with pinocchio from compiled code (``IB[H_PIN_FN]``):
    the caller's sequence for a step of code 1 (``free``: ``aba``, mode 1, and where the free
    step does not hold the stick-slip path) or 0 (the stick-slip path): ``nonLinearEffects``
    and ``crba``, mode 2, or mode 3 where the cache holds the step's. The results in ``F``'s
    scratch. Returns :func:`_fast_step_one`'s, 4 included (the caller's general solve)."""
    n = S.shape[1]
    o = F_SIZE + 2 * n
    A = F[o:o + n]
    Mf = F[o + n:o + n + n * n]
    M = Mf.reshape((n, n))
    fn, model = IB[H_PIN_FN], IB[H_PIN_MODEL]
    q, v = S[plant_src.QM], S[plant_src.VM]
    r = 1
    if free:
        pin_call(fn, model, 0, q, v, S[plant_src.FORCE], A)
        r = _fast_step_one(IB, F, S, A, M, rec, i, start, 1, C, pre_next, X)
        if r != 1 and r != 5:
            return r
    if r == 1:
        pin_call(fn, model, 1, q, v, v, A)
        pin_call(fn, model, 2, q, v, v, Mf)
        IB[H_RUN_STICK] += 1
        return _fast_step_one(IB, F, S, A, M, rec, i, start, 2, C, pre_next, X)
    IB[H_RUN_CACHED] += 1
    return _fast_step_one(IB, F, S, A, M, rec, i, start, 3, C, pre_next, X)


def _run_on(IB, j, c, s):
    """The step at row ``j`` from cycle ``c`` in the caller's fast run (:meth:`ModelBackend.
    _fast <cosim.model.ModelBackend._fast>`, after a step with ``pre_next`` 1): −1 if it is
    not a plain step there (the step with node events: the caller's), else its ``pre_next``,
    as the caller computes them."""
    if c + s > IB[H_PLAIN_LIM]:
        return -1
    if j + 1 < IB[H_STOP] and c + 2 * s <= IB[H_MORE_LIM] and c + s <= IB[H_SOON]:
        return 1
    return 0


def _fast_step_one(IB, F, S, a, M, rec, i, start, mode, C, pre_next, X):
    """:func:`fast_step` for one step."""
    h = F[F_H]
    if mode == 1:
        if not plant_src.free_end(S, a, h, F[F_FRICTION] != 0.0):
            return 5 if stick_cached(S, X) else 1
    elif mode == 2:
        stick_cache(S, a, M, X)
        if not _stick_from(S, a, M, h):
            return 4
    elif mode == 3:
        n = S.shape[1]
        if not _stick_from(S, X[1 + 2 * n:1 + 3 * n], X[1 + 3 * n:1 + 3 * n + n * n].reshape(
                (n, n)), h):
            return 4
    return _finish_step(IB, F, S, rec, i, start, C, pre_next, X)


def _finish_step(IB, F, S, rec, i, start, C, pre_next, X):
    """:func:`fast_step` from the plant's ``finish``."""
    h = F[F_H]
    hh = F[F_HH]
    plant_src.finish(S, h, hh)
    # pre_next −1: the plant's part only, the nodes run on the general path
    r = _step_nodes(IB, F, S, rec, i, start, plant_src.Q_START, plant_src.V_START,
                    plant_src.A_PREV, plant_src.Q, plant_src.Q, pre_next < 0)
    if r or pre_next < 0:
        return r
    if pre_next:
        n = IB[H_N]
        tau = F[F_SIZE + n:F_SIZE + 2 * n]
        code = plant_src.pre_free(S, C, tau, hh, F[F_FRICTION])
        if code == 0 and stick_cached(S, X):
            code = 2
        return 8 * (code + 2)
    return 0


def _stick_from(S, a, M, h):
    """Mode 2's and 3's test: True where ``stuck`` or the likely pattern holds."""
    return plant_src.stuck(S, a) or plant_src.likely_pattern(S, M, h) == 1


def stick_cache(S, a, M, X):
    """The stick-slip cache ``X`` (float64, ``1 + 3n + n²``: ``X[0]`` 1.0 once filled, then
    the ``S[QM]`` and ``S[VM]`` pinocchio ran on, the bias ``a`` from ``nonLinearEffects``, the
    matrix ``M`` from ``crba``, row by row) filled with this step's. Both are functions of
    ``(q, v)`` and the model alone, so a later step on the same ``(q, v)`` bit for bit — every
    stuck joint at rest and every joint stuck — may take them from here (:func:`stick_cached`)
    instead of two pinocchio calls."""
    n = S.shape[1]
    for j in range(n):
        X[1 + j] = S[plant_src.QM, j]
        X[1 + n + j] = S[plant_src.VM, j]
        X[1 + 2 * n + j] = a[j]
    o = 1 + 3 * n
    for r in range(n):
        for c in range(n):
            X[o + r * n + c] = M[r, c]
    X[0] = 1.0


def _same_bits(x, y):
    """``x`` and ``y`` the same float (zeros of one sign; a NaN never)."""
    return x == y and math.copysign(1.0, x) == math.copysign(1.0, y)


def stick_cached(S, X):
    """Whether the stick-slip cache ``X`` (:func:`stick_cache`) ran on this step's ``S[QM]``
    and ``S[VM]``, bit for bit."""
    if X[0] == 0.0:
        return False
    n = S.shape[1]
    for j in range(n):
        if not (_same_bits(S[plant_src.QM, j], X[1 + j]) and
                _same_bits(S[plant_src.VM, j], X[1 + n + j])):
            return False
    return True


def _step_nodes(IB, F, S, rec, i, start, start_row, velocity_row, acc_row, end_row, q_row,
                plant_only):
    """The end of a fast step, after the plant's: the trace row ``i`` (``S[q_row]`` the
    angles, the torques that drove the step), the count changes of the encoder's motion
    (``S[start_row]``, ``S[velocity_row]``, ``S[acc_row]``, ``S[end_row]``: start angle and
    velocity, the step's acceleration, end angle; :func:`step_changes`) and every node's plain
    ticks to the step's last cycle with the torques they output there (:func:`plain_step`;
    not with ``plant_only``: the nodes run on the general path). Returns 0; 2 if a joint moved
    more than one count in a cycle; 3 as :func:`plain_step`'s True."""
    n = IB[H_N]
    N, P, E, PEND, VIS, PIPE, DUE, CHC, CHN, NCH, CUR, SCR = blob_views(IB)
    tau = F[F_SIZE + n:F_SIZE + 2 * n]
    # the trace row and the step's count changes (CUR at the first)
    for j in range(n):
        rec[0, i, j] = S[q_row, j]
        rec[1, i, j] = tau[j]
    if _step_changes(S, start_row, velocity_row, acc_row, end_row, F[F_SIZE:F_SIZE + n],
                     F[F_H], IB[H_CYCLES], CHC, CHN, NCH, SCR):
        return 2
    for k in range(n):
        CUR[k] = 0
    if plant_only:
        return 0
    if _plain_step(N, P, E, VIS, PIPE, DUE, PEND, NCH, True, start, IB[H_CYCLES], 0, CHC, CHN,
                   NCH, CUR, tau):
        return 3
    return 0



def fast_step_compliant(IB, F, S, acc, rec, i, start, C, Z, pre_next):
    """:func:`fast_step` for the compliant plant (:class:`models.compliant.CompliantPlant`,
    :meth:`ModelBackend.fast_path <cosim.model.ModelBackend.fast_path>`): one whole plant step
    with no event in it, after :func:`models.compliant_kernel_src.pre` and ``pin.aba``'s
    accelerations ``acc`` on the link: :func:`~models.compliant_kernel_src.finish`, the trace
    row ``i`` (the link angles, the torques that drove the step), the motor-side encoder's
    count changes (its motion ``θ``: the plant's :meth:`motion
    <models.compliant.CompliantPlant.motion>`) and every node's plain ticks to the step's last
    cycle with the torques they output there.

    The compliant step has no set-valued solve through pinocchio (the motor side's friction is
    solved per joint inside ``pre``), so a step always completes here. With ``pre_next`` (the
    caller runs the next step on this path too and has drawn its current-sensor noise from
    the plant's stream, as :meth:`CompliantPlant.step` would at its start: ``Z`` the run's
    draws, row ``i + 1 − IB[H_C_FIRST]``), the next step's ``pre`` on the torques the nodes
    output.

    Returns 0; 2 if a joint moved more than one count in a cycle (the plant has stepped, the
    nodes have not); 3 as :func:`plain_step`'s True; with ``pre_next``, ``8 · (code + 2)`` with
    ``code`` 1 (``pre`` done) or −1 (a torque was not finite, nothing done). ``pre_next`` −1:
    the plant's part only, as :func:`fast_step`'s.

    Steps run on, with pinocchio from compiled code (``IB[H_PIN_FN]``, as :func:`fast_step`'s):
    where the next step's ``pre`` is done and its row is below ``IB[H_C_PLAIN_END]``, its
    ``aba`` is called here and the step run, with ``pre_next`` where the row after it is
    below ``IB[H_C_DRAWN_END]``; and so on: the caller's own calls for them. ``k`` such steps
    add ``64 · k`` to the return value, which is that of row ``i + k``."""
    IB = borrow(IB)
    F = borrow(F)
    S = borrow(S)
    acc = borrow(acc)
    rec = borrow(rec)
    C = borrow(C)
    Z = borrow(Z)
    r = _compliant_one(IB, F, S, acc, rec, i, start, C, Z, pre_next)
    if IB[H_PIN_FN] == 0:
        return r
    n = S.shape[1]
    o = F_SIZE + 2 * n
    A = F[o:o + n]
    fn, model = IB[H_PIN_FN], IB[H_PIN_MODEL]
    s = IB[H_CYCLES]
    k = 0
    while r == 24 and i + k + 1 < IB[H_C_PLAIN_END]:
        k += 1
        IB[H_RUN_PIN] += 1
        pin_call(fn, model, 0, S[compliant_src.QM], S[compliant_src.VM], S[compliant_src.LF], A)
        more = 1 if i + k + 1 < IB[H_C_DRAWN_END] else 0
        r = _compliant_one(IB, F, S, A, rec, i + k, start + k * s, C, Z, more)
    return r + 64 * k


def _compliant_one(IB, F, S, acc, rec, i, start, C, Z, pre_next):
    """:func:`fast_step_compliant` for one step."""
    h = F[F_H]
    hh = F[F_HH]
    compliant_src.finish(S, acc, h, hh)
    # the motor-side encoder counts the motor (θ); the trace records the link (q)
    r = _step_nodes(IB, F, S, rec, i, start, compliant_src.TH_START, compliant_src.W_START,
                    compliant_src.AM_PREV, compliant_src.TH, compliant_src.Q, pre_next < 0)
    if r or pre_next < 0:       # the plant's part only (as fast_step's)
        return r
    if pre_next:
        n = IB[H_N]
        tau = F[F_SIZE + n:F_SIZE + 2 * n]
        if compliant_src.pre(S, C, tau, Z[i + 1 - IB[H_C_FIRST]], h, hh,
                             F[F_FRICTION] != 0.0):
            return 24
        return 8
    return 0

# --- the boundary's sine/cosine unit (hdl/node/trig_ref.py) ---------------------------------
_ATAN = np.array(_ATAN_LIST, dtype=np.int64)
#: :func:`sin_cos` needs ``|count · kb|`` below 2^62: ``kb`` (Q22 binary-angle units per count)
#: below this, with the 24-bit count (the caller runs the reference otherwise)
SIN_COS_KB_MAX = 1 << 38


def cordic(bam):
    """:func:`hdl.node.trig_ref.cordic`: ``(cos, sin)`` TRIG words of a 24-bit binary angle
    (``x``, ``y`` and ``z`` stay below 2^29)."""
    s = bam & 0xFFFFFF                      # wrap(bam, 24)
    if s >> 23:
        s -= 1 << 24
    flip = s > (1 << 22) or s < -(1 << 22)
    if flip:
        s = (s + (1 << 23)) & 0xFFFFFF      # wrap(s + 2^23, 24)
        if s >> 23:
            s -= 1 << 24
    x = _X0
    y = 0
    z = s << _ZGUARD
    for i in range(_ITERATIONS):
        if z >= 0:
            x, y, z = x - (y >> i), y + (x >> i), z - _ATAN[i]
        else:
            x, y, z = x + (y >> i), y - (x >> i), z + _ATAN[i]
    c = (x + (1 << (_GUARD - 1))) >> _GUARD         # round_shift(x, GUARD)
    s_ = (y + (1 << (_GUARD - 1))) >> _GUARD
    if flip:
        return -c, -s_
    return c, s_


def sin_cos(count, kb):
    """:func:`hdl.node.trig_ref.sin_cos` with ``kb = bam_constant(counts_per_rev)`` below
    :data:`SIN_COS_KB_MAX`: ``(cos q, sin q)`` TRIG words of joint count ``count``."""
    c = count & 0xFFFFFF                    # wrap(count, 24)
    if c >> 23:
        c -= 1 << 24
    return cordic(((c * kb + (1 << 21)) >> 22) & 0xFFFFFF)     # binary_angle
