"""The compliant plant step's per-joint arithmetic as code numba can compile
(:meth:`CompliantPlant.use_kernel <models.compliant.CompliantPlant.use_kernel>`): everything of
:meth:`CompliantPlant.step <models.compliant.CompliantPlant.step>` but the noise draw and
pinocchio's ABA, which stay calls from Python before and between these functions.

A line-for-line translation of that method (``models.gear.play``, ``dahl`` and ``gear_torque`` are
the reference's own functions, compiled as they are), which stays the readable source of
truth and the pure-Python path: every float operation is the reference's, in the reference's
order (no fastmath, so no contraction), ``exp``/``sin``/``cos`` as Python's ``math`` calls
them; the states are equal bit for bit (tests/test_compliant.py). Kept apart from
:mod:`models.plant_kernel_src` (the rigid plant's), which it does not change.

State: one float64 row per quantity (``S[Q]``, …, shape (rows, n)); constants in ``C``.
"""

from __future__ import annotations

import math

# The gear's curve and play are the reference's own functions (floats only): the loader
# compiles them with this module's (cosim.model_kernel.jit_module).
from mrm_cosim.models.gear import dahl, gear_torque, play  # noqa: F401 - called by pre, compiled

#: Functions of other modules this one calls, compiled with it.
CALLS = ("gear_torque", "play", "dahl")

# --- state rows ------------------------------------------------------------------------------
(Q, V, A_PREV, Q_START, V_START, TH, W, AM_PREV, TH_START, W_START, Y, TAU, TAU_J, QM, VM, THM,
 LF) = range(17)
#: the holding brakes' levels (output-referred, on the motor side) where engaged, else 0
BRAKE, BRAKE_SLIP = 17, 18
#: the Dahl hysteresis torque (Y then holds the last mid-step deflection)
Z = 19
S_ROWS = 20
# --- constant rows ---------------------------------------------------------------------------
(ALPHA, BETA, PEAK, FC, FSX, INV_VS, VISC, AMP, PHASE, HAS_SPRING, T1, T2, K1, K2, K3, HALF,
 DG, BM, RIPPLE, RPHASE, R2, SIGMA, OFF, FH, SIG, PLAY) = range(26)
C_ROWS = 26


def pre(S, C, cmd, noise, h, hh, friction):
    """:meth:`CompliantPlant.step` up to the ABA: amplifier, gear, motor side, the link's
    generalised force into ``S[LF]``. Returns False (state untouched) if ``cmd`` is not
    finite."""
    n = S.shape[1]
    for i in range(n):
        if not math.isfinite(cmd[i]):
            return False
    S[Q_START, :] = S[Q, :]
    S[V_START, :] = S[V, :]
    S[TH_START, :] = S[TH, :]
    S[W_START, :] = S[W, :]
    for i in range(n):
        u = cmd[i]
        p = C[PEAK, i]
        if u > p:
            u = p
        elif u < -p:
            u = -p
        u = u + C[SIGMA, i] * noise[i]
        d = S[TAU, i] - u
        S[TAU, i] = u + d * C[ALPHA, i]
        vi = S[V, i]
        S[QM, i] = S[Q, i] + hh * vi
        S[VM, i] = vi + hh * S[A_PREV, i]
        S[THM, i] = S[TH, i] + hh * S[W, i]
        delta = S[THM, i] - S[QM, i] + C[OFF, i]
        if C[PLAY, i] != 0.0:
            yi = play(S[Y, i], delta, C[HALF, i])
            tj = gear_torque(yi, C[T1, i], C[T2, i], C[K1, i], C[K2, i], C[K3, i])
            if yi != S[Y, i] or C[HALF, i] == 0.0:
                tj += C[DG, i] * (S[W, i] - vi)
            S[Y, i] = yi
        else:
            zi = dahl(S[Z, i], delta - S[Y, i], C[FH, i], C[SIG, i])
            S[Z, i] = zi
            S[Y, i] = delta
            tj = gear_torque(delta, C[T1, i], C[T2, i], C[K1, i], C[K2, i], C[K3, i]) + zi
            tj += C[DG, i] * (S[W, i] - vi)
        tj += C[RIPPLE, i] * math.sin(C[R2, i] * S[THM, i] + C[RPHASE, i])
        S[TAU_J, i] = tj
        S[LF, i] = tj
        wi = S[W, i]
        rho = u + d * C[BETA, i] - tj - C[VISC, i] * wi
        bm = C[BM, i]
        pm = bm * wi + h * rho
        if friction or S[BRAKE, i] != 0.0:
            x = wi * C[INV_VS, i]
            lv = C[FC, i] + C[FSX, i] * math.exp(-x * x)
            if S[BRAKE, i] != 0.0:
                lv += S[BRAKE, i] if wi == 0.0 else S[BRAKE_SLIP, i]
            level = h * lv
            if pm > level:
                wn = (pm - level) / bm
            elif pm < -level:
                wn = (pm + level) / bm
            else:
                wn = 0.0
        else:
            wn = pm / bm
        S[AM_PREV, i] = (wn - wi) / h
        S[W, i] = wn
        S[TH, i] = S[THM, i] + hh * wn
    for i in range(n):
        if C[HAS_SPRING, i] != 0.0:
            S[LF, i] += C[AMP, i] * math.cos(S[QM, i] + C[PHASE, i])
    return True


def finish(S, acc, h, hh):
    """The end of :meth:`CompliantPlant.step`: the link's velocities and angles."""
    for i in range(S.shape[1]):
        vn = S[V, i] + h * acc[i]
        S[A_PREV, i] = (vn - S[V, i]) / h
        S[V, i] = vn
        S[Q, i] = S[QM, i] + hh * vn
