"""Bit-exact reference of the node's joint controller, one call per control tick.

The joint controller runs on the joint engine (:mod:`.joint`) every ``tick_cycles`` clock
cycles (50 → 1 MHz), on local measurements: the encoder count ``q`` and velocity estimate
``q̇`` latched at the tick. The master's references come with Comm D, for the period start
``t = 0``: ``q_d0`` (counts), ``q̇_d0``, ``q̈_d0`` and a torque word ``τ_D``. Inside the period the
node interpolates ``q_d(t) = q_d0 + (q̇_d0 + q̈_d0 t/2) t`` and ``q̇_d(t) = q̇_d0 + q̈_d0 t``.

A tick has two parts. Part A uses the reference state ``(q_des, v_des)`` prepared by the
previous tick for *this* tick's time, so the measurement-to-torque path is short:

* ``e = q_des − q`` (counts), ``q̇_r = v_des + λ e`` (λ scaled to rad/count),
  ``q̈_r = q̈_d0 + λ (v_des − q̇)``;
* VDC mode (DESIGN.md joint equation, friction in the joint regressor
  ``[q̈_r, q̇_r, sgn_s(q̇_r), 1]``):
  ``τ = τ_Lr + θ̂_J,0 q̈_r + θ̂_J,1 q̇_r + θ̂_J,2 sgn_s(q̇_r) + θ̂_J,3 + k_j (q̇_r − q̇)`` with
  ``sgn_s(x) = clip(x / v_s, −1, 1)``, the clip being the saturation of the SGN format;
  ``τ_D`` is ``τ_Lr``;
* PID mode: ``τ = τ_D + k_p e + k_i I + k_d (v_des − q̇)`` with the integral ``I`` of the
  previous tick (counts × ticks), then ``I ← I + e``; ``τ_D`` is a feedforward. ``I`` needs
  both a quarter-count resolution and a range of 10^7 counts × ticks, more than one word: it
  is kept exactly as ``I = I_hi + I_lo``, ``I_lo`` fine (POS) and ``I_hi`` coarse (IHI,
  1024 counts × ticks): ``c = round(I_lo + e)`` onto IHI, ``I_lo ← I_lo + e − c``,
  ``I_hi ← clip(I_hi + c, I_min, I_max)`` (anti-windup on the coarse part);
* torque mode: ``τ = τ_D`` (the master's torque, the paper's "PID with 1000 Hz").

Part B prepares ``(q_des, v_des)`` for the next tick at ``t_next`` cycles after the period start
(an input), with the clock period ``T_c``: ``t = t_next T_c``, ``v_des = q̇_d0 + q̈_d0 t``,
``q_des = q_d0 + K_c (q̇_d0 + q̈_d0 t/2) t``. So a new Comm D takes effect one tick after it
is latched. Torque limits and the watchdog's ramp act after the engine (:mod:`.watchdog`).

Each rounding point is one ``fx`` below (exact sum, one rounding half up, saturation); the
formats are in :mod:`mrm_cosim.protocol.fixed`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

from mrm_cosim.protocol.fixed import (
    ACC,
    ANG,
    CNT,
    CT,
    FORCE,
    GAIN,
    IHI,
    IM,
    IVLC,
    IVS,
    KC,
    LAM,
    LAMC,
    POS,
    SGN,
    TIME,
    TS,
    VEL,
    VISC,
    saturate,
)
from mrm_cosim.protocol.joint_program import MODES, JointParams, pid_formats

from .vdc_ref import fx_point

__all__ = ["JointInputs", "JointModel", "joint_input_words", "joint_state_words"]


@dataclass
class JointInputs:
    """Engine inputs latched at a tick (words).

    Attributes
    ----------
    q : int — encoder count (saturated to 24 bits, CNT)
    qd : int — velocity estimate (VEL)
    tn : int — cycles from the period start to the *next* tick (TIME)
    tau_D, qd0, vd0, ad0 : int — Comm D: torque (FORCE), q_d0 (POS), q̇_d0 (VEL), q̈_d0 (ACC)
    """

    q: int
    qd: int
    tn: int
    tau_D: int
    qd0: int
    vd0: int
    ad0: int


# The rounding points of a tick (each an ``fx``: exact sum, one rounding half up onto the
# destination format, saturation to 24 bits), destination first, then each summand's LSB.
# Part A:
_E = fx_point(POS, POS.lsb, CNT.lsb)                                    # e = q_des − q
_QDR = fx_point(VEL, VEL.lsb, LAMC.lsb + POS.lsb)                       # q̇_r = v_des + λ e
_QDDR = fx_point(ACC, ACC.lsb, LAM.lsb + VEL.lsb)                       # q̈_d0 + λ (v_des − q̇)
_SG = fx_point(SGN, IVS.lsb + VEL.lsb, IVLC.lsb + POS.lsb)              # sgn_s(q̇_r)
_TAU_VDC = fx_point(FORCE, FORCE.lsb, IM.lsb + ACC.lsb, VISC.lsb + VEL.lsb,
                    FORCE.lsb + SGN.lsb, GAIN.lsb + VEL.lsb)


@cache
def _tau_pid(pid_shift: int):
    """The PID torque's rounding point of a node built with PID gain shift ``pid_shift``."""
    f = pid_formats(pid_shift)
    return fx_point(FORCE, FORCE.lsb, f["kp"].lsb + POS.lsb, f["ki"].lsb + POS.lsb,
                    f["ki"].lsb + IHI.lsb, f["kd"].lsb + VEL.lsb)


