"""Trigonometric jerk-continuous Cartesian straight-line planner (Li et al., seeds/002).

Acceleration of a rest-to-rest move of length ``L`` in time ``T`` (eq. 3), ``ω = 4π/T``::

    a(t) =  A/2 (1 − cos ωt)     0 ≤ t ≤ T/2
    a(t) = −A/2 (1 − cos ωt)     T/2 < t ≤ T

Integrating (docs/trajectories.md rederives it) gives ``L = A T²/8`` (eq. 11), peak velocity
``A T/4`` at T/2 (eq. 12), peak jerk ``2πA/T`` at T/8 (eq. 13), hence the shortest time under
velocity/acceleration/jerk limits (eqs. 15–16)::

    T ≥ max(2L/V, √(8L/A_max), ∛(16πL/J))

Translation runs along the segment ``p = (1 − k) p_s + k p_e`` with ``k = s/D``; rotation
turns about one fixed base-frame axis by ``φ(t)`` (quaternion slerp along the shortest path,
``k = φ/θ``). Both use one duration ``T = max(T_D, T_θ)`` (eq. 17) and the amplitudes
``A_D = 8D/T²``, ``A_θ = 8θ/T²``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mrm_cosim.master import quaternion as quat
from mrm_cosim.errors import InputError, require_nonnegative, require_positive

__all__ = ["AxisLimits", "LineLimits", "TrigProfile", "LineGeometry", "CartesianSamples",
           "LinePlan", "limiting_bound", "limiting_field", "trig_min_duration", "pose_from_matrix",
           "plan_line",
           "sample_times", "ORTHONORMALITY_TOLERANCE", "PROJECTION_NOTE_THRESHOLD"]

#: A rotation block with ‖RᵀR − I‖_F above this is rejected as "not a rotation".
ORTHONORMALITY_TOLERANCE = 0.02
#: Above this deviation a rotation block is projected onto SO(3) with a note.
PROJECTION_NOTE_THRESHOLD = 1e-9


@dataclass(frozen=True)
class AxisLimits:
    """Velocity, acceleration and jerk limits of one motion (m or rad based), all > 0."""

    velocity: float
    acceleration: float
    jerk: float

    def __post_init__(self):
        for name in ("velocity", "acceleration", "jerk"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.number):
                raise InputError(name, f"must be a number, not {value!r}")
            object.__setattr__(self, name, require_positive(value, name))


@dataclass(frozen=True)
class LineLimits:
    """Limits of the translation (m/s, m/s², m/s³) and of the rotation (rad/s, rad/s², rad/s³)."""

    translation: AxisLimits
    rotation: AxisLimits


def trig_min_duration(distance: float, limits: AxisLimits) -> float:
    """Shortest duration of the trigonometric profile over ``distance`` (eqs. 15/16), s.

    Parameters
    ----------
    distance : float
        Length of the move (m or rad), >= 0; 0 gives 0.
    limits : AxisLimits
        Velocity, acceleration and jerk bounds in the same unit.
    """
    d = require_nonnegative(distance, "distance")
    if d == 0.0:
        return 0.0
    return max(_duration_terms(d, limits).values())


def _duration_terms(d: float, limits: AxisLimits) -> dict[str, float]:
    """The duration each bound alone would need over ``d`` (eqs. 15/16), by bound name."""
    return {"velocity": 2.0 * d / limits.velocity,
            "acceleration": math.sqrt(8.0 * d / limits.acceleration),
            "jerk": (16.0 * math.pi * d / limits.jerk) ** (1.0 / 3.0)}


def limiting_field(geometry, limits: LineLimits, translation_time: float,
                   rotation_time: float) -> str:
    """The limit that sets the duration of a line, as the dotted field of the line file
    (``limits.translation.velocity``): of the part that takes longer, the bound whose term of
    eqs. 15/16 is the largest."""
    if translation_time >= rotation_time:
        part, distance, lim = "translation", geometry.distance, limits.translation
    else:
        part, distance, lim = "rotation", geometry.angle, limits.rotation
    return f"limits.{part}.{limiting_bound(distance, lim)}"


def limiting_bound(distance: float, limits: AxisLimits) -> str:
    """Which of ``velocity``, ``acceleration``, ``jerk`` sets :func:`trig_min_duration`."""
    terms = _duration_terms(require_nonnegative(distance, "distance"), limits)
    return max(terms, key=terms.get)


@dataclass(frozen=True)
class TrigProfile:
    """One-dimensional trigonometric rest-to-rest profile of length ``distance`` in ``duration``.

    ``duration = 0`` is allowed only with ``distance = 0`` (no motion). Outside [0, T] the
    profile rests at 0 or at ``distance``.
    """

    distance: float
    duration: float

    def __post_init__(self):
        d = require_nonnegative(self.distance, "distance")
        T = require_nonnegative(self.duration, "duration")
        if T == 0.0 and d != 0.0:
            raise InputError("duration", f"must be positive to move {d!r}")
        object.__setattr__(self, "distance", d)
        object.__setattr__(self, "duration", T)

    @property
    def amplitude(self) -> float:
        """Acceleration amplitude ``A = 8L/T²`` (eq. 11), m/s² or rad/s²."""
        return 0.0 if self.duration == 0.0 else 8.0 * self.distance / self.duration**2

    @property
    def peak_velocity(self) -> float:
        """``A T / 4`` (eq. 12), reached at T/2."""
        return self.amplitude * self.duration / 4.0

    @property
    def peak_acceleration(self) -> float:
        """``A``, reached at T/4 (and −A at 3T/4)."""
        return self.amplitude

    @property
    def peak_jerk(self) -> float:
        """``2πA / T`` (eq. 13), reached at T/8 (and ±at 3T/8, 5T/8, 7T/8)."""
        return 0.0 if self.duration == 0.0 else 2.0 * math.pi * self.amplitude / self.duration

    def evaluate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, acceleration, jerk at times ``t``.

        Parameters
        ----------
        t : float or ndarray, shape (n,), s

        Returns
        -------
        s, v, a, j : ndarray, shape (n,)
            Path length travelled and its first three derivatives. ``s`` is exactly 0 at
            t <= 0 and exactly ``distance`` at t >= T.
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        T, L, A = self.duration, self.distance, self.amplitude
        if T == 0.0:
            z = np.zeros_like(t)
            return z.copy(), z.copy(), z.copy(), z
        w = 4.0 * math.pi / T
        second = t > 0.5 * T
        # Second half mirrors the first: s(t) = L − s₁(T − t), v = v₁(T − t), a = −a₁, j = j₁.
        u = np.clip(np.where(second, T - t, t), 0.0, 0.5 * T)
        half_sin2 = np.sin(0.5 * w * u) ** 2          # (1 − cos ωu)/2, no cancellation
        s1 = 0.5 * A * (0.5 * u * u - 2.0 * half_sin2 / (w * w))
        v1 = 0.5 * A * (u - np.sin(w * u) / w)
        a1 = A * half_sin2
        j1 = 0.5 * A * w * np.sin(w * u)
        s = np.where(second, L - s1, s1)
        s = np.where(t >= T, L, np.where(t <= 0.0, 0.0, s))
        a = np.where(second, -a1, a1)
        return s, v1, a, j1


@dataclass(frozen=True)
class CartesianSamples:
    """Sampled Cartesian motion, time-major; quaternions (w, x, y, z); base-frame vectors.

    Attributes
    ----------
    t : ndarray, shape (n,), s
    position : ndarray, shape (n, 3), m
    quaternion : ndarray, shape (n, 4)
    velocity, acceleration, jerk : ndarray, shape (n, 3), m/s, m/s², m/s³
    angular_velocity, angular_acceleration, angular_jerk : ndarray, shape (n, 3)
        rad/s, rad/s², rad/s³, in the base frame.
    """

    t: np.ndarray
    position: np.ndarray
    quaternion: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray
    angular_velocity: np.ndarray
    angular_acceleration: np.ndarray
    angular_jerk: np.ndarray

    COLUMNS = ("t_s",
               "x_m", "y_m", "z_m",
               "qw", "qx", "qy", "qz",
               "vx_m_s", "vy_m_s", "vz_m_s",
               "ax_m_s2", "ay_m_s2", "az_m_s2",
               "jx_m_s3", "jy_m_s3", "jz_m_s3",
               "wx_rad_s", "wy_rad_s", "wz_rad_s",
               "alphax_rad_s2", "alphay_rad_s2", "alphaz_rad_s2",
               "jwx_rad_s3", "jwy_rad_s3", "jwz_rad_s3")

    def table(self) -> np.ndarray:
        """All columns side by side in :attr:`COLUMNS` order, shape (n, 26)."""
        return np.column_stack([self.t, self.position, self.quaternion, self.velocity,
                                self.acceleration, self.jerk, self.angular_velocity,
                                self.angular_acceleration, self.angular_jerk])


@dataclass(frozen=True)
class LineGeometry:
    """Straight segment from pose (p_s, q_s) to (p_e, q_e) and its fixed rotation axis.

    Attributes
    ----------
    p_start, p_end : ndarray, shape (3,), m
    q_start, q_end : ndarray, shape (4,)
        (w, x, y, z); ``q_end`` is in the same hemisphere as ``q_start`` (shortest path).
    distance : float, m
    angle : float, rad, in [0, π]
    direction : ndarray, shape (3,)
        Unit vector p_s → p_e (zeros if distance is 0).
    axis : ndarray, shape (3,)
        Unit rotation axis in the base frame (zeros if angle is 0).
    """

    p_start: np.ndarray
    p_end: np.ndarray
    q_start: np.ndarray
    q_end: np.ndarray
    distance: float
    angle: float
    direction: np.ndarray
    axis: np.ndarray

    @classmethod
    def between(cls, p_start, R_start, p_end, R_end) -> LineGeometry:
        """Geometry of the move between two poses (rotation matrices must be orthonormal)."""
        p_s = np.asarray(p_start, dtype=float)
        p_e = np.asarray(p_end, dtype=float)
        q_s = quat.from_matrix(R_start)
        q_e = quat.from_matrix(R_end)
        if float(q_s @ q_e) < 0.0:
            q_e = -q_e
        with np.errstate(over="ignore", invalid="ignore"):
            delta = p_e - p_s
            distance = float(np.linalg.norm(delta))
        if not math.isfinite(distance):
            raise InputError("end.pose", "the move from the start position overflows a float")
        direction = delta / distance if distance > 0.0 else np.zeros(3)
        axis, angle = quat.relative_axis_angle(q_s, q_e)
        return cls(p_s, p_e, q_s, q_e, distance, angle, direction, axis)

    def sample(self, t, trans, rot) -> CartesianSamples:
        """Map path-parameter derivatives to Cartesian samples.

        Parameters
        ----------
        t : ndarray, shape (n,), s
        trans : tuple of 4 ndarray, shape (n,)
            Distance travelled along the segment (m) and its derivatives; the last sample of
            the move must carry exactly ``distance`` for the end pose to be exact.
        rot : tuple of 4 ndarray, shape (n,)
            Angle turned (rad) and its derivatives.
        """
        s, sd, sdd, sddd = (np.asarray(x, dtype=float) for x in trans)
        phi, phid, phidd, phiddd = (np.asarray(x, dtype=float) for x in rot)
        k = s / self.distance if self.distance > 0.0 else np.zeros_like(s)
        k = np.clip(k, 0.0, 1.0)[:, None]
        position = (1.0 - k) * self.p_start + k * self.p_end
        kr = np.clip(phi / self.angle, 0.0, 1.0) if self.angle > 0.0 else np.zeros_like(phi)
        quaternion = quat.slerp(self.q_start, self.q_end, kr)
        d, ax = self.direction, self.axis
        return CartesianSamples(
            t=np.asarray(t, dtype=float), position=position, quaternion=quaternion,
            velocity=sd[:, None] * d, acceleration=sdd[:, None] * d, jerk=sddd[:, None] * d,
            angular_velocity=phid[:, None] * ax, angular_acceleration=phidd[:, None] * ax,
            angular_jerk=phiddd[:, None] * ax)


def sample_times(duration: float, dt: float) -> np.ndarray:
    """Uniform grid ``0, dt, 2dt, …`` up to the first point at or after ``duration``, s.

    The last sample lies at or after the end, where the motion rests at the end pose.
    """
    dt = require_positive(dt, "dt")
    n = int(math.ceil(duration / dt - 1e-9)) + 1
    if n > 50_000_000:
        raise InputError("dt", f"gives {float(n):.3g} samples for {duration:g} s (at most "
                         f"50,000,000); choose a larger step")
    return np.arange(max(n, 1)) * dt


@dataclass(frozen=True)
class LinePlan:
    """A synchronized trigonometric straight-line move (seeds/002 eqs. 5–17).

    Attributes
    ----------
    geometry : LineGeometry
    limits : LineLimits
    translation_time, rotation_time : float, s
        Shortest times of each part alone (eqs. 15, 16); 0 for no motion.
    duration : float, s
        ``max(translation_time, rotation_time)`` (eq. 17).
    translation, rotation : TrigProfile
        Both of length ``duration``.
    notes : list of str
        Remarks about the input (e.g. a rotation block projected onto SO(3)).
    """

    geometry: LineGeometry
    limits: LineLimits
    translation_time: float
    rotation_time: float
    duration: float
    translation: TrigProfile
    rotation: TrigProfile
    notes: list[str] = field(default_factory=list)

    def sample(self, t) -> CartesianSamples:
        """Cartesian pose, velocity, acceleration and jerk at times ``t`` (s), shape (n,)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        return self.geometry.sample(t, self.translation.evaluate(t), self.rotation.evaluate(t))

    def limiting_field(self) -> str:
        """The limit that sets :attr:`duration`, as the dotted field of the line file
        (``limits.translation.velocity``); see :func:`limiting_field`."""
        return limiting_field(self.geometry, self.limits, self.translation_time,
                              self.rotation_time)

    def summary(self) -> dict:
        """The figures ``mrm plan line --json`` prints (SI units)."""
        return {
            "distance_m": self.geometry.distance,
            "rotation_rad": self.geometry.angle,
            "translation_time_s": self.translation_time,
            "rotation_time_s": self.rotation_time,
            "duration_s": self.duration,
            "translation_accel_amplitude": self.translation.amplitude,
            "rotation_accel_amplitude": self.rotation.amplitude,
        }


