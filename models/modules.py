"""Module types of the modular robot: MRM paper Table 1 plus the geometry the paper leaves out.

Source: Zhu, Lamarche, Dupuis, Martin, *Modular Robot Manipulators with Precision Control*,
Table 1 (``seeds/003_*.txt``). Frames per module (paper Fig. 2, choices in ``docs/robot.md``):

* {C_k} on Link b and {A_k} on Link a share the joint origin, z on the joint axis; at q_k = 0
  they coincide and ``ᶜR_A = Rz(q_k)``.
* Link b is the proximal link: it carries the base-side interface {B_k} at ``(−L_b, 0, 0)`` in
  {C_k}. Link a is the distal link: it carries the tip-side interface {T_k} at ``(L_a, 0, 0)``
  in {A_k}. Both interfaces have x along the link axis, pointing from base towards tip.
* Module k+1 mounts on module k with {B_k+1} = {T_k} rotated by a twist about their common x.

Table 1 gives each link's 13 parameters (:mod:`models.spatial` order); they are kept here as
printed. One printed entry is inconsistent with its neighbours (Type I, Link b, ``m rx²``) —
see :data:`TABLE1_ERRATA` and ``docs/robot.md``; the physical body used everywhere is derived
from the self-consistent set (:func:`LinkParams.theta`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mrm_cosim.models.actuators import ACTUATORS
from mrm_cosim.models.spatial import theta_from_physical

__all__ = ["LinkParams", "SpringSpec", "ModuleType", "MODULE_TYPES", "TABLE1", "TABLE1_ERRATA"]


# Table 1 as printed: 13 parameters per link, referenced to {A_k} (Link a) and {C_k} (Link b).
# Order: m, m rx, m ry, m rz, m rx², m ry², m rz², m rx ry − Ixy, m rx rz − Ixz, m ry rz − Iyz,
#        Ixx, Iyy, Izz  (kg, kg·m, kg·m²).
TABLE1: dict[str, dict[str, tuple[float, ...]]] = {
    "I": {
        "a": (1.8, 0.135, 0.0, -0.0216, 0.01, 0.0, 2.59e-4, 0.0, -2e-3, 0.0, 2e-3, 8.5e-3, 6.5e-3),
        "b": (0.5, -0.0175, 0.0, -7.5e-3, 4.5e-4, 0.0, 1.13e-4, 0.0, 2.63e-4, 0.0,
              8e-4, 1e-3, 5e-4),
    },
    "II": {
        "a": (3.0, 0.108, 0.0, -0.012, 3.9e-3, 0.0, 4.8e-5, 0.0, -4.32e-4, 0.0,
              4e-3, 0.014, 0.01),
        "b": (1.64, -0.13, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 3.6e-3, 6e-3, 3e-3),
    },
}

# Printed entries that disagree with the entries they are derived from, with the derived value.
# Type I Link b: m rx = −0.0175 kg·m with m = 0.5 kg gives rx = −0.035 m and m rx² = 6.125e-4,
# not the printed 4.5e-4 (which is what rx = −0.03 would give). Every other entry of Table 1
# agrees with m·r·r to the printed precision.
TABLE1_ERRATA: dict[tuple[str, str, int], tuple[float, float]] = {
    ("I", "b", 4): (4.5e-4, 0.5 * 0.035**2),
}


@dataclass(frozen=True)
class LinkParams:
    """One link's inertial parameters, from a Table 1 column.

    Attributes
    ----------
    printed : tuple of 13 floats
        The 13 parameters as printed (kg, kg·m, kg·m²).
    mass : float, kg
    com : tuple of 3 floats, m
        Centre of mass in the link's frame ({A_k} for Link a, {C_k} for Link b).
    inertia_c : tuple of 9 floats, kg·m² (row-major 3×3)
        Inertia about the centre of mass, in the link frame's axes.
    """

    printed: tuple[float, ...]
    mass: float
    com: tuple[float, float, float]
    inertia_c: tuple[float, ...]

    @classmethod
    def from_table(cls, printed) -> LinkParams:
        """Physical body from 13 printed parameters.

        Mass and first moment are taken as printed; the inertia about the centre of mass comes
        from ``I··`` (diagonal) and ``m rᵢ rⱼ − Iᵢⱼ`` (products), so that the result is a rigid
        body whose ``m rᵢ²`` entries are recomputed rather than read (they are derived values
        and one of them is misprinted).
        """
        t = np.asarray(printed, dtype=float)
        if t.shape != (13,):
            raise ValueError(f"a link needs 13 parameters, not {t.shape}")
        m = float(t[0])
        c = t[1:4] / m
        Ixy = m * c[0] * c[1] - t[7]
        Ixz = m * c[0] * c[2] - t[8]
        Iyz = m * c[1] * c[2] - t[9]
        Ic = np.array([[t[10], Ixy, Ixz], [Ixy, t[11], Iyz], [Ixz, Iyz, t[12]]])
        return cls(tuple(float(x) for x in t), m, tuple(float(x) for x in c),
                   tuple(float(x) for x in Ic.ravel()))

    @property
    def inertia_c_matrix(self) -> np.ndarray:
        return np.array(self.inertia_c).reshape(3, 3)

    def theta(self) -> np.ndarray:
        """The self-consistent 13 parameters of the physical body, shape (13,)."""
        return theta_from_physical(self.mass, self.com, self.inertia_c_matrix)

    def check_physical(self, where: str) -> None:
        """Raise ``ValueError`` unless the inertia is physically realizable.

        Positive definite, and the principal moments satisfy the triangle inequality (to a
        relative tolerance of 1e-9: Table 1 has flat links that sit exactly on the bound).
        """
        Ic = self.inertia_c_matrix
        if self.mass <= 0.0:
            raise ValueError(f"{where}: mass must be positive, not {self.mass!r}")
        if not np.allclose(Ic, Ic.T):
            raise ValueError(f"{where}: inertia is not symmetric")
        ev = np.linalg.eigvalsh(Ic)
        if ev[0] <= 0.0:
            raise ValueError(f"{where}: inertia about the centre of mass is not positive "
                             f"definite (principal moments {ev.tolist()})")
        tol = 1e-9 * ev.sum()
        if ev[0] + ev[1] < ev[2] - tol:
            raise ValueError(f"{where}: principal moments {ev.tolist()} violate the triangle "
                             "inequality (no rigid body has them)")


@dataclass(frozen=True)
class SpringSpec:
    """Gravity counterbalance spring of a joint: ``τ_s(q) = torque · cos(q + phase)``.

    Attributes
    ----------
    torque : float, N·m
        Signed amplitude (its sign is set by how the module is mounted against gravity).
    phase : float, rad
    """

    torque: float
    phase: float = 0.0

    def torque_at(self, q):
        """Spring torque on the joint at joint angle ``q`` (rad), N·m."""
        return self.torque * np.cos(q + self.phase)


@dataclass(frozen=True)
class ModuleType:
    """A module type: actuator data (Table 1), link parameters (Table 1) and geometry (ours).

    Attributes
    ----------
    name : str
    actuator : str
        Harmonic Drive actuator model (key of ``models.actuators.ACTUATORS``).
    peak_torque, continuous_torque : float, N·m at the joint (Table 1)
    gear_ratio : int (Table 1)
    encoder_lines : int
        Encoder pulses per motor revolution (Table 1); ×4 quadrature × gear ratio per joint rev.
    spring_max : float, N·m
        Largest counterbalance torque the module's spring can be preloaded to (0: no spring).
    spring : SpringSpec or None
        Default preload of the counterbalance spring (None: none fitted).
    link_a, link_b : LinkParams
    length_a : float, m
        Joint axis to the tip-side interface {T_k}, along x of {A_k}.
    length_b : float, m
        Base-side interface {B_k} to the joint axis, along x of {C_k}.
    joint_limit : float, rad
        Symmetric range of the joint, ``|q| ≤ joint_limit``.
    max_speed : float, rad/s
        Largest joint speed (actuator output).
    """

    name: str
    actuator: str
    peak_torque: float
    continuous_torque: float
    gear_ratio: int
    encoder_lines: int
    link_a: LinkParams
    link_b: LinkParams
    length_a: float
    length_b: float
    joint_limit: float
    max_speed: float
    spring_max: float = 0.0
    spring: SpringSpec | None = None
    source: str = field(default="", compare=False)

    @property
    def counts_per_rev(self) -> int:
        """Encoder counts per joint revolution: lines × 4 (quadrature) × gear ratio."""
        return 4 * self.encoder_lines * self.gear_ratio

    @property
    def mass(self) -> float:
        return self.link_a.mass + self.link_b.mass


def _builtin_types() -> dict[str, ModuleType]:
    # Geometry: see docs/robot.md. Lengths are chosen so that each link's centre of mass
    # (Table 1) lies between its joint and its interface, nearer the joint where the actuator
    # sits, and so that the paper's quintic test gives its reported 0.5226 m/s tip speed on
    # mrm3. Maximum speeds are the actuators' (models.actuators: FHA-C manual).
    common = dict(gear_ratio=100, encoder_lines=2000, joint_limit=np.deg2rad(170.0))
    return {
        "I": ModuleType(
            name="I", actuator="FHA-11C-100", peak_torque=11.0, continuous_torque=4.2,
            max_speed=ACTUATORS["FHA-11C-100"].max_speed,
            link_a=LinkParams.from_table(TABLE1["I"]["a"]),
            link_b=LinkParams.from_table(TABLE1["I"]["b"]),
            length_a=0.20, length_b=0.10, source="MRM paper Table 1, Type-I", **common),
        "II": ModuleType(
            name="II", actuator="FHA-14C-100", peak_torque=28.0, continuous_torque=6.8,
            max_speed=ACTUATORS["FHA-14C-100"].max_speed,
            link_a=LinkParams.from_table(TABLE1["II"]["a"]),
            link_b=LinkParams.from_table(TABLE1["II"]["b"]),
            length_a=0.16, length_b=0.22, spring_max=11.0, spring=SpringSpec(8.0, 0.0),
            source="MRM paper Table 1, Type-II", **common),
    }


MODULE_TYPES: dict[str, ModuleType] = _builtin_types()
