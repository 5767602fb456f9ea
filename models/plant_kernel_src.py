"""The plant step's per-joint arithmetic as code numba can compile (:meth:`Plant.use_kernel
<models.plant.Plant.use_kernel>`): everything of :meth:`Plant.step <models.plant.Plant.step>`
but pinocchio's calls, which stay calls from Python between these functions.

Line-for-line translations of :meth:`Plant.step`, ``_free_step``, ``_stick_slip_step``,
``_likely_pattern`` and ``_cholesky_solve`` (models/plant.py), which stay the readable source of
truth and the pure-Python path. Every float operation is the reference's, in the reference's
order (no reassociation, no fused multiply-add: numba does not contract without ``fastmath``),
and ``exp``/``cos`` are the C library's, as Python's ``math`` calls them; so the states are
equal bit for bit (tests/test_plant.py and the closed-loop trace hashes check it).

State: one float64 row per quantity (``S[Q]``, ``S[V]``, …, shape (rows, n)); the constants in
``C`` (``C[ALPHA]``, …).
"""

from __future__ import annotations

import math

import numpy as np

# --- state rows ------------------------------------------------------------------------------
Q, V, TAU, A_PREV, Q_START, V_START, QM, VM, FORCE, RHO, LEVEL, SIGN, NEW = range(13)
#: the holding brakes' levels at the joint where engaged (else 0): held, slipping
BRAKE, BRAKE_SLIP = 13, 14
S_ROWS = 15
# --- constant rows ---------------------------------------------------------------------------
ALPHA, BETA, PEAK, FC, FSX, INV_VS, VISC, AMP, PHASE, HAS_SPRING = range(10)
C_ROWS = 10


def pre(S, C, cmd, hh):
    """:meth:`Plant.step` up to the first pinocchio call: the amplifier, the midpoint, the
    friction level, the torque ``ρ`` and the signs. Returns -1 if ``cmd`` is not finite (the
    state untouched), else 1 if every joint slides, 0 if one is at rest."""
    n = S.shape[1]
    for i in range(n):
        if not math.isfinite(cmd[i]):
            return -1
    S[Q_START, :] = S[Q, :]
    S[V_START, :] = S[V, :]
    sliding = 1
    for i in range(n):
        u = cmd[i]
        p = C[PEAK, i]
        if u > p:
            u = p
        elif u < -p:
            u = -p
        d = S[TAU, i] - u
        S[TAU, i] = u + d * C[ALPHA, i]
        vi = S[V, i]
        S[QM, i] = S[Q, i] + hh * vi
        S[VM, i] = vi + hh * S[A_PREV, i]
        x = vi * C[INV_VS, i]
        S[LEVEL, i] = C[FC, i] + C[FSX, i] * math.exp(-x * x)
        if S[BRAKE, i] != 0.0:
            S[LEVEL, i] += S[BRAKE, i] if vi == 0.0 else S[BRAKE_SLIP, i]
        S[RHO, i] = u + d * C[BETA, i] - C[VISC, i] * vi
        if vi > 0.0:
            S[SIGN, i] = 1.0
        elif vi < 0.0:
            S[SIGN, i] = -1.0
        else:
            S[SIGN, i] = 0.0
            sliding = 0
    for i in range(n):
        if C[HAS_SPRING, i] != 0.0:
            S[RHO, i] += C[AMP, i] * math.cos(S[QM, i] + C[PHASE, i])
    return sliding


def pre_free(S, C, cmd, hh, friction):
    """:func:`pre`, then :func:`free_force` where the free step applies (no friction, or every
    joint slides): one call where the caller would make two (``friction`` 1.0 or 0.0, as the
    plant's). Returns pre's -1 (nothing done), else 1 if ``S[FORCE]`` is ready for ``pin.aba``,
    0 if the stick-slip solve must run."""
    sliding = pre(S, C, cmd, hh)
    if sliding < 0:
        return -1
    if friction == 0.0 or sliding:
        free_force(S, friction)
        return 1
    return 0


def free_force(S, with_friction):
    """``_free_step``'s generalised force into ``S[FORCE]`` (what ``pin.aba`` takes)."""
    for i in range(S.shape[1]):
        S[FORCE, i] = S[RHO, i] - with_friction * S[LEVEL, i] * S[SIGN, i]


