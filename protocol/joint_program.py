"""The joint controller as an engine program: VDC joint control, PID, torque-only.

Same computation as :class:`~hdl.node.joint_ref.JointModel` (equations, formats and the
two-part tick are explained there), statement for statement. Entry points ``"vdc"``,
``"pid"``, ``"torque"``, one per mode; each runs Part A (torque from this tick's measurement)
then Part B (the reference for the next tick).

Input ports (latched by the core at the tick): ``q, qd, tn, tauD, qd0, vd0, ad0``. Output
registers: ``tau`` (FORCE), ``qdr`` (VEL), ``err`` (POS). Uploaded words: the fields of
:class:`~hdl.node.joint_ref.JointParams`; state: ``qdes, vdes, ilo_s, ihi_s``.
"""

from __future__ import annotations

from functools import lru_cache

from mrm_cosim.hdl.node.engine import MacEngine
from mrm_cosim.protocol.fixed import ACC, ANG, CNT, FORCE, IHI, POS, SGN, TIME, TS, VEL
from mrm_cosim.protocol.isa import Microcode, Program, T
from mrm_cosim.hdl.node.joint_ref import MODES, JointInputs, JointModel, JointParams

__all__ = ["build_joint_program", "joint_microcode", "JointUnit", "joint_input_words",
           "joint_param_words", "joint_state_words", "INPUTS"]

INPUTS = ("q", "qd", "tn", "tauD", "qd0", "vd0", "ad0")


def build_joint_program() -> Program:
    p = Program("joint", depth=64)
    for name, fmt in zip(INPUTS, (CNT, VEL, TIME, FORCE, POS, VEL, ACC), strict=True):
        p.reg(name, fmt, "input")
    p.reg("tau", FORCE, "output")
    p.reg("qdr_o", VEL, "output")
    p.reg("err_o", POS, "output")
    for name, fmt in JointParams.FORMATS.items():
        p.reg(name, fmt, "param")
    p.reg("qdes", POS, "state")
    p.reg("vdes", VEL, "state")
    p.reg("ilo_s", POS, "state")
    p.reg("ihi_s", IHI, "state")
    for name, fmt in (("e", POS), ("qdr", VEL), ("qddr", ACC), ("sg", SGN),
                      ("icar", IHI), ("ihs", IHI), ("imx", IHI), ("ts", TS), ("tsh", TS),
                      ("h", VEL), ("dq", ANG)):
        p.reg(name, fmt)

    def part_a(mode):
        p.mac("e", [T("qdes"), -T("q")])
        p.mac("err_o", [T("e")])
        p.mac("qdr", [T("vdes"), T("lamc", "e")])
        p.mac("qdr_o", [T("qdr")])
        if mode == "vdc":
            p.mac("qddr", [T("ad0"), T("lam", "vdes"), -T("lam", "qd")])
            p.mac("sg", [T("ivs", "vdes"), T("ivlc", "e")])
            p.mac("tau", [T("tauD"), T("th0", "qddr"), T("th1", "qdr"), T("th2", "sg"),
                          T("th3"), T("kj", "qdr"), -T("kj", "qd")])
        elif mode == "pid":
            p.mac("tau", [T("tauD"), T("kp", "e"), T("ki", "ilo_s"), T("ki", "ihi_s"),
                          T("kd", "vdes"), -T("kd", "qd")])
            p.mac("icar", [T("ilo_s"), T("qdes"), -T("q")])
            p.mac("ilo_s", [T("ilo_s"), T("qdes"), -T("q"), -T("icar")])
            p.mac("ihs", [T("ihi_s"), T("icar")])
            p.max("imx", "ihs", "ilo")
            p.min("ihi_s", "imx", "ihi")
        else:
            p.mac("tau", [T("tauD")])

    def part_b():
        p.mac("ts", [T("tn", "cT")])
        p.mac("tsh", [T("tn", "cTh")])
        p.mac("vdes", [T("vd0"), T("ad0", "ts")])
        p.mac("h", [T("vd0"), T("ad0", "tsh")])
        p.mac("dq", [T("h", "ts")])
        p.mac("qdes", [T("qd0"), T("dq", "Kc")])

    for mode in MODES:
        p.entry(mode)
        part_a(mode)
        part_b()
        p.end()
    return p


@lru_cache(maxsize=1)
def joint_microcode() -> Microcode:
    """The compiled joint program (built once)."""
    return build_joint_program().compile()


class JointUnit(MacEngine):
    """The engine loaded with the joint program (:func:`joint_microcode`)."""

    def __init__(self):
        super().__init__(joint_microcode())


def joint_input_words(x: JointInputs) -> list[int]:
    """Input-port words in port order."""
    return [x.q, x.qd, x.tn, x.tau_D, x.qd0, x.vd0, x.ad0]


def joint_param_words(params: JointParams) -> dict[str, int]:
    return params.words()


def joint_state_words(model: JointModel) -> dict[str, int]:
    return {"qdes": model.q_des, "vdes": model.v_des, "ilo_s": model.i_lo, "ihi_s": model.i_hi}
