"""What the master does when nodes trip: re-arm and blend back, or end (issue 22 item 2).

A node's watchdog trips when the master falls silent for TIMEOUT cycles (a cut cable, a lost
link); the node then stops its joint, holds it and engages its brake (docs/node.md "Safe
stop"). The master sees it in Comm A (``Status.TRIPPED``, ``HOLD``, ``BRAKE``) once the link
is back, or sees the replies go missing while it is not. ``on_trip`` (:data:`ON_TRIP`) says
what it does then (:class:`master.cycle.Master`, docs/faults.md "Recovery"):

* ``"rearm"``: when every node answers a period's Comm A again, each with the period of this
  period's time-code (the nodes' timers are on the master's grid), every tripped node has
  completed its stop (``Status.BRAKE`` or ``SAFE``: at rest on its brake; re-arming a loop
  against a joint that still moves saturates it and winds its integral up), and the upload
  read-back (CRC and count) agrees with everything uploaded (and the references are not
  primitives', ``references = "dmp"``, whose generators would ignore a blend: the run ends
  instead), the master sends every node a
  Comm D holding the
  position it reports (zero velocity and acceleration), then CONFIG ARM to the tripped nodes;
  they re-arm at the next boundary. A node that did not trip (above a cut line, it kept
  receiving requests) gets a Comm D that continues from its reported position at its reported
  velocity, and no ARM (re-arming a moving joint saturates it: 0.19 rad of overshoot with
  pid-fpga after a cut of line 2). From the next period the references follow
  :class:`Blend`, a quintic from those states to the trajectory's position, velocity and
  acceleration at the blend's end, ``rearm_blend`` seconds later or more; then the
  trajectory. A read-back that
  disagrees ends the run instead (the nodes may not hold what the master thinks).
* ``"end"``: at the first sign (a period whose replies are missing, or a node reporting a
  trip) the master stops sending: every node's watchdog trips, and the nodes stop, hold and
  brake; the run continues to its end only so that the plant's motion is recorded.

Either way a run with a trip or a lost link is not clean (``mrm run`` exit code 3).
"""

from __future__ import annotations

import numpy as np

__all__ = ["ON_TRIP", "Blend", "quintic_blend", "fit_blend", "BLEND_TORQUE"]

#: What the master does when nodes trip or the link is lost (``[safety] on_trip``).
ON_TRIP = ("rearm", "end")
#: The blend's inertial torque (nominal joint inertia × its peak acceleration) may use at most
#: this fraction of each joint's peak torque; the rest is left for gravity, friction and the
#: loop's corrections. A blend that asks more is lengthened (:func:`fit_blend`): a joint
#: driven into saturation winds a node PID's integral up (a 0.2 s blend after a stop at the
#: quintic's peak speed asked joint 1 of mrm3 for ~3× its peak torque and it overshot by
#: 0.19 rad with pid-fpga). [ASSUMED 0.5]
BLEND_TORQUE = 0.5


def quintic_blend(q0, v0, a0, q1, v1, a1, T: float) -> np.ndarray:
    """Coefficients ``c`` (shape (6, n)) of the quintic ``p(τ) = Σ c_k τ^k`` on ``[0, T]``
    with ``p, ṗ, p̈`` = ``q0, v0, a0`` at 0 and ``q1, v1, a1`` at ``T`` (per joint)."""
    q0, v0, a0, q1, v1, a1 = (np.asarray(x, dtype=float) for x in (q0, v0, a0, q1, v1, a1))
    T2, T3 = T * T, T * T * T
    h = q1 - q0 - v0 * T - 0.5 * a0 * T2
    dv = v1 - v0 - a0 * T
    da = a1 - a0
    c3 = (10.0 * h - 4.0 * dv * T + 0.5 * da * T2) / T3
    c4 = (-15.0 * h + 7.0 * dv * T - da * T2) / (T3 * T)
    c5 = (6.0 * h - 3.0 * dv * T + 0.5 * da * T2) / (T3 * T2)
    return np.array([q0, v0, 0.5 * a0, c3, c4, c5])


class Blend:
    """The references from a held position back onto a trajectory.

    Parameters
    ----------
    trajectory : callable
        ``trajectory(t) -> (q, q̇, q̈)``, arrays of shape (n,), t in s from period 0.
    q_hold : ndarray, shape (n,), rad
        Where the joints are at ``t0``.
    t0 : float, s
        Start of the blend (the period the nodes re-arm in).
    duration : float, s
        Length of the blend; from ``t0 + duration`` on, the trajectory itself.
    v_hold : ndarray, shape (n,), rad/s, optional
        Their velocities at ``t0`` (default: at rest; a joint whose node did not trip keeps
        moving with the references it was last given).
    """

    def __init__(self, trajectory, q_hold, t0: float, duration: float, v_hold=None):
        self.trajectory = trajectory
        self.t0 = float(t0)
        self.t1 = self.t0 + float(duration)
        z = np.zeros_like(np.asarray(q_hold, dtype=float))
        v0 = z if v_hold is None else np.asarray(v_hold, dtype=float)
        q1, v1, a1 = (np.asarray(x, dtype=float) for x in trajectory(self.t1))
        self._c = quintic_blend(q_hold, v0, z, q1, v1, a1, float(duration))

    def __call__(self, t: float):
        """``(q, q̇, q̈)`` at ``t`` (s from period 0): the blend in ``[t0, t1)``, the trajectory
        after it (before ``t0``: the held position)."""
        if t >= self.t1:
            return self.trajectory(t)
        c = self._c
        tau = max(0.0, t - self.t0)
        q = c[0] + tau * (c[1] + tau * (c[2] + tau * (c[3] + tau * (c[4] + tau * c[5]))))
        v = c[1] + tau * (2 * c[2] + tau * (3 * c[3] + tau * (4 * c[4] + tau * 5 * c[5])))
        a = 2 * c[2] + tau * (6 * c[3] + tau * (12 * c[4] + tau * 20 * c[5]))
        return q, v, a


def fit_blend(trajectory, q_hold, t0: float, duration: float, inertia, peak_torque,
              budget: float = BLEND_TORQUE, tries: int = 12, v_hold=None) -> Blend:
    """The shortest :class:`Blend` of at least ``duration`` whose inertial torque ``inertia ×
    max |q̈|`` (per joint, sampled over the blend) stays within ``budget × peak_torque``:
    ``duration`` lengthened by at least 25 % a try (at most ``tries``; the last is returned).

    ``inertia`` : ndarray, shape (n,), kg·m² (nominal: the diagonal of the mass matrix at
    ``q_hold`` plus the reflected rotor inertia); ``peak_torque`` : ndarray, shape (n,), N·m.
    """
    inertia = np.asarray(inertia, dtype=float)
    limit = budget * np.asarray(peak_torque, dtype=float)
    T = float(duration)
    for _ in range(tries):
        blend = Blend(trajectory, q_hold, t0, T, v_hold)
        acc = np.max(np.abs([blend(t0 + x * T)[2] for x in np.linspace(0.0, 1.0, 41)]),
                     axis=0)
        ratio = float(np.max(inertia * acc / limit))
        if ratio <= 1.0:
            return blend
        T *= max(1.25, min(2.0, float(np.sqrt(ratio))))
    return blend
