"""The VDC unit's program and uploads: Link a / Link b required net forces and adaptation.

What the node's VDC unit computes, as an engine program (:mod:`.isa`) that the gateware runs
(:class:`~mrm_cosim.hdl.node.vdc.VdcUnit`) and whose register map the master's uploads address
(:func:`~.regs.vdc_upload`). Same computation as the bit-exact reference
:class:`~mrm_cosim.hdl.node.vdc_ref.VdcModel`, statement for statement (see that module for the
equations and rounding points). Entry points:

* ``"first"`` — prime the derivative history with this period's ``V_rC`` and ``q̇_r`` (so
  ``dV_rC/dt`` and ``q̈_r`` are zero), then fall through into ``"main"``;
* ``"main"`` — rotate Comm B's velocities and gravity into {A}, derive ``dV_rC/dt`` and ``q̈_r``
  by backward difference and carry them across the joint, compute ``F_a, F_b``; MARK (Comm C
  can go); adapt both links' estimates; keep ``V_rC, q̇_r`` for the next period; END.

Register names (host side): Comm B ``qdr, VC0..5, VrC0..5``; snapshot ``qd, cq, sq``; gravity
``gC0..2``; results ``FA0..5, FB0..5`` (output registers 0..11, read for Comm C); estimates
``thA0..12, thB0..12``; uploads ``KA0..5, KB0..5, rA0..12, rB0..12, loA0..12, hiA0..12,
loB0..12, hiB0..12, invT`` (:class:`VdcParams`).

The regressor ``Y(ω, V_r, dV_r/dt, g)`` is used through :data:`Y_TABLE`: each non-zero entry
is an exact sum of ± words ``a_i`` (``a = dv_r + ω × v_r + g``), ``P_ij = ω_i ω_r,j`` and
``dw_i`` (the required angular acceleration). Entries are never rounded on their own: the
engine multiplies each summand by ``θ̂_j`` (or by the velocity error) directly.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .fixed import ACC, FORCE, GAIN, INVT, RHOT, SIG, THETA, TRIG, VEL, theta_group
from .isa import Microcode, Program, T

__all__ = ["N_PARAMS", "LINKS", "Y_TABLE", "link_terms", "VdcParams", "theta_words",
           "build_vdc_program", "vdc_microcode", "vdc_param_words"]

#: Inertial parameters per link (MRM Table 1 order): mass, first moments, second moments.
N_PARAMS = 13
#: Register-name letter of each link: ``A`` Link a (in {A}), ``B`` Link b (in {C}).
LINKS = ("A", "B")


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
        rho = np.asarray(rho, dtype=float).reshape(2, N_PARAMS)
        lo = np.asarray(lower, dtype=float).reshape(2, N_PARAMS)
        hi = np.asarray(upper, dtype=float).reshape(2, N_PARAMS)
        return cls(
            K=[[GAIN.encode(x) for x in K[i]] for i in range(2)],
            rho_T=[[RHOT[theta_group(j)].encode(rho[i, j] * period) for j in range(N_PARAMS)]
                   for i in range(2)],
            lower=[[THETA[theta_group(j)].encode(lo[i, j]) for j in range(N_PARAMS)]
                   for i in range(2)],
            upper=[[THETA[theta_group(j)].encode(hi[i, j]) for j in range(N_PARAMS)]
                   for i in range(2)],
            inv_T=INVT.encode(1.0 / period),
        )


def theta_words(theta) -> list:
    """THETA words of float estimates, shape (2, 13): Link a, then Link b."""
    t = np.asarray(theta, dtype=float).reshape(2, N_PARAMS)
    return [[THETA[theta_group(j)].encode(t[i, j]) for j in range(N_PARAMS)] for i in range(2)]


def build_vdc_program() -> Program:
    """The VDC program (see the module docstring)."""
    p = Program("vdc")
    r = p.reg
    for n in ["qdr", "qd"] + [f"VC{k}" for k in range(6)] + [f"VrC{k}" for k in range(6)]:
        r(n, VEL, "host")
    r("cq", TRIG, "host")
    r("sq", TRIG, "host")
    for k in range(3):
        r(f"gC{k}", ACC, "host")
    r("invT", INVT, "param")
    for L in LINKS:
        for k in range(6):
            r(f"K{L}{k}", GAIN, "param")
        for j in range(13):
            g = theta_group(j)
            r(f"th{L}{j}", THETA[g], "state")
            r(f"r{L}{j}", RHOT[g], "param")
            r(f"lo{L}{j}", THETA[g], "param")
            r(f"hi{L}{j}", THETA[g], "param")
            r(f"s{L}{j}", SIG)
            r(f"D{L}{j}", THETA[g])
            r(f"t{L}{j}", THETA[g])
        for k in range(6):
            r(f"F{L}{k}", FORCE, "output")
            r(f"e{L}{k}", VEL)
        for k in range(3):
            r(f"a{L}{k}", ACC)
            for n in range(3):
                r(f"P{L}{k}{n}", ACC)
    r("pqdr", VEL, "state")
    r("qddr", ACC)
    for k in range(6):
        r(f"pC{k}", VEL, "state")
        r(f"dC{k}", ACC)
    for k in (0, 1, 3, 4, 5):
        r(f"dA{k}", ACC)
    for k in (0, 1, 3, 4, 5):
        r(f"VA{k}", VEL)
        r(f"VrA{k}", VEL)
    r("gA0", ACC)
    r("gA1", ACC)

    # Names of the vectors of each link ({A}: rotated; third linear component unchanged).
    vec = {
        "A": dict(V=["VA0", "VA1", "VC2", "VA3", "VA4", "VA5"],
                  Vr=["VrA0", "VrA1", "VrC2", "VrA3", "VrA4", "VrA5"],
                  dV=["dA0", "dA1", "dC2", "dA3", "dA4", "dA5"], g=["gA0", "gA1", "gC2"]),
        "B": dict(V=[f"VC{k}" for k in range(6)], Vr=[f"VrC{k}" for k in range(6)],
                  dV=[f"dC{k}" for k in range(6)], g=["gC0", "gC1", "gC2"]),
    }

    def rotate(dst0, dst1, x0, x1):
        p.mac(dst0, [T("cq", x0), T("sq", x1)])
        p.mac(dst1, [-T("sq", x0), T("cq", x1)])

    def link_a(dst, src, rate):
        rotate(dst[0], dst[1], src[0], src[1])
        rotate(dst[3], dst[4], src[3], src[4])
        p.mac(dst[5], [T(src[5]), T(rate)])

    p.entry("first")
    for k in range(6):
        p.mac(f"pC{k}", [T(f"VrC{k}")])
    p.mac("pqdr", [T("qdr")])

    p.entry("main")
    link_a(vec["A"]["V"], vec["B"]["V"], "qd")
    link_a(vec["A"]["Vr"], vec["B"]["Vr"], "qdr")
    rotate("gA0", "gA1", "gC0", "gC1")
    for k in range(6):
        p.mac(f"dC{k}", [T(f"VrC{k}", "invT"), -T(f"pC{k}", "invT")])
    p.mac("qddr", [T("qdr", "invT"), -T("pqdr", "invT")])
    # Across the joint: dV_rA = Rᵀ dV_rC − q̇ (ẑ×)(Rᵀ V_rC) + z q̈_r.
    VrA = vec["A"]["Vr"]
    for base in (0, 3):
        p.mac(f"dA{base}", [T("cq", f"dC{base}"), T("sq", f"dC{base + 1}"),
                            T("qd", VrA[base + 1])])
        p.mac(f"dA{base + 1}", [-T("sq", f"dC{base}"), T("cq", f"dC{base + 1}"),
                                -T("qd", VrA[base])])
    p.mac("dA5", [T("dC5"), T("qddr")])

    def summand(L, kind, idx):
        if kind == "a":
            return f"a{L}{idx}"
        if kind == "P":
            return f"P{L}{idx // 10}{idx % 10}"
        return vec[L]["dV"][3 + idx]

    for L in LINKS:
        V, Vr, dV, g = vec[L]["V"], vec[L]["Vr"], vec[L]["dV"], vec[L]["g"]
        for k in range(3):
            p.mac(f"a{L}{k}", [T(dV[k]), T(V[3 + (k + 1) % 3], Vr[(k + 2) % 3]),
                               -T(V[3 + (k + 2) % 3], Vr[(k + 1) % 3]), T(g[k])])
            for n in range(3):
                p.mac(f"P{L}{k}{n}", [T(V[3 + k], Vr[3 + n])])
        for k in range(6):
            p.mac(f"e{L}{k}", [T(Vr[k]), -T(V[k])])
        for row in range(6):
            terms = []
            for (_, col), parts in link_terms(row=row):
                for sgn, kind, idx in parts:
                    t = T(summand(L, kind, idx), f"th{L}{col}")
                    terms.append(t if sgn > 0 else -t)
            terms.append(T(f"K{L}{row}", f"e{L}{row}"))
            p.mac(f"F{L}{row}", terms)
    p.mark()
    for L in LINKS:
        for col in range(13):
            terms = []
            for (row, _), parts in link_terms(col=col):
                for sgn, kind, idx in parts:
                    t = T(summand(L, kind, idx), f"e{L}{row}")
                    terms.append(t if sgn > 0 else -t)
            p.mac(f"s{L}{col}", terms)
            p.mac(f"D{L}{col}", [T(f"r{L}{col}", f"s{L}{col}")])
            p.mac(f"t{L}{col}", [T(f"th{L}{col}"), T(f"D{L}{col}")])
            p.clamp(f"th{L}{col}", f"t{L}{col}", f"lo{L}{col}", f"hi{L}{col}")
    for k in range(6):
        p.mac(f"pC{k}", [T(f"VrC{k}")])
    p.mac("pqdr", [T("qdr")])
    p.end()
    return p


@lru_cache(maxsize=1)
def vdc_microcode() -> Microcode:
    """The compiled VDC program (built once)."""
    return build_vdc_program().compile()


def vdc_param_words(prm: VdcParams) -> dict[str, int]:
    """Register words of the uploads (gains, adaptation, bounds, 1/T), by name."""
    out = {"invT": prm.inv_T}
    for i, L in enumerate(LINKS):
        for k in range(6):
            out[f"K{L}{k}"] = prm.K[i][k]
        for j in range(13):
            out[f"r{L}{j}"] = prm.rho_T[i][j]
            out[f"lo{L}{j}"] = prm.lower[i][j]
            out[f"hi{L}{j}"] = prm.upper[i][j]
    return out
