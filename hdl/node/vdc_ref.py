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

from mrm_cosim.protocol.fixed import (ACC, FORCE, GAIN, INVT, RHOT, SIG, THETA, TRIG, VEL,
                                      round_shift, saturate, theta_group)
from mrm_cosim.protocol.vdc_program import LINKS, VdcParams, link_terms

__all__ = ["fx", "VdcInputs", "VdcModel", "vdc_input_words", "vdc_state_words"]


def fx(parts, fmt, wrap: bool = False) -> int:
    """Round ``Σ v · 2^lsb`` (``parts`` = [(v, lsb)]) half up onto ``fmt`` and saturate."""
    L = min([lsb for _, lsb in parts] + [fmt.lsb])
    total = sum(v << (lsb - L) for v, lsb in parts)
    return saturate(round_shift(total, fmt.lsb - L))


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


def _rot_t(c: int, s: int, x0: int, x1: int, fmt) -> tuple[int, int]:
    """First two components of ``Rz(q)ᵀ x``: ``(c x0 + s x1, −s x0 + c x1)``."""
    lsb = TRIG.lsb + fmt.lsb
    return fx([(c * x0, lsb), (s * x1, lsb)], fmt), fx([(-s * x0, lsb), (c * x1, lsb)], fmt)


def _link_a(c: int, s: int, V: list, qd: int) -> list[int]:
    """``Rz(q)ᵀ`` per block plus ``z q̇``, VEL words."""
    v0, v1 = _rot_t(c, s, V[0], V[1], VEL)
    w0, w1 = _rot_t(c, s, V[3], V[4], VEL)
    w2 = fx([(V[5], VEL.lsb), (qd, VEL.lsb)], VEL)
    return [v0, v1, V[2], w0, w1, w2]


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
        a = [fx([(dV[k], ACC.lsb), (V[3 + (k + 1) % 3] * V_r[(k + 2) % 3], 2 * VEL.lsb),
                 (-V[3 + (k + 2) % 3] * V_r[(k + 1) % 3], 2 * VEL.lsb), (g[k], ACC.lsb)], ACC)
             for k in range(3)]
        P = {10 * m + n: fx([(V[3 + m] * V_r[3 + n], 2 * VEL.lsb)], ACC)
             for m in range(3) for n in range(3)}
        dw = dV[3:]
        e = [fx([(V_r[k], VEL.lsb), (-V[k], VEL.lsb)], VEL) for k in range(6)]

        def y(parts):
            return sum(sgn * {"a": a, "P": P, "dw": dw}[kind][idx] for sgn, kind, idx in parts)

        F = []
        for row in range(6):
            parts = [(y(s) * th[col], ACC.lsb + THETA[theta_group(col)].lsb)
                     for (_, col), s in link_terms(row=row)]
            parts.append((self.params.K[i][row] * e[row], GAIN.lsb + VEL.lsb))
            F.append(fx(parts, FORCE))
        sig = [fx([(y(s) * e[row], ACC.lsb + VEL.lsb) for (row, _), s in link_terms(col=col)],
                  SIG) for col in range(13)]
        new = []
        for j in range(13):
            fmt = THETA[theta_group(j)]
            delta = fx([(self.params.rho_T[i][j] * sig[j], RHOT[theta_group(j)].lsb + SIG.lsb)],
                       fmt)
            t = fx([(th[j], fmt.lsb), (delta, fmt.lsb)], fmt)
            new.append(min(max(t, self.params.lower[i][j]), self.params.upper[i][j]))
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
        lsb = VEL.lsb + INVT.lsb
        dC = [fx([(x.V_rC[k] * inv_T, lsb), (-self.prev_C[k] * inv_T, lsb)], ACC)
              for k in range(6)]
        qdd_r = fx([(x.qd_r * inv_T, lsb), (-self.prev_qd_r * inv_T, lsb)], ACC)
        # Across the joint: dV_rA = Rᵀ dV_rC − q̇ (ẑ×)(Rᵀ V_rC) + z q̈_r; (ẑ×)(x, y, z) = (−y, x, 0).
        lr, lq = TRIG.lsb + ACC.lsb, 2 * VEL.lsb
        dA = [0] * 6
        for base in (0, 3):
            d0, d1 = dC[base], dC[base + 1]
            dA[base] = fx([(c * d0, lr), (s * d1, lr), (x.qd * V_rA[base + 1], lq)], ACC)
            dA[base + 1] = fx([(-s * d0, lr), (c * d1, lr), (-x.qd * V_rA[base], lq)], ACC)
        dA[2] = dC[2]
        dA[5] = fx([(dC[5], ACC.lsb), (qdd_r, ACC.lsb)], ACC)
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
