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
from functools import cache

from mrm_cosim.units import CLOCK_HZ

from .fixed import (ACC, ANG, CNT, CT, FORCE, GAIN, IHI, IM, IVLC, IVS, KC, KD, KI, KP, LAM, LAMC,
                    POS, SGN, TIME, TS, VEL, VISC, Fmt)
from .isa import Microcode, Program, T

__all__ = ["MODES", "INPUTS", "PID_SHIFT_MAX", "pid_formats", "pid_shifts_per_node",
           "JointParams",
           "build_joint_program", "joint_microcode", "joint_param_words"]

#: The joint controller's modes, one entry point each, in the order of CONFIG MODE's values.
MODES = ("vdc", "pid", "torque")
#: The engine's input ports, in port order (latched by the core at the tick).
INPUTS = ("q", "qd", "tn", "tauD", "qd0", "vd0", "ad0")

#: Largest PID gain shift a node is built with. At shift 12 the KP word reaches ±2048
#: N·m/count: one count of error would already saturate the ±1024 N·m torque word (FORCE),
#: so a coarser KP could only hold gains that act as a bang-bang switch.
PID_SHIFT_MAX = 12


@cache
def pid_formats(shift: int = 0) -> dict[str, Fmt]:
    """The PID gain words' formats of a node built with PID gain shift ``shift``
    (0..:data:`PID_SHIFT_MAX`): ``kp`` (KP), ``ki`` (KI) and ``kd`` (KD), each ``2^shift``
    coarser than at shift 0, so their range grows by ``2^shift`` and their relative
    resolution stays 23 bits of the largest gain they hold.

    The PID gains scale with the joint's inertia and the square (k_p), cube (k_i) or first
    power (k_d) of the closed loop's bandwidth, over four decades between a wrist and the
    first joint of a long arm; one set of formats cannot hold them all with useful resolution.
    The shift is a build parameter of the node (it only moves the joint program's shifts,
    :mod:`.isa`: the same engine, the same cost), chosen per module by the master
    (:func:`mrm_cosim.master.uploads.pid_shifts`)."""
    if not isinstance(shift, int) or isinstance(shift, bool) or not 0 <= shift <= PID_SHIFT_MAX:
        raise ValueError(f"pid_shift must be an integer 0..{PID_SHIFT_MAX}, not {shift!r}")
    return {name: Fmt(f.name, f.lsb + shift, f.unit)
            for name, f in (("kp", KP), ("ki", KI), ("kd", KD))}


@dataclass
class JointParams:
    """Uploaded words of the joint engine (see :meth:`from_float` for their meaning), and the
    PID gain shift of the node they are for (:func:`pid_formats`; not a word: the node is
    built with it)."""

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
    pid_shift: int = 0

    #: Formats of the words at PID gain shift 0 (:meth:`formats` for any shift).
    FORMATS = dict(cT=CT, cTh=CT, Kc=KC, lamc=LAMC, lam=LAM, ivs=IVS, ivlc=IVLC, kj=GAIN,
                   th0=IM, th1=VISC, th2=FORCE, th3=FORCE, kp=KP, ki=KI, kd=KD, ilo=IHI,
                   ihi=IHI)

    @classmethod
    def zero(cls, pid_shift: int = 0) -> JointParams:
        """All words zero (a node's registers after reset), for a node built with PID gain
        shift ``pid_shift``."""
        pid_formats(pid_shift)                  # validates
        return cls(**dict.fromkeys(cls.FORMATS, 0), pid_shift=pid_shift)

    @classmethod
    def formats(cls, pid_shift: int = 0) -> dict[str, Fmt]:
        """Formats of the words of a node built with PID gain shift ``pid_shift``."""
        return {**cls.FORMATS, **pid_formats(pid_shift)}

    @classmethod
    def from_float(cls, *, counts_per_rev: int = 800_000, clock_hz: float = float(CLOCK_HZ),
                   tick_cycles: int = 50, lam: float = 50.0, k_j: float = 0.0,
                   inertia: float = 0.0, viscous: float = 0.0, coulomb: float = 0.0,
                   offset: float = 0.0, v_smooth: float = 1e-3, k_p: float = 0.0,
                   k_i: float = 0.0, k_d: float = 0.0, i_max: float = 0.0,
                   pid_shift: int = 0, field: str = "joint") -> JointParams:
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
        pid_shift : int
            The node's PID gain shift (:func:`pid_formats`).
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
        fmts = cls.formats(pid_shift)
        return cls(**{k: fmts[k].encode_checked(v, f"{field}.{k}") for k, v in values.items()},
                   pid_shift=pid_shift)

    def words(self) -> dict[str, int]:
        """The uploaded words by register name (everything but :attr:`pid_shift`)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "pid_shift"}


def pid_shifts_per_node(pid_shift, n: int) -> list[int]:
    """``pid_shift`` as one PID gain shift per node: a list or tuple of ``n`` (node 1 first),
    or one shift for every node (validated, :func:`pid_formats`)."""
    shifts = (list(pid_shift) if isinstance(pid_shift, list | tuple) else [pid_shift] * n)
    if len(shifts) != n:
        raise ValueError(f"pid_shift: {len(shifts)} shifts for {n} nodes")
    for s in shifts:
        pid_formats(s)
    return shifts


def build_joint_program(pid_shift: int = 0) -> Program:
    """The joint program of a node built with PID gain shift ``pid_shift``."""
    p = Program("joint", depth=64)
    for name, fmt in zip(INPUTS, (CNT, VEL, TIME, FORCE, POS, VEL, ACC), strict=True):
        p.reg(name, fmt, "input")
    p.reg("tau", FORCE, "output")
    p.reg("qdr_o", VEL, "output")
    p.reg("err_o", POS, "output")
    for name, fmt in JointParams.formats(pid_shift).items():
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


@cache
def joint_microcode(pid_shift: int = 0) -> Microcode:
    """The compiled joint program of a node built with PID gain shift ``pid_shift`` (built
    once per shift). Its register addresses and the cycles of each entry point do not depend
    on the shift (tests/test_joint.py), only the PID statements' product and output shifts."""
    return build_joint_program(pid_shift).compile()


def joint_param_words(params: JointParams) -> dict[str, int]:
    """Register words of the uploads, by name."""
    return params.words()
