"""Bit-exact Python reference of the node's fixed-point VDC unit (transaction level).

One call of :meth:`VdcModel.step` is one period: from the Comm B words (required joint
velocity, actual and required velocity of {C}), the encoder snapshot (``q̇`` and the CORDIC's
``cos q``, ``sin q``) and the gravity words of the previous Comm D, it returns the Comm C words
(required net force/moment of Link a in {A} and of Link b in {C}) and then adapts the
parameter estimates with the projection function. The float model it approximates is
:class:`~.vdc_float_ref.ModuleVDC`; the number formats are in :mod:`mrm_cosim.protocol.fixed`
and docs/node.md.

Every rounding point is written out below; each is ``fx(Σ products, format)``: the exact sum,
rounded half up once onto the format's LSB and saturated to 24 bits — what one statement of the
engine does (:mod:`mrm_cosim.protocol.vdc_program` is the same computation as an engine program;
tests check that they agree bit for bit, and that both agree with the float model within the
measured budget).

The regressor is used through :data:`~mrm_cosim.protocol.vdc_program.Y_TABLE`, as in the
program; the uploaded words are :class:`~mrm_cosim.protocol.vdc_program.VdcParams`.
:func:`vdc_input_words` and :func:`vdc_state_words` name this model's words as the program's
registers, to load the engine with the same inputs and state.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mrm_cosim.protocol.fixed import (
    ACC,
    FORCE,
    GAIN,
    INVT,
    RHOT,
    SIG,
    THETA,
    TRIG,
    VEL,
    WORD_MAX,
    WORD_MIN,
    round_shift,
    saturate,
    theta_group,
)
from mrm_cosim.protocol.vdc_program import LINKS, Y_TABLE, VdcParams, link_terms

__all__ = ["fx", "VdcInputs", "VdcModel", "vdc_input_words", "vdc_state_words"]


def fx(parts, fmt, wrap: bool = False) -> int:
    """Round ``Σ v · 2^lsb`` (``parts`` = [(v, lsb)]) half up onto ``fmt`` and saturate."""
    L = min([lsb for _, lsb in parts] + [fmt.lsb])
    total = sum(v << (lsb - L) for v, lsb in parts)
    return saturate(round_shift(total, fmt.lsb - L))


def fx_point(fmt, *lsbs):
    """One rounding point of :func:`fx` as a function of its summands' values:
    ``fx_point(fmt, l0, l1)(v0, v1) == fx([(v0, l0), (v1, l1)], fmt)`` for all integers.

    The shifts that align the summands on the finest LSB, the rounding constant and the
    saturation bounds are worked out once, where the point is defined, so a hot path (the
    joint controller's tick runs a million times per simulated second and node) pays for
    the integer arithmetic only. The statement reads as the ``fx`` it stands for: the
    destination format first, then each summand's LSB.
    """
    low = min(*lsbs, fmt.lsb)
    shifts = tuple(lsb - low for lsb in lsbs)
    r = fmt.lsb - low
    half = (1 << (r - 1)) if r else 0
    lo, hi = WORD_MIN, WORD_MAX
    if len(shifts) == 1:
        (s0,) = shifts

        def point(v0):
            v = ((v0 << s0) + half) >> r
            return lo if v < lo else hi if v > hi else v
    elif len(shifts) == 2:
        s0, s1 = shifts

        def point(v0, v1):
            v = ((v0 << s0) + (v1 << s1) + half) >> r
            return lo if v < lo else hi if v > hi else v
    elif len(shifts) == 3:
        s0, s1, s2 = shifts

        def point(v0, v1, v2):
            v = ((v0 << s0) + (v1 << s1) + (v2 << s2) + half) >> r
            return lo if v < lo else hi if v > hi else v
    elif len(shifts) == 4:
        s0, s1, s2, s3 = shifts

        def point(v0, v1, v2, v3):
            v = ((v0 << s0) + (v1 << s1) + (v2 << s2) + (v3 << s3) + half) >> r
            return lo if v < lo else hi if v > hi else v
    elif len(shifts) == 5:
        s0, s1, s2, s3, s4 = shifts

        def point(v0, v1, v2, v3, v4):
            v = ((v0 << s0) + (v1 << s1) + (v2 << s2) + (v3 << s3) + (v4 << s4) + half) >> r
            return lo if v < lo else hi if v > hi else v
    else:
        def point(*values):
            v = (sum(x << s for x, s in zip(values, shifts, strict=True)) + half) >> r
            return lo if v < lo else hi if v > hi else v
    return point


@dataclass
class VdcInputs:
    """Words one VDC run reads.

    Attributes
    ----------
    qd_r : int, VEL — required joint velocity (Comm B)
    V_C, V_rC : list of 6 int, VEL — actual and required velocity of {C} (Comm B)
    qd : int, VEL — joint velocity snapshot (encoder)
    cos_q, sin_q : int, TRIG — of the joint angle snapshot (CORDIC)
    g_C : list of 3 int, ACC — upward gravity in {C} (previous Comm D)
    """

    qd_r: int
    V_C: list
    V_rC: list
    qd: int
    cos_q: int
    sin_q: int
    g_C: list

    @classmethod
    def from_float(cls, qd_r, V_C, V_rC, qd, q, g_C) -> VdcInputs:
        """Words from floats; ``cos q, sin q`` rounded directly (not through the CORDIC)."""
        return cls(VEL.encode(qd_r), [VEL.encode(x) for x in V_C],
                   [VEL.encode(x) for x in V_rC], VEL.encode(qd), TRIG.encode(np.cos(q)),
                   TRIG.encode(np.sin(q)), [ACC.encode(x) for x in g_C])


# The rounding points (:func:`fx_point`; summands with the same LSB are added exactly first,
# which is the same exact sum). Rotations Rz(q)ᵀ of VEL and ACC vectors:
_ROT = {VEL: fx_point(VEL, TRIG.lsb + VEL.lsb), ACC: fx_point(ACC, TRIG.lsb + ACC.lsb)}
_VEL = fx_point(VEL, VEL.lsb)                            # a sum of VEL words
_ACC = fx_point(ACC, ACC.lsb)                            # a sum of ACC words
_DIFF = fx_point(ACC, VEL.lsb + INVT.lsb)                # backward difference (x − x_prev)/T
_DA = fx_point(ACC, TRIG.lsb + ACC.lsb, 2 * VEL.lsb)     # Rᵀ dV_rC ∓ q̇ (ẑ×) Rᵀ V_rC
_A = fx_point(ACC, ACC.lsb, 2 * VEL.lsb)                 # a = dv_r + g + ω × v_r
_P = fx_point(ACC, 2 * VEL.lsb)                          # P_ij = ω_i ω_r,j
#: F_row = Σ_group (Σ_col Y θ̂) + K e: one LSB per θ group, then the gain's.
_F = fx_point(FORCE, *(ACC.lsb + fmt.lsb for fmt in THETA), GAIN.lsb + VEL.lsb)
_SIG = fx_point(SIG, ACC.lsb + VEL.lsb)                  # s_col = Σ_row Y e
_DELTA = [fx_point(THETA[g], RHOT[g].lsb + SIG.lsb) for g in range(3)]   # Δθ = ρT s
_THETA = [fx_point(THETA[g], THETA[g].lsb) for g in range(3)]            # θ̂ + Δθ
_GROUP = [theta_group(j) for j in range(13)]


def _index(kind: str, idx: int) -> int:
    """Position of a regressor summand in the vector ``a0 a1 a2, P00 … P22, dw0 dw1 dw2``."""
    return {"a": 0, "P": 3 + 3 * (idx // 10) + idx % 10, "dw": 12}[kind] + \
        (0 if kind == "P" else idx)


#: :data:`Y_TABLE` as positions in that vector: ``{(row, col): ((sign, position), ...)}``.
_Y = {rc: tuple((sgn, _index(kind, idx)) for sgn, kind, idx in summands)
      for rc, summands in Y_TABLE.items()}
#: Per row, the columns of its non-zero entries, by θ group: ``[[cols] × 3] × 6``.
_ROW_COLS = [[[col for (_, col), _s in link_terms(row=row) if _GROUP[col] == g]
              for g in range(3)] for row in range(6)]
#: Per column, the rows of its non-zero entries.
_COL_ROWS = [[row for (row, _), _s in link_terms(col=col)] for col in range(13)]


def _rot_t(c: int, s: int, x0: int, x1: int, fmt) -> tuple[int, int]:
    """First two components of ``Rz(q)ᵀ x``: ``(c x0 + s x1, −s x0 + c x1)``."""
    rot = _ROT[fmt]
    return rot(c * x0 + s * x1), rot(c * x1 - s * x0)


def _link_a(c: int, s: int, V: list, qd: int) -> list[int]:
    """``Rz(q)ᵀ`` per block plus ``z q̇``, VEL words."""
    v0, v1 = _rot_t(c, s, V[0], V[1], VEL)
    w0, w1 = _rot_t(c, s, V[3], V[4], VEL)
    return [v0, v1, V[2], w0, w1, _VEL(V[5] + qd)]


@dataclass
class VdcModel:
    """State and one-period step of the fixed-point VDC unit.

    Attributes
    ----------
    params : VdcParams
    theta : list of 2 lists of 13 int
        Parameter estimates (THETA words), Link a then Link b.
    prev_C : list of 6 int
        Required velocity of {C} of the previous period (VEL words).
    prev_qd_r : int
        Required joint velocity of the previous period (VEL word).
    primed : bool
        False until the first step (which then has zero ``dV_rC/dt`` and ``q̈_r``).
    """

    params: VdcParams
    theta: list
    prev_C: list = field(default_factory=lambda: [0] * 6)
    prev_qd_r: int = 0
    primed: bool = False

    def _link(self, i: int, V, V_r, dV, g):
        """Required net force words and adaptation of link ``i``."""
        th = self.theta[i]
        p = self.params
        # the regressor's summands: a = dv_r + ω × v_r + g, P_mn = ω_m ω_r,n, dw = dω_r
        w = [_A(dV[k] + g[k], V[3 + (k + 1) % 3] * V_r[(k + 2) % 3]
                - V[3 + (k + 2) % 3] * V_r[(k + 1) % 3]) for k in range(3)]
        w += [_P(V[3 + m] * V_r[3 + n]) for m in range(3) for n in range(3)]
        w += dV[3:]
        e = [_VEL(V_r[k] - V[k]) for k in range(6)]
        # each entry of Y, an exact sum of summands, once (it serves F and s)
        y = {}
        for rc, terms in _Y.items():
            v = 0
            for sgn, k in terms:
                v += w[k] if sgn > 0 else -w[k]
            y[rc] = v
        F = []
        for row, groups in enumerate(_ROW_COLS):
            sums = []
            for cols in groups:
                v = 0
                for col in cols:
                    v += y[(row, col)] * th[col]
                sums.append(v)
            F.append(_F(sums[0], sums[1], sums[2], p.K[i][row] * e[row]))
        new = []
        lower, upper, rho = p.lower[i], p.upper[i], p.rho_T[i]
        for j in range(13):
            g_ = _GROUP[j]
            v = 0
            for row in _COL_ROWS[j]:
                v += y[(row, j)] * e[row]
            t = _THETA[g_](th[j] + _DELTA[g_](rho[j] * _SIG(v)))
            new.append(min(max(t, lower[j]), upper[j]))
        return F, new

    def step(self, x: VdcInputs) -> tuple[list[int], list[int]]:
        """One period: forces of Link a and Link b (FORCE words), then adaptation.

        Returns
        -------
        F_a, F_b : list of 6 int
        """
        c, s = x.cos_q, x.sin_q
        if not self.primed:
            self.prev_C = list(x.V_rC)
            self.prev_qd_r = x.qd_r
            self.primed = True
        V_A = _link_a(c, s, x.V_C, x.qd)
        V_rA = _link_a(c, s, x.V_rC, x.qd_r)
        g0, g1 = _rot_t(c, s, x.g_C[0], x.g_C[1], ACC)
        g_A = [g0, g1, x.g_C[2]]
        inv_T = self.params.inv_T
        dC = [_DIFF(inv_T * (x.V_rC[k] - self.prev_C[k])) for k in range(6)]
        qdd_r = _DIFF(inv_T * (x.qd_r - self.prev_qd_r))
        # Across the joint: dV_rA = Rᵀ dV_rC − q̇ (ẑ×)(Rᵀ V_rC) + z q̈_r; (ẑ×)(x, y, z) = (−y, x, 0).
        dA = [0] * 6
        for base in (0, 3):
            d0, d1 = dC[base], dC[base + 1]
            dA[base] = _DA(c * d0 + s * d1, x.qd * V_rA[base + 1])
            dA[base + 1] = _DA(c * d1 - s * d0, -x.qd * V_rA[base])
        dA[2] = dC[2]
        dA[5] = _ACC(dC[5] + qdd_r)
        F_a, th_a = self._link(0, V_A, V_rA, dA, g_A)
        F_b, th_b = self._link(1, x.V_C, x.V_rC, dC, x.g_C)
        self.theta = [th_a, th_b]
        self.prev_C = list(x.V_rC)
        self.prev_qd_r = x.qd_r
        return F_a, F_b


def vdc_input_words(x: VdcInputs) -> dict[str, int]:
    """Register words of one run's inputs, by name."""
    out = {"qdr": x.qd_r, "qd": x.qd, "cq": x.cos_q, "sq": x.sin_q}
    for k in range(6):
        out[f"VC{k}"] = x.V_C[k]
        out[f"VrC{k}"] = x.V_rC[k]
    for k in range(3):
        out[f"gC{k}"] = x.g_C[k]
    return out


def vdc_state_words(model: VdcModel) -> dict[str, int]:
    """Register words of the state (estimates, derivative history), by name."""
    out = {}
    for i, L in enumerate(LINKS):
        for j in range(13):
            out[f"th{L}{j}"] = model.theta[i][j]
    for k in range(6):
        out[f"pC{k}"] = model.prev_C[k]
    out["pqdr"] = model.prev_qd_r
    return out