def free_end(S, a, h, check):
    """``_free_step``'s end velocities ``v + h · a`` into ``S[NEW]``; with ``check`` (friction
    on), False if a joint would not keep its direction (the stick-slip solve is needed)."""
    n = S.shape[1]
    for i in range(n):
        S[NEW, i] = S[V, i] + h * a[i]
    if check:
        for i in range(n):
            if S[NEW, i] * S[SIGN, i] <= 0.0:
                return False
    return True


def finish(S, h, hh):
    """The end of :meth:`Plant.step`: velocities ``S[NEW]``, the step's acceleration, the
    angles."""
    for i in range(S.shape[1]):
        w = S[NEW, i]
        S[A_PREV, i] = (w - S[V, i]) / h
        S[V, i] = w
        S[Q, i] = S[QM, i] + hh * w


def stuck(S, bias):
    """``_stick_slip_step`` up to ``crba``: the net torque ``ρ − bias`` into ``S[FORCE]``.
    True if every joint is at rest and held by its static friction (``S[NEW]`` = 0)."""
    n = S.shape[1]
    free = False
    for i in range(n):
        S[FORCE, i] = S[RHO, i] - bias[i]
        if S[SIGN, i] != 0.0:
            free = True
    if free:
        return False
    for i in range(n):
        if not abs(S[FORCE, i]) <= S[LEVEL, i]:
            return False
    for i in range(n):
        S[NEW, i] = 0.0
    return True


def likely_pattern(S, M, h):
    """``_stick_slip_step``'s ``_likely_pattern`` (``M`` from ``crba``, its upper triangle
    filled): end velocities into ``S[NEW]`` and 1 if joints at rest stay stuck and sliding
    joints keep sliding; 0 if not; -1 if every joint slides or none does (the pattern is not
    tried)."""
    n = S.shape[1]
    free = np.empty(n, dtype=np.int64)
    nf = 0
    for i in range(n):
        if S[SIGN, i] != 0.0:
            free[nf] = i
            nf += 1
    if nf == 0 or nf == n:
        return -1
    A = np.empty((nf, nf))
    b = np.empty(nf)
    for r in range(nf):
        i = free[r]
        for c in range(nf):
            j = free[c]
            A[r, c] = M[i, j] if i <= j else M[j, i]
        b[r] = h * (S[FORCE, i] - S[LEVEL, i] * S[SIGN, i])
    dv = np.empty(nf)
    if not cholesky_solve(A, b, dv):
        return 0
    for i in range(n):
        S[NEW, i] = 0.0
    for r in range(nf):
        i = free[r]
        w = S[V, i] + dv[r]
        if w * S[SIGN, i] <= 0.0:
            return 0
        S[NEW, i] = w
    for i in range(n):
        if S[SIGN, i] == 0.0:
            hold = h * S[FORCE, i]
            for r in range(nf):
                j = free[r]
                hold -= (M[i, j] if i < j else M[j, i]) * dv[r]
            if abs(hold) > h * S[LEVEL, i] * (1.0 + 1e-12):
                return 0
    return 1


def cholesky_solve(A, b, x):
    """``_cholesky_solve``: ``A x = b`` for a small symmetric positive definite ``A``; the
    solution into ``x``; False if ``A`` is not positive definite."""
    k = b.shape[0]
    L = np.zeros((k, k))
    for j in range(k):
        d = A[j, j]
        for p in range(j):
            d -= L[j, p] * L[j, p]
        if not d > 0.0:
            return False
        d = math.sqrt(d)
        L[j, j] = d
        for i in range(j + 1, k):
            v = A[i, j]
            for p in range(j):
                v -= L[i, p] * L[j, p]
            L[i, j] = v / d
    y = np.zeros(k)
    for i in range(k):
        v = b[i]
        for p in range(i):
            v -= L[i, p] * y[p]
        y[i] = v / L[i, i]
    for i in range(k - 1, -1, -1):
        v = y[i]
        for p in range(i + 1, k):
            v -= L[p, i] * y[p]
        y[i] = v / L[i, i]
    x[:] = y
    return True
