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

from mrm_cosim.protocol.fixed import (ACC, ANG, CNT, CT, FORCE, GAIN, IHI, IM, IVLC, IVS, KC, KI,
                                      KP, LAM, LAMC, POS, SGN, TIME, TS, VEL, VISC, saturate)
from mrm_cosim.protocol.joint_program import MODES, JointParams

from .vdc_ref import fx

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


@dataclass
class JointModel:
    """State and tick of the joint controller.

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
        p = self.params
        q = saturate(x.q)
        e = fx([(self.q_des, POS.lsb), (-q, CNT.lsb)], POS)
        qdr = fx([(self.v_des, VEL.lsb), (p.lamc * e, LAMC.lsb + POS.lsb)], VEL)
        if mode == "vdc":
            lq = LAM.lsb + VEL.lsb
            qddr = fx([(x.ad0, ACC.lsb), (p.lam * self.v_des, lq), (-p.lam * x.qd, lq)], ACC)
            sg = fx([(p.ivs * self.v_des, IVS.lsb + VEL.lsb), (p.ivlc * e, IVLC.lsb + POS.lsb)],
                    SGN)
            tau = fx([(x.tau_D, FORCE.lsb), (p.th0 * qddr, IM.lsb + ACC.lsb),
                      (p.th1 * qdr, VISC.lsb + VEL.lsb), (p.th2 * sg, FORCE.lsb + SGN.lsb),
                      (p.th3, FORCE.lsb), (p.kj * qdr, GAIN.lsb + VEL.lsb),
                      (-p.kj * x.qd, GAIN.lsb + VEL.lsb)], FORCE)
        elif mode == "pid":
            tau = fx([(x.tau_D, FORCE.lsb), (p.kp * e, KP.lsb + POS.lsb),
                      (p.ki * self.i_lo, KI.lsb + POS.lsb), (p.ki * self.i_hi, KI.lsb + IHI.lsb),
                      (p.kd * self.v_des, GAIN.lsb + VEL.lsb), (-p.kd * x.qd, GAIN.lsb + VEL.lsb)],
                     FORCE)
            s = [(self.i_lo, POS.lsb), (self.q_des, POS.lsb), (-q, CNT.lsb)]   # I_lo + e
            c = fx(s, IHI)
            self.i_lo = fx(s + [(-c, IHI.lsb)], POS)
            hi = fx([(self.i_hi, IHI.lsb), (c, IHI.lsb)], IHI)
            self.i_hi = min(max(hi, p.ilo), p.ihi)
        else:
            tau = fx([(x.tau_D, FORCE.lsb)], FORCE)
        # Part B: the reference for the next tick.
        ts = fx([(x.tn * p.cT, TIME.lsb + CT.lsb)], TS)
        tsh = fx([(x.tn * p.cTh, TIME.lsb + CT.lsb)], TS)
        self.v_des = fx([(x.vd0, VEL.lsb), (x.ad0 * ts, ACC.lsb + TS.lsb)], VEL)
        h = fx([(x.vd0, VEL.lsb), (x.ad0 * tsh, ACC.lsb + TS.lsb)], VEL)
        dq = fx([(h * ts, VEL.lsb + TS.lsb)], ANG)
        self.q_des = fx([(x.qd0, POS.lsb), (dq * p.Kc, ANG.lsb + KC.lsb)], POS)
        return tau, qdr, e


def joint_input_words(x: JointInputs) -> list[int]:
    """Input-port words in port order (:data:`~mrm_cosim.protocol.joint_program.INPUTS`)."""
    return [x.q, x.qd, x.tn, x.tau_D, x.qd0, x.vd0, x.ad0]


def joint_state_words(model: JointModel) -> dict[str, int]:
    """Register words of the state (reference for the next tick, PID integral), by name."""
    return {"qdes": model.q_des, "vdes": model.v_des, "ilo_s": model.i_lo, "ihi_s": model.i_hi}
