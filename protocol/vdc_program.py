"""The VDC unit: Link a / Link b required net forces and adaptation as an engine program.

Same computation as :class:`~hdl.node.vdc_ref.VdcModel`, statement for statement (see that
module for the equations and rounding points). Entry points:

* ``"first"`` — prime the derivative history with this period's ``V_rC`` and ``q̇_r`` (so
  ``dV_rC/dt`` and ``q̈_r`` are zero), then fall through into ``"main"``;
* ``"main"`` — rotate Comm B's velocities and gravity into {A}, derive ``dV_rC/dt`` and ``q̈_r``
  by backward difference and carry them across the joint, compute ``F_a, F_b``; MARK (Comm C
  can go); adapt both links' estimates; keep ``V_rC, q̇_r`` for the next period; END.

Register names (host side): Comm B ``qdr, VC0..5, VrC0..5``; snapshot ``qd, cq, sq``; gravity
``gC0..2``; results ``FA0..5, FB0..5`` (output registers 0..11, read for Comm C); estimates
``thA0..12, thB0..12``; uploads ``KA0..5, KB0..5, rA0..12, rB0..12, loA0..12, hiA0..12,
loB0..12, hiB0..12, invT``.
"""

from __future__ import annotations

from functools import lru_cache

from mrm_cosim.protocol.fixed import (ACC, FORCE, GAIN, INVT, RHOT, SIG, THETA, TRIG, VEL,
                                      theta_group)
from mrm_cosim.protocol.isa import Microcode, Program, T

from mrm_cosim.hdl.node.engine import MacEngine
from mrm_cosim.hdl.node.vdc_ref import VdcInputs, VdcModel, link_terms

__all__ = ["build_vdc_program", "vdc_microcode", "VdcUnit", "vdc_input_words",
           "vdc_param_words", "vdc_state_words", "LINKS"]

LINKS = ("A", "B")


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


class VdcUnit(MacEngine):
    """The engine loaded with the VDC program (:func:`vdc_microcode`)."""

    def __init__(self):
        super().__init__(vdc_microcode())


def vdc_input_words(x: VdcInputs) -> dict[str, int]:
    """Register words of one run's inputs, by name."""
    out = {"qdr": x.qd_r, "qd": x.qd, "cq": x.cos_q, "sq": x.sin_q}
    for k in range(6):
        out[f"VC{k}"] = x.V_C[k]
        out[f"VrC{k}"] = x.V_rC[k]
    for k in range(3):
        out[f"gC{k}"] = x.g_C[k]
    return out


def vdc_param_words(model: VdcModel) -> dict[str, int]:
    """Register words of the uploads (gains, adaptation, bounds, 1/T), by name."""
    prm = model.params
    out = {"invT": prm.inv_T}
    for i, L in enumerate(LINKS):
        for k in range(6):
            out[f"K{L}{k}"] = prm.K[i][k]
        for j in range(13):
            out[f"r{L}{j}"] = prm.rho_T[i][j]
            out[f"lo{L}{j}"] = prm.lower[i][j]
            out[f"hi{L}{j}"] = prm.upper[i][j]
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
