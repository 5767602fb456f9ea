"""The joint controller as an engine program: VDC joint control, PID, torque-only.

The program the node's joint engine runs every control tick
(:class:`~mrm_cosim.hdl.node.joint.JointUnit`), whose register map the master's uploads address
(:func:`~.regs.joint_upload`). Same computation as the bit-exact reference
:class:`~mrm_cosim.hdl.node.joint_ref.JointModel` (equations, formats and the two-part tick are
explained there), statement for statement. Entry points ``"vdc"``,
``"pid"``, ``"torque"``, one per mode; each runs Part A (torque from this tick's measurement)
then Part B (the reference for the next tick).

Input ports (latched by the core at the tick): ``q, qd, tn, tauD, qd0, vd0, ad0``. Output
registers: ``tau`` (FORCE), ``qdr`` (VEL), ``err`` (POS). Uploaded words: the fields of
:class:`JointParams`; state: ``qdes, vdes, ilo_s, ihi_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from functools import lru_cache

from mrm_cosim.units import CLOCK_HZ

from .fixed import (ACC, ANG, CNT, CT, FORCE, GAIN, IHI, IM, IVLC, IVS, KC, KI, KP, LAM, LAMC, POS,
                    SGN, TIME, TS, VEL, VISC)
from .isa import Microcode, Program, T

__all__ = ["MODES", "INPUTS", "JointParams", "build_joint_program", "joint_microcode",
           "joint_param_words"]

#: The joint controller's modes, one entry point each, in the order of CONFIG MODE's values.
MODES = ("vdc", "pid", "torque")
#: The engine's input ports, in port order (latched by the core at the tick).
INPUTS = ("q", "qd", "tn", "tauD", "qd0", "vd0", "ad0")


@dataclass
class JointParams:
    """Uploaded words of the joint engine (see :meth:`from_float` for their meaning)."""

    cT: int
    cTh: int
    Kc: int
    lamc: int
    lam: int
    ivs: int
    ivlc: int
    kj: int
    th0: int
    th1: int
    th2: int
    th3: int
    kp: int
    ki: int
    kd: int
    ilo: int
    ihi: int

    FORMATS = dict(cT=CT, cTh=CT, Kc=KC, lamc=LAMC, lam=LAM, ivs=IVS, ivlc=IVLC, kj=GAIN,
                   th0=IM, th1=VISC, th2=FORCE, th3=FORCE, kp=KP, ki=KI, kd=GAIN, ilo=IHI,
                   ihi=IHI)

    @classmethod
    def from_float(cls, *, counts_per_rev: int = 800_000, clock_hz: float = float(CLOCK_HZ),
                   tick_cycles: int = 50, lam: float = 50.0, k_j: float = 0.0,
                   inertia: float = 0.0, viscous: float = 0.0, coulomb: float = 0.0,
                   offset: float = 0.0, v_smooth: float = 1e-3, k_p: float = 0.0,
                   k_i: float = 0.0, k_d: float = 0.0, i_max: float = 0.0,
                   field: str = "joint") -> JointParams:
        """Words from SI values, refusing any that does not fit (:class:`InputError`).

        Parameters
        ----------
        counts_per_rev : int
        clock_hz : float
        tick_cycles : int
            Cycles per control tick (for the integral gain).
        lam : float, 1/s
            λ of ``q̇_r = q̇_d + λ (q_d − q)``.
        k_j : float, N·m·s/rad
            Joint velocity-error gain.
        inertia, viscous, coulomb, offset : float
            Joint regressor estimates: reflected rotor inertia (kg·m²), viscous (N·m·s/rad),
            Coulomb (N·m) friction and a constant torque (N·m).
        v_smooth : float, rad/s
            Speed over which the smooth sign goes from −1 to 1 (half of it each side).
        k_p, k_i, k_d : float
            PID gains in N·m/rad, N·m/(rad·s), N·m·s/rad.
        i_max : float, rad·s
            Anti-windup bound of the integral of the position error (on its coarse part).
        field : str
            Name used in error messages.
        """
        rad = 2 * math.pi / counts_per_rev          # rad per count
        tick = tick_cycles / clock_hz
        values = dict(cT=1 / clock_hz, cTh=0.5 / clock_hz, Kc=1 / rad, lamc=lam * rad,
                      lam=lam, ivs=1 / v_smooth, ivlc=lam * rad / v_smooth, kj=k_j,
                      th0=inertia, th1=viscous, th2=coulomb, th3=offset, kp=k_p * rad,
                      ki=k_i * rad * tick, kd=k_d, ilo=-i_max / (rad * tick),
                      ihi=i_max / (rad * tick))
        return cls(**{k: cls.FORMATS[k].encode_checked(v, f"{field}.{k}")
                      for k, v in values.items()})

    def words(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


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


def joint_param_words(params: JointParams) -> dict[str, int]:
    """Register words of the uploads, by name."""
    return params.words()
