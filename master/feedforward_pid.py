"""Float joint controller at the master rate: model feedforward plus PID on encoder feedback.

``τ = rnea_nominal(q, q̇_d, q̈_d) + I_m q̈_d − τ_spring,nominal(q) + K_p e + K_i ∫e + K_d ė``,
``e = q_d − q``; gains place a triple closed-loop pole at ``−ω`` per joint
(``K_p = 3Jω², K_i = Jω³, K_d = 3Jω`` with J the joint's nominal inertia at home).

It uses only what a real master knows: the nominal rigid-body model (Table 1), the actuators'
nominal reflected inertia and spring preloads, encoder counts (q from counts, q̇ by a backward
difference over one period). It knows nothing of friction. This is the float reference the
preview runs before the gateware loop exists; the VDC and FPGA controllers replace it.
"""

from __future__ import annotations

import math

import numpy as np

from mrm_cosim.models.actuators import ACTUATORS
from mrm_cosim.models.robot import load_robot
from mrm_cosim.errors import require_positive

__all__ = ["FeedforwardPID"]


class FeedforwardPID:
    """Feedforward + PID joint controller, called once per period.

    Parameters
    ----------
    robot : Robot or str
    period : float, s
        Controller period (1 ms on the MRM master).
    bandwidth_hz : float
        Closed-loop pole frequency ω/2π of each joint's PID, Hz.
    """

    def __init__(self, robot, period: float = 1e-3, bandwidth_hz: float = 8.0):
        import pinocchio as pin

        self.robot = load_robot(robot)
        self.period = require_positive(period, "period")
        bw = require_positive(bandwidth_hz, "bandwidth_hz")
        self._pin = pin
        self.model = self.robot.pinocchio_model()
        self.data = self.model.createData()
        self.armature = np.array([ACTUATORS[m.type.actuator].output_inertia
                                  for m in self.robot.modules])
        self.counts_per_rev = self.robot.counts_per_rev.astype(float)
        M = pin.crba(self.model, self.data, self.robot.home)
        inertia = np.diag(M) + self.armature
        w = 2.0 * math.pi * bw
        self.kp = 3.0 * inertia * w * w
        self.ki = inertia * w**3
        self.kd = 3.0 * inertia * w
        self._q_prev: np.ndarray | None = None
        self._integral = np.zeros(self.robot.n)

    def reset(self) -> None:
        self._q_prev = None
        self._integral[:] = 0.0

    def joint_positions(self, counts) -> np.ndarray:
        """Joint angles (rad) from encoder counts."""
        return np.asarray(counts, dtype=float) * (2.0 * math.pi) / self.counts_per_rev

    def __call__(self, counts, q_d, qd_d, qdd_d) -> np.ndarray:
        """Torque command (N·m, shape (n,)) for this period from encoder counts and references."""
        q = self.joint_positions(counts)
        qd = np.zeros_like(q) if self._q_prev is None else (q - self._q_prev) / self.period
        self._q_prev = q
        tau_ff = self._pin.rnea(self.model, self.data, q, np.asarray(qd_d, dtype=float),
                                np.asarray(qdd_d, dtype=float))
        e = q_d - q
        self._integral += e * self.period
        tau = (tau_ff + self.armature * qdd_d - self.robot.spring_torque(q)
               + self.kp * e + self.ki * self._integral + self.kd * (qd_d - qd))
        return np.clip(tau, -self.robot.peak_torques, self.robot.peak_torques)
