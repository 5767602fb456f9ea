"""Time-optimal jerk-limited straight-line move through Ruckig, for comparison with the
trigonometric profile (seeds/002 shape vs the fastest shape under the same limits).

Two one-dimensional Ruckig problems on the path parameters (distance travelled along the
segment, m; angle turned about the fixed axis, rad), rest to rest, under the same velocity,
acceleration and jerk limits as :mod:`master.trig_planner`, solved together with time
synchronization so both parts end at the longer of the two minimum durations. Because the
line and the rotation axis are fixed, the Cartesian speed/acceleration/jerk norms equal the
path-parameter ones, so the Cartesian limits hold exactly. The trigonometric profile is one
feasible motion under these limits, so Ruckig's duration can never be longer.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
from ruckig import InputParameter, Result, Ruckig, RuckigError, Synchronization, Trajectory

from mrm_cosim.master.trig_planner import CartesianSamples, LineGeometry, LineLimits, LinePlan
from mrm_cosim.errors import InputError

__all__ = ["RuckigPath", "RuckigLinePlan", "plan_line_ruckig"]


@dataclass(frozen=True)
class RuckigPath:
    """Piecewise-constant-jerk profile of one path parameter, read from a Ruckig trajectory.

    Attributes
    ----------
    distance : float
        Target (m or rad); the path rests at it after ``duration``.
    duration : float, s
    t_start : ndarray, shape (7,), s
        Start time of each of Ruckig's seven phases.
    p, v, a, j : ndarray, shape (7,)
        Position, velocity and acceleration at each phase start, and the phase's jerk.
    """

    distance: float
    duration: float
    t_start: np.ndarray
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    j: np.ndarray

    @classmethod
    def from_profile(cls, profile, distance: float, duration: float) -> RuckigPath:
        """Copy one DOF's :class:`ruckig.Profile` (brake and accel pre-phases must be empty)."""
        if profile.brake.duration != 0.0 or profile.accel.duration != 0.0:
            raise RuntimeError("Ruckig returned a brake/accel pre-phase for a rest-to-rest move")
        t = np.asarray(profile.t, dtype=float)
        t_start = np.concatenate([[0.0], np.cumsum(t)[:-1]])
        return cls(float(distance), float(duration), t_start,
                   np.asarray(profile.p[:7], dtype=float), np.asarray(profile.v[:7], dtype=float),
                   np.asarray(profile.a[:7], dtype=float), np.asarray(profile.j, dtype=float))

    def evaluate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, acceleration and jerk at times ``t`` (s), each shape (n,).

        Exactly 0 before the start and exactly ``distance`` (at rest) from ``duration`` on.
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if self.duration == 0.0:
            z = np.zeros_like(t)
            return z + self.distance, z.copy(), z.copy(), z
        tc = np.clip(t, 0.0, self.duration)
        i = np.clip(np.searchsorted(self.t_start, tc, side="right") - 1, 0, 6)
        u = tc - self.t_start[i]
        p0, v0, a0, j = self.p[i], self.v[i], self.a[i], self.j[i]
        s = p0 + u * (v0 + u * (a0 / 2.0 + u * j / 6.0))
        v = v0 + u * (a0 + u * j / 2.0)
        a = a0 + u * j
        moving = (t > 0.0) & (t < self.duration)
        s = np.where(t >= self.duration, self.distance, np.where(t <= 0.0, 0.0, s))
        return (s, np.where(moving, v, 0.0), np.where(moving, a, 0.0),
                np.where(moving, j, 0.0))


@dataclass(frozen=True)
class RuckigLinePlan:
    """A time-optimal synchronized jerk-limited straight-line move.

    Attributes
    ----------
    geometry : LineGeometry
    limits : LineLimits
    translation_time, rotation_time : float, s
        Minimum duration of each part alone (Ruckig's independent minimum).
    duration : float, s
        Synchronized duration, ``max(translation_time, rotation_time)``.
    translation, rotation : RuckigPath
    trig_duration : float, s
        Duration of the trigonometric plan under the same limits (>= ``duration``).
    notes : list of str
    """

    geometry: LineGeometry
    limits: LineLimits
    translation_time: float
    rotation_time: float
    duration: float
    translation: RuckigPath
    rotation: RuckigPath
    trig_duration: float
    notes: list[str] = field(default_factory=list)

    def sample(self, t) -> CartesianSamples:
        """Cartesian pose, velocity, acceleration and jerk at times ``t`` (s), shape (n,)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        return self.geometry.sample(t, self.translation.evaluate(t), self.rotation.evaluate(t))

    def summary(self) -> dict:
        """Figures for ``mrm plan line --profile ruckig --json`` (SI units)."""
        return {
            "profile": "ruckig",
            "distance_m": self.geometry.distance,
            "rotation_rad": self.geometry.angle,
            "translation_time_s": self.translation_time,
            "rotation_time_s": self.rotation_time,
            "duration_s": self.duration,
            "trig_duration_s": self.trig_duration,
        }


def plan_line_ruckig(plan: LinePlan) -> RuckigLinePlan:
    """Solve the move of a trigonometric :class:`LinePlan` time-optimally with Ruckig.

    Parameters
    ----------
    plan : LinePlan
        Supplies the geometry and the limits; its duration is reported for comparison.

    Returns
    -------
    RuckigLinePlan
    """
    g, lim = plan.geometry, plan.limits
    targets = [g.distance, g.angle]
    otg = Ruckig(2)
    inp = InputParameter(2)
    inp.current_position = [0.0, 0.0]
    inp.current_velocity = [0.0, 0.0]
    inp.current_acceleration = [0.0, 0.0]
    inp.target_position = targets
    inp.target_velocity = [0.0, 0.0]
    inp.target_acceleration = [0.0, 0.0]
    inp.max_velocity = [lim.translation.velocity, lim.rotation.velocity]
    inp.max_acceleration = [lim.translation.acceleration, lim.rotation.acceleration]
    inp.max_jerk = [lim.translation.jerk, lim.rotation.jerk]
    inp.synchronization = Synchronization.Time
    traj = Trajectory(2)
    try:
        result = otg.calculate(inp, traj)
    except RuckigError as exc:          # extreme limits: its solver found no profile
        match = re.search(r"dof: (\d)", str(exc))
        part = ("translation", "rotation")[int(match.group(1))] if match else None
        raise InputError(f"limits.{part}" if part else "limits",
                         "Ruckig finds no trajectory for these limits (its solver failed); "
                         "the trigonometric profile (--profile trig) may take them") from None
    except ValueError as exc:           # a result code the binding has no name for
        if "is not a valid Result" not in str(exc):
            raise
        raise InputError(plan.limiting_field(),
                         f"the move takes {plan.duration:.3g} s with the trigonometric profile; "
                         f"Ruckig cannot compute a trajectory that long (its result "
                         f"{str(exc).split()[0]}: duration out of range)") from None
    if result not in (Result.Working, Result.Finished):
        raise RuntimeError(f"Ruckig failed on a rest-to-rest move: {result}")
    t_trans, t_rot = (float(x) for x in traj.independent_min_durations)
    duration = float(traj.duration)
    profiles = traj.profiles[0]
    paths = [RuckigPath.from_profile(profiles[k], targets[k], duration) for k in range(2)]
    return RuckigLinePlan(g, lim, t_trans, t_rot, duration, paths[0], paths[1], plan.duration,
                          list(plan.notes))