_I_CARRY = fx_point(IHI, POS.lsb, POS.lsb, CNT.lsb)                     # c = round(I_lo + e)
_I_LO = fx_point(POS, POS.lsb, POS.lsb, CNT.lsb, IHI.lsb)               # I_lo + e − c
_I_HI = fx_point(IHI, IHI.lsb, IHI.lsb)                                 # I_hi + c
_TAU_D = fx_point(FORCE, FORCE.lsb)
# Part B:
_TS = fx_point(TS, TIME.lsb + CT.lsb)                                   # t = t_next T_c
_VD = fx_point(VEL, VEL.lsb, ACC.lsb + TS.lsb)                          # q̇_d0 + q̈_d0 t
_DQ = fx_point(ANG, VEL.lsb + TS.lsb)                                   # (q̇_d0 + q̈_d0 t/2) t
_QD = fx_point(POS, POS.lsb, ANG.lsb + KC.lsb)                          # q_d0 + K_c Δq


@dataclass
class JointModel:
    """State and tick of the joint controller.

    A tick is :meth:`part_a` then :meth:`part_b` (:meth:`tick` does both). The parts are
    separate methods because a transaction-level caller (the ``model`` backend) runs Part B
    alone for a tick whose torque nobody observes, and Part A later.

    Attributes
    ----------
    params : JointParams
    q_des, v_des : int
        Reference for the coming tick (POS, VEL), prepared by Part B.
    i_lo, i_hi : int
        PID integral of the position error, fine (POS) and coarse (IHI) parts.
    """

    params: JointParams
    q_des: int = 0
    v_des: int = 0
    i_lo: int = 0
    i_hi: int = 0

    def tick(self, mode: str, x: JointInputs) -> tuple[int, int, int]:
        """One tick; returns ``(τ, q̇_r, e)`` words (FORCE, VEL, POS)."""
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, not {mode!r}")
        out = self.part_a(MODES.index(mode), x.q, x.qd, x.tau_D, x.ad0)
        self.part_b(x.tn, x.qd0, x.vd0, x.ad0)
        return out

    def part_a(self, mode: int, q: int, qd: int, tau_D: int, ad0: int) -> tuple[int, int, int]:
        """Part A from the reference ``(q_des, v_des)`` the previous tick prepared: the
        torque and, in PID mode, the integral's update. ``mode`` indexes :data:`MODES`;
        ``q`` the count (saturated here), ``qd`` the velocity word, ``tau_D``, ``ad0`` the
        committed Comm D's torque and ``q̈_d0``. Returns ``(τ, q̇_r, e)`` (FORCE, VEL, POS)."""
        p = self.params
        q = saturate(q)
        e = _E(self.q_des, -q)
        qdr = _QDR(self.v_des, p.lamc * e)
        if mode == 0:                                                   # VDC
            qddr = _QDDR(ad0, p.lam * (self.v_des - qd))
            sg = _SG(p.ivs * self.v_des, p.ivlc * e)
            tau = _TAU_VDC(tau_D + p.th3, p.th0 * qddr, p.th1 * qdr, p.th2 * sg,
                           p.kj * (qdr - qd))
        elif mode == 1:                                                 # PID
            tau = _tau_pid(p.pid_shift)(tau_D, p.kp * e, p.ki * self.i_lo, p.ki * self.i_hi,
                           p.kd * (self.v_des - qd))
            self.pid_integral(q)
        else:                                                           # torque
            tau = _TAU_D(tau_D)
        return tau, qdr, e

    def pid_integral(self, q: int) -> None:
        """The PID integral's update of Part A alone, ``I ← I + e`` for the count ``q``
        (saturated here): what a PID tick whose torque nobody observes still has to do."""
        q = saturate(q)
        c = _I_CARRY(self.i_lo, self.q_des, -q)
        self.i_lo = _I_LO(self.i_lo, self.q_des, -q, -c)
        p = self.params
        self.i_hi = min(max(_I_HI(self.i_hi, c), p.ilo), p.ihi)

    def part_b(self, tn: int, qd0: int, vd0: int, ad0: int) -> None:
        """Part B: the reference ``(q_des, v_des)`` for the next tick, ``tn`` cycles after the
        start of the period the Comm D words ``q_d0, q̇_d0, q̈_d0`` are for (TIME, POS, VEL,
        ACC)."""
        p = self.params
        ts = _TS(tn * p.cT)
        tsh = _TS(tn * p.cTh)
        self.v_des = _VD(vd0, ad0 * ts)
        h = _VD(vd0, ad0 * tsh)
        dq = _DQ(h * ts)
        self.q_des = _QD(qd0, dq * p.Kc)


def joint_input_words(x: JointInputs) -> list[int]:
    """Input-port words in port order (:data:`~mrm_cosim.protocol.joint_program.INPUTS`)."""
    return [x.q, x.qd, x.tn, x.tau_D, x.qd0, x.vd0, x.ad0]


def joint_state_words(model: JointModel) -> dict[str, int]:
    """Register words of the state (reference for the next tick, PID integral), by name."""
    return {"qdes": model.q_des, "vdes": model.v_des, "ilo_s": model.i_lo, "ihi_s": model.i_hi}
