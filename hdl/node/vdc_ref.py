"""Bit-exact Python reference of the node's fixed-point VDC unit (transaction level).

One call of :meth:`VdcModel.step` is one period: from the Comm B words (required joint
velocity, actual and required velocity of {C}), the encoder snapshot (``q̇`` and the CORDIC's
``cos q``, ``sin q``) and the gravity words of the previous Comm D, it returns the Comm C words
(required net force/moment of Link a in {A} and of Link b in {C}) and then adapts the
parameter estimates with the projection function. The float model it approximates is
:class:`master.vdc_float.ModuleVDC`; the number formats are in :mod:`.fixed` and docs/node.md.

Every rounding point is written out below; each is ``fx(Σ products, format)``: the exact sum,
rounded half up once onto the format's LSB and saturated to 24 bits — what one statement of the
engine does (:mod:`.vdc` is the same computation as an engine program; tests check that they
agree bit for bit, and that both agree with the float model within the measured budget).

The regressor ``Y(ω, V_r, dV_r/dt, g)`` is used through :data:`Y_TABLE`: each non-zero entry
is an exact sum of ± words ``a_i`` (``a = dv_r + ω × v_r + g``), ``P_ij = ω_i ω_r,j`` and
``dw_i`` (the required angular acceleration). Entries are never rounded on their own: the
engine multiplies each summand by ``θ̂_j`` (or by the velocity error) directly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .fixed import ACC, FORCE, GAIN, INVT, RHOT, SIG, THETA, TRIG, VEL, WORD_MAX, WORD_MIN, \
    round_shift, saturate, theta_group

__all__ = ["Y_TABLE", "fx", "fx_point", "VdcParams", "VdcInputs", "VdcModel", "link_terms"]


def _e(spec: str) -> list[tuple[int, str, int]]:
    """Parse ``"-dw2 +P10"`` into [(sign, kind, index)], index of P as 10*i + j."""
    out = []
    for tok in spec.split():
        sign = -1 if tok[0] == "-" else 1
        body = tok.lstrip("+-")
        kind = "P" if body[0] == "P" else "dw" if body.startswith("dw") else "a"
        out.append((sign, kind, int(body[len(kind):])))
    return out


# Y[(row, col)] for rows f0 f1 f2 n0 n1 n2 and the 13 parameters (MRM Table 1 order); derived
# from the closed form in DESIGN.md "VDC in equations" (docs/node.md), tested against
# models.spatial.regressor.
Y_TABLE: dict[tuple[int, int], list[tuple[int, str, int]]] = {
    (0, 0): _e("+a0"), (1, 0): _e("+a1"), (2, 0): _e("+a2"),
    (0, 1): _e("-P11 -P22"), (0, 2): _e("-dw2 +P10"), (0, 3): _e("+dw1 +P20"),
    (1, 1): _e("+dw2 +P01"), (1, 2): _e("-P00 -P22"), (1, 3): _e("-dw0 +P21"),
    (2, 1): _e("-dw1 +P02"), (2, 2): _e("+dw0 +P12"), (2, 3): _e("-P00 -P11"),
    (3, 2): _e("+a2"), (3, 3): _e("-a1"),
    (4, 1): _e("-a2"), (4, 3): _e("+a0"),
    (5, 1): _e("+a1"), (5, 2): _e("-a0"),
    (4, 4): _e("+dw1 -P02"), (5, 4): _e("+dw2 +P01"),
    (3, 5): _e("+dw0 +P12"), (5, 5): _e("+dw2 -P10"),
    (3, 6): _e("+dw0 -P21"), (4, 6): _e("+dw1 +P20"),
    (3, 7): _e("-dw1 +P02"), (4, 7): _e("-dw0 -P12"), (5, 7): _e("+P11 -P00"),
    (3, 8): _e("-dw2 -P01"), (4, 8): _e("+P00 -P22"), (5, 8): _e("-dw0 +P21"),
    (3, 9): _e("+P22 -P11"), (4, 9): _e("-dw2 +P10"), (5, 9): _e("-dw1 -P20"),
    (3, 10): _e("+dw0 +P12 -P21"), (4, 10): _e("+P20"), (5, 10): _e("-P10"),
    (3, 11): _e("-P21"), (4, 11): _e("+dw1 +P20 -P02"), (5, 11): _e("+P01"),
    (3, 12): _e("+P12"), (4, 12): _e("-P02"), (5, 12): _e("+dw2 +P01 -P10"),
}


_ROWS = {r: [(rc, s) for rc, s in sorted(Y_TABLE.items()) if rc[0] == r] for r in range(6)}
_COLS = {c: [(rc, s) for rc, s in sorted(Y_TABLE.items()) if rc[1] == c] for c in range(13)}


def link_terms(row: int | None = None, col: int | None = None):
    """Non-zero entries of :data:`Y_TABLE` in a row or a column, as ``((row, col), summands)``."""
    if row is not None and col is None:
        return _ROWS[row]
    if col is not None and row is None:
        return _COLS[col]
    return [(rc, s) for rc, s in sorted(Y_TABLE.items())
            if (row is None or rc[0] == row) and (col is None or rc[1] == col)]


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
class VdcParams:
    """Uploaded words of the VDC unit; index 0 Link a, 1 Link b.

    Attributes
    ----------
    K : list of 2 lists of 6 int, GAIN
    rho_T : list of 2 lists of 13 int, RHOT of each parameter's group
    lower, upper : list of 2 lists of 13 int, THETA of each parameter's group
    inv_T : int, INVT (1/period of the backward difference)
    """

    K: list
    rho_T: list
    lower: list
    upper: list
    inv_T: int

    @classmethod
    def from_float(cls, K, rho, lower, upper, period: float) -> VdcParams:
        """Words from float gains (shapes (2, 6), (2, 13), (2, 13), (2, 13)) and period (s)."""
        K = np.asarray(K, dtype=float).reshape(2, 6)
        rho = np.asarray(rho, dtype=float).reshape(2, 13)
        lo = np.asarray(lower, dtype=float).reshape(2, 13)
        hi = np.asarray(upper, dtype=float).reshape(2, 13)
        return cls(
            K=[[GAIN.encode(x) for x in K[i]] for i in range(2)],
            rho_T=[[RHOT[theta_group(j)].encode(rho[i, j] * period) for j in range(13)]
                   for i in range(2)],
            lower=[[THETA[theta_group(j)].encode(lo[i, j]) for j in range(13)] for i in range(2)],
            upper=[[THETA[theta_group(j)].encode(hi[i, j]) for j in range(13)] for i in range(2)],
            inv_T=INVT.encode(1.0 / period),
        )


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

    @staticmethod
    def theta_words(theta) -> list:
        """THETA words of float estimates, shape (2, 13)."""
        t = np.asarray(theta, dtype=float).reshape(2, 13)
        return [[THETA[theta_group(j)].encode(t[i, j]) for j in range(13)] for i in range(2)]

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