def pose_from_matrix(M, field: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Validate a homogeneous transform and split it into position and rotation.

    Parameters
    ----------
    M : array_like, shape (4, 4)
        ``[[R, p], [0, 0, 0, 1]]`` with p in metres.
    field : str
        Name used in error messages (``"start.pose"``).

    Returns
    -------
    p : ndarray, shape (3,), m
    R : ndarray, shape (3, 3)
        ``R`` projected onto SO(3) (:func:`master.quaternion.project_to_so3`).
    notes : list of str
        One note if the projection moved ``R`` by more than rounding.

    Raises
    ------
    InputError
        Wrong shape, non-finite entries, last row not [0, 0, 0, 1], det(R) <= 0, or
        ``‖RᵀR − I‖_F >`` :data:`ORTHONORMALITY_TOLERANCE`.
    """
    rows = M
    if isinstance(rows, np.ndarray):
        rows = rows.tolist()
    if not isinstance(rows, list | tuple) or len(rows) != 4:
        raise InputError(field, "must be a 4x4 list of rows [[R, p], [0, 0, 0, 1]]")
    for i, row in enumerate(rows):
        if not isinstance(row, list | tuple) or len(row) != 4:
            raise InputError(f"{field}[{i}]", f"must be a row of 4 numbers, not {row!r}")
        for j, x in enumerate(row):
            if isinstance(x, bool) or not isinstance(x, int | float):
                raise InputError(f"{field}[{i}][{j}]", f"must be a number, not {x!r}")
            if not math.isfinite(x):
                raise InputError(f"{field}[{i}][{j}]", f"must be finite, not {x!r}")
    A = np.array(rows, dtype=float)
    if not np.array_equal(A[3], [0.0, 0.0, 0.0, 1.0]):
        raise InputError(f"{field}[3]", f"must be [0, 0, 0, 1], not {rows[3]!r}")
    R = A[:3, :3]
    det = float(np.linalg.det(R))
    if det <= 0.0:
        raise InputError(field, f"rotation block has det {det:.3g} <= 0: not a rotation")
    err = quat.orthonormality_error(R)
    if err > ORTHONORMALITY_TOLERANCE:
        raise InputError(field, f"rotation block is not orthonormal: ‖RᵀR − I‖ = {err:.3g} "
                                f"> {ORTHONORMALITY_TOLERANCE}")
    notes = []
    if err > PROJECTION_NOTE_THRESHOLD:
        notes.append(f"{field}: rotation block projected onto SO(3) (‖RᵀR − I‖ = {err:.2e})")
    return A[:3, 3].copy(), quat.project_to_so3(R), notes


def plan_line(start, end, limits: LineLimits) -> LinePlan:
    """Plan the synchronized trigonometric move between two homogeneous poses.

    Parameters
    ----------
    start, end : array_like, shape (4, 4)
        Homogeneous transforms, metres (validated by :func:`pose_from_matrix`).
    limits : LineLimits

    Returns
    -------
    LinePlan
    """
    p_s, R_s, notes_s = pose_from_matrix(start, "start.pose")
    p_e, R_e, notes_e = pose_from_matrix(end, "end.pose")
    geometry = LineGeometry.between(p_s, R_s, p_e, R_e)
    t_d = trig_min_duration(geometry.distance, limits.translation)
    t_r = trig_min_duration(geometry.angle, limits.rotation)
    T = max(t_d, t_r)
    if not math.isfinite(T * T):    # A = 8L/T² (eq. 11): T² must be a float
        name = limiting_field(geometry, limits, t_d, t_r)
        _, part, bound = name.split(".")
        value = getattr(getattr(limits, part), bound)
        last = f"{T:.3g} s" if math.isfinite(T) else "more seconds than a float holds"
        raise InputError(name, f"{value!r} makes the move last {last}, too long for its "
                         "figures to be computed in floating point")
    return LinePlan(geometry, limits, t_d, t_r, T,
                    TrigProfile(geometry.distance, T), TrigProfile(geometry.angle, T),
                    notes_s + notes_e)
