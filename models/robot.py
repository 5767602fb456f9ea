"""A robot: an assembly of N modules, from a built-in name or a TOML file, validated field by field.

An assembly file (``models/robots/mrm3.toml`` is one) reads::

    name = "my-arm"
    [base]                       # pose of {B_1}, the first module's base interface, in the world
    xyz = [0.0, 0.0, 0.3]        # m
    rpy_deg = [0.0, 0.0, 0.0]    # roll, pitch, yaw (URDF convention), or rpy = [...] in rad
    [tool]                       # tool point in {T_N}, the last module's tip interface (optional)
    xyz = [0.0, 0.0, 0.0]
    [[modules]]                  # base to tip
    type = "I"                   # a built-in type ("I", "II") or one from [module_types]
    twist_deg = 0.0              # rotation of {B_k} about x relative to {T_k-1} (or twist, rad)
    [[modules]]
    type = "II"
    twist_deg = 90.0
    spring = { torque = 8.0, phase_deg = 0.0 }   # counterbalance preload (Type II only)
    [module_types.III]           # optional user module types, see docs/robot.md
    like = "I"                   # start from a built-in type, then override fields

Gravity is −9.81 m/s² along the world z axis. The world frame is pinocchio's universe.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from mrm_cosim.errors import (
    InputError,
    reject_control_characters,
    reject_strings,
    require_finite,
    require_nonnegative,
    require_positive,
    require_vector,
)
from mrm_cosim.models.actuators import ACTUATORS
from mrm_cosim.models.modules import MODULE_TYPES, LinkParams, ModuleType, SpringSpec
from mrm_cosim.tomlfile import read_toml

__all__ = ["Module", "Robot", "load_robot", "builtin_robots", "GRAVITY", "rot_x", "rot_z",
           "rpy_to_matrix", "matrix_to_rpy", "homogeneous"]

GRAVITY = np.array([0.0, 0.0, -9.81])
# The node counts joint position in a 32-bit signed register (hdl/node/encoder.py); a joint
# turns at most half a revolution each way (joint_limit ≤ π), so 4 × lines × gear ≤ 2^32 − 2.
MAX_COUNTS_PER_REV = 2**32 - 2
BUILTIN_DIR = Path(__file__).parent / "robots"


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rpy_to_matrix(rpy) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed axes X, Y, Z): ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p),
                              math.cos(y), math.sin(y))
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def matrix_to_rpy(R) -> tuple[float, float, float]:
    """Inverse of :func:`rpy_to_matrix`; at gimbal lock (|pitch| = π/2) roll is set to 0."""
    R = np.asarray(R, dtype=float)
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    if abs(R[2, 0]) < 1.0 - 1e-12:
        roll = math.atan2(R[2, 1], R[2, 2])
        yaw = math.atan2(R[1, 0], R[0, 0])
    else:
        roll = 0.0
        yaw = math.atan2(-R[0, 1], R[1, 1])
    return roll, pitch, yaw


def homogeneous(R=None, p=None) -> np.ndarray:
    """4×4 homogeneous transform from a rotation (3×3) and a translation (3,)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if p is not None:
        T[:3, 3] = p
    return T


def _translation_x(d: float) -> np.ndarray:
    return homogeneous(p=(d, 0.0, 0.0))


@dataclass(frozen=True)
class Module:
    """One module of an assembly.

    Attributes
    ----------
    index : int
        0-based position from the base.
    type : ModuleType
    twist : float, rad
        Rotation of this module's {B} about its x axis relative to the previous {T} (for the
        first module: relative to the base pose).
    spring : SpringSpec or None
        Counterbalance preload of this instance (the type's default unless overridden).
    """

    index: int
    type: ModuleType
    twist: float = 0.0
    spring: SpringSpec | None = None


class Robot:
    """An N-module robot: kinematic and inertial description, URDF and pinocchio model.

    Parameters
    ----------
    name : str
    modules : list of Module, base to tip
    base : ndarray, shape (4, 4)
        Pose of the first module's base interface {B_1} in the world frame.
    tool : ndarray, shape (4, 4)
        Tool point in the last module's tip interface {T_N}.
    home : ndarray, shape (n,), rad
        Rest posture (zeros unless the assembly gives one).
    """

    def __init__(self, name: str, modules: list[Module], base=None, tool=None, home=None):
        if not modules:
            raise InputError("modules", "an assembly needs at least one module")
        self.name = name
        self.modules = list(modules)
        self.base = np.array(homogeneous() if base is None else base, dtype=float)
        self.tool = np.array(homogeneous() if tool is None else tool, dtype=float)
        self.home = np.zeros(self.n) if home is None else np.array(home, dtype=float)
        self.gravity = GRAVITY.copy()

    @property
    def n(self) -> int:
        """Number of modules, which is the number of joints."""
        return len(self.modules)

    @property
    def joint_names(self) -> list[str]:
        return [f"joint{k + 1}" for k in range(self.n)]

    # --- kinematic structure ---------------------------------------------------------------
    def mount_transform(self, k: int) -> np.ndarray:
        """Pose of {C_k} in the frame of the previous moving body ({A_k-1}, or the world).

        ``k`` is 0-based. The chain is then ``world → C_0 → Rz(q_0) → A_0 → mount(1) → C_1 …``.
        """
        # memoised (the master asks for every mount several times a period) on all it depends
        # on: the modules (frozen, so by identity) and the base (by value)
        mod = self.modules[k]
        dep = self.base.tobytes() if k == 0 else self.modules[k - 1]
        memo = self.__dict__.setdefault("_mounts", {})
        hit = memo.get(k)
        if hit is None or hit[0] is not mod or not (hit[1] is dep or hit[1] == dep):
            parent = self.base if k == 0 else _translation_x(self.modules[k - 1].type.length_a)
            hit = memo[k] = (mod, dep, parent @ homogeneous(rot_x(mod.twist))
                             @ _translation_x(mod.type.length_b))
        return hit[2].copy()

    def tool_transform(self) -> np.ndarray:
        """Pose of the tool point in {A_N} (the last module's Link a frame)."""
        return _translation_x(self.modules[-1].type.length_a) @ self.tool

    def link_frames(self, q) -> list[tuple[np.ndarray, np.ndarray]]:
        """World poses of {C_k} and {A_k} for every module at joint angles ``q``.

        Parameters
        ----------
        q : array_like, shape (n,), rad

        Returns
        -------
        list of (T_C, T_A), 4×4 each, base to tip.
        """
        q = np.asarray(q, dtype=float)
        frames = []
        T = np.eye(4)
        for k in range(self.n):
            T_C = T @ self.mount_transform(k)
            T_A = T_C @ homogeneous(rot_z(float(q[k])))
            frames.append((T_C, T_A))
            T = T_A
        return frames

    def tip_pose(self, q) -> np.ndarray:
        """World pose (4×4) of the tool point at joint angles ``q`` (rad)."""
        return self.link_frames(q)[-1][1] @ self.tool_transform()

    # --- limits ------------------------------------------------------------------------------
    @property
    def joint_limits(self) -> np.ndarray:
        """``|q_k| ≤ joint_limits[k]``, rad, shape (n,)."""
        return np.array([m.type.joint_limit for m in self.modules])

    @property
    def peak_torques(self) -> np.ndarray:
        return np.array([m.type.peak_torque for m in self.modules])

    @property
    def continuous_torques(self) -> np.ndarray:
        return np.array([m.type.continuous_torque for m in self.modules])

    @property
    def max_speeds(self) -> np.ndarray:
        return np.array([m.type.max_speed for m in self.modules])

    @property
    def counts_per_rev(self) -> np.ndarray:
        return np.array([m.type.counts_per_rev for m in self.modules], dtype=np.int64)

    def spring_torque(self, q) -> np.ndarray:
        """Counterbalance spring torques at joint angles ``q``, N·m, shape (n,)."""
        return np.array([0.0 if m.spring is None else m.spring.torque_at(float(q[k]))
                         for k, m in enumerate(self.modules)])

    # --- URDF and pinocchio -----------------------------------------------------------------
    def urdf(self) -> str:
        """URDF text of the assembly (rigid bodies and joint limits; no friction, no springs).

        Link names: ``link{k}b`` (frame {C_k}), ``link{k}a`` (frame {A_k}); massless frames
        ``B{k}``, ``T{k}`` for the interfaces and ``tool``; joints ``joint{k}`` (revolute about
        z) and ``mount{k}`` (fixed). Masses and inertias are the Table 1 links'.
        """
        out = ['<?xml version="1.0"?>', f'<robot name="{_xml(self.name)}">',
               '  <link name="base_link"/>']
        for k, mod in enumerate(self.modules):
            i = k + 1
            t = mod.type
            parent = "base_link" if k == 0 else f"link{k}a"
            out += [
                _urdf_link(f"link{i}b", t.link_b),
                _urdf_fixed(f"mount{i}", parent, f"link{i}b", self.mount_transform(k)),
                _urdf_link(f"link{i}a", t.link_a),
                f'  <joint name="joint{i}" type="revolute">',
                f'    <parent link="link{i}b"/>',
                f'    <child link="link{i}a"/>',
                '    <origin xyz="0 0 0" rpy="0 0 0"/>',
                '    <axis xyz="0 0 1"/>',
                f'    <limit lower="{_f(-t.joint_limit)}" upper="{_f(t.joint_limit)}" '
                f'effort="{_f(t.peak_torque)}" velocity="{_f(t.max_speed)}"/>',
                '  </joint>',
                f'  <link name="B{i}"/>',
                _urdf_fixed(f"B{i}_frame", f"link{i}b", f"B{i}", _translation_x(-t.length_b)),
                f'  <link name="T{i}"/>',
                _urdf_fixed(f"T{i}_frame", f"link{i}a", f"T{i}", _translation_x(t.length_a)),
            ]
        out += ['  <link name="tool"/>',
                _urdf_fixed("tool_frame", f"T{self.n}", "tool", self.tool),
                '</robot>', '']
        return "\n".join(out)

    def pinocchio_model(self):
        """Pinocchio model built from :meth:`urdf` (fixed base, gravity −9.81 along z)."""
        import pinocchio as pin

        model = pin.buildModelFromXML(self.urdf())
        model.gravity.linear = self.gravity.copy()
        return model

    # --- description -------------------------------------------------------------------------
    def describe(self) -> dict:
        """A JSON-ready description of the assembly (what ``mrm robot show`` prints)."""
        return {
            "name": self.name,
            "n_modules": self.n,
            "total_mass_kg": float(sum(m.type.mass for m in self.modules)),
            "base": {"xyz": self.base[:3, 3].tolist(), "rpy": list(matrix_to_rpy(self.base))},
            "tool": {"xyz": self.tool[:3, 3].tolist(), "rpy": list(matrix_to_rpy(self.tool))},
            "gravity": self.gravity.tolist(),
            "home_deg": np.rad2deg(self.home).tolist(),
            "modules": [_describe_module(m) for m in self.modules],
        }

    @cached_property
    def nominal_theta(self) -> np.ndarray:
        """Nominal 13 parameters per link, shape (n, 2, 13): ``[:, 0]`` Link a in {A_k},
        ``[:, 1]`` Link b in {C_k}."""
        return np.array([[m.type.link_a.theta(), m.type.link_b.theta()] for m in self.modules])


def _describe_module(m: Module) -> dict:
    t = m.type
    return {
        "index": m.index + 1,
        "type": t.name,
        "actuator": t.actuator,
        "twist_deg": math.degrees(m.twist),
        "peak_torque_Nm": t.peak_torque,
        "continuous_torque_Nm": t.continuous_torque,
        "gear_ratio": t.gear_ratio,
        "encoder_lines": t.encoder_lines,
        "counts_per_rev": t.counts_per_rev,
        "length_a_m": t.length_a,
        "length_b_m": t.length_b,
        "joint_limit_deg": math.degrees(t.joint_limit),
        "max_speed_rad_s": t.max_speed,
        "spring": None if m.spring is None else {"torque_Nm": m.spring.torque,
                                                  "phase_deg": math.degrees(m.spring.phase)},
        "link_a": {"mass_kg": t.link_a.mass, "com_m": list(t.link_a.com),
                   "theta13": list(t.link_a.printed)},
        "link_b": {"mass_kg": t.link_b.mass, "com_m": list(t.link_b.com),
                   "theta13": list(t.link_b.printed)},
    }


def _f(x: float) -> str:
    return repr(float(x)) if x != 0 else "0"


def _xml(s: str) -> str:
    return s.replace("&", "&amp;").replace("<", "&lt;").replace('"', "&quot;")


def _urdf_origin(T) -> str:
    xyz = " ".join(_f(v) for v in T[:3, 3])
    rpy = " ".join(_f(v) for v in matrix_to_rpy(T[:3, :3]))
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def _urdf_fixed(name: str, parent: str, child: str, T) -> str:
    return (f'  <joint name="{name}" type="fixed">\n    <parent link="{parent}"/>\n'
            f'    <child link="{child}"/>\n    {_urdf_origin(T)}\n  </joint>')


def _urdf_link(name: str, link: LinkParams) -> str:
    inertia = link.inertia_c_matrix
    return (f'  <link name="{name}">\n    <inertial>\n'
            f'      <origin xyz="{" ".join(_f(c) for c in link.com)}" rpy="0 0 0"/>\n'
            f'      <mass value="{_f(link.mass)}"/>\n'
            f'      <inertia ixx="{_f(inertia[0, 0])}" ixy="{_f(inertia[0, 1])}" '
            f'ixz="{_f(inertia[0, 2])}" iyy="{_f(inertia[1, 1])}" iyz="{_f(inertia[1, 2])}" '
            f'izz="{_f(inertia[2, 2])}"/>\n'
            '    </inertial>\n  </link>')


# --- loading and validation ------------------------------------------------------------------

def builtin_robots() -> list[str]:
    """Names of the built-in assemblies."""
    return sorted(p.stem for p in BUILTIN_DIR.glob("*.toml"))


def load_robot(spec) -> Robot:
    """A robot from a built-in name (``"mrm3"``, ``"mrm6"``), a TOML path, or a Robot.

    Raises
    ------
    InputError
        Unknown name, unreadable file, or any invalid field (named in the message).
    """
    if isinstance(spec, Robot):
        return spec
    if isinstance(spec, str) and spec in builtin_robots():
        path = BUILTIN_DIR / f"{spec}.toml"
    else:
        path = Path(spec)
        if path.suffix != ".toml" and not path.exists():
            raise InputError("robot", f"unknown robot {str(spec)!r}; built-in robots are "
                             f"{', '.join(builtin_robots())}, or give a .toml file")
    doc = read_toml(path, "robot")
    return robot_from_dict(doc, default_name=path.stem)


def _finite(value, field: str) -> float:
    return require_finite(reject_strings(value, field), field)


def _positive(value, field: str) -> float:
    return require_positive(reject_strings(value, field), field)


def _nonnegative(value, field: str) -> float:
    return require_nonnegative(reject_strings(value, field), field)


def _vector(value, length: int, field: str) -> list[float]:
    if isinstance(value, list) and len(value) == length:
        reject_strings(value, field)
    return require_vector(value, length, field)


def _check_keys(table: dict, allowed: set[str], where: str) -> None:
    if not isinstance(table, dict):
        raise InputError(where, f"must be a table, not {table!r}")
    for key in table:
        if key not in allowed:
            raise InputError(f"{where}.{key}" if where else key,
                             f"unknown field; expected one of {', '.join(sorted(allowed))}")


def _angle(table: dict, key: str, where: str, default: float = 0.0) -> float:
    """Read ``key`` (rad) or ``key_deg`` (degrees) from a table; not both."""
    if key in table and f"{key}_deg" in table:
        raise InputError(f"{where}.{key}", f"give {key} or {key}_deg, not both")
    if key in table:
        return _finite(table[key], f"{where}.{key}")
    if f"{key}_deg" in table:
        return math.radians(_finite(table[f"{key}_deg"], f"{where}.{key}_deg"))
    return default


def _pose(table, where: str) -> np.ndarray:
    if table is None:
        return homogeneous()
    _check_keys(table, {"xyz", "rpy", "rpy_deg"}, where)
    xyz = _vector(table.get("xyz", [0.0, 0.0, 0.0]), 3, f"{where}.xyz")
    if "rpy" in table and "rpy_deg" in table:
        raise InputError(f"{where}.rpy", "give rpy or rpy_deg, not both")
    if "rpy_deg" in table:
        rpy = [math.radians(a) for a in _vector(table["rpy_deg"], 3, f"{where}.rpy_deg")]
    else:
        rpy = _vector(table.get("rpy", [0.0, 0.0, 0.0]), 3, f"{where}.rpy")
    return homogeneous(rpy_to_matrix(rpy), xyz)


def _spring(value, where: str, mtype: ModuleType) -> SpringSpec | None:
    if value is None:
        return mtype.spring
    if value is False:
        return None
    _check_keys(value, {"torque", "phase", "phase_deg"}, where)
    if "torque" not in value:
        raise InputError(f"{where}.torque", "missing")
    torque = _finite(value["torque"], f"{where}.torque")
    if abs(torque) > mtype.spring_max:
        raise InputError(f"{where}.torque",
                         f"|{torque}| N·m exceeds the spring_max of module type {mtype.name!r} "
                         f"({mtype.spring_max} N·m)")
    return SpringSpec(torque, _angle(value, "phase", where))


def _type_name(value, field: str, known: dict) -> str:
    """A module type name must be a string (a list or table is no name, and no dict key)."""
    if not isinstance(value, str):
        raise InputError(field, f"must be the name of a module type ({', '.join(sorted(known))}"
                         f"), not {value!r}")
    return value


_TYPE_FIELDS = {"like", "actuator", "peak_torque", "continuous_torque", "gear_ratio",
                "encoder_lines", "length_a", "length_b", "joint_limit", "joint_limit_deg",
                "max_speed", "spring_max", "spring", "link_a", "link_b"}


def _module_type(name: str, table: dict, known: dict[str, ModuleType]) -> ModuleType:
    where = f"module_types.{name}"
    _check_keys(table, _TYPE_FIELDS, where)
    like = table.get("like")
    if like is not None:
        _type_name(like, f"{where}.like", known)
        if like not in known:
            raise InputError(f"{where}.like", f"unknown module type {like!r}; known types are "
                             f"{', '.join(sorted(known))}")
        base = known[like]
        fields = {}
    else:
        missing = sorted({"actuator", "peak_torque", "continuous_torque", "link_a", "link_b",
                          "length_a", "length_b", "max_speed"} - set(table))
        if missing:
            raise InputError(f"{where}.{missing[0]}", "missing (or give like = \"I\")")
        base = None
        fields = dict(gear_ratio=100, encoder_lines=2000, joint_limit=math.radians(170.0),
                      spring_max=0.0, spring=None)
    if "actuator" in table:
        if not isinstance(table["actuator"], str) or not table["actuator"]:
            raise InputError(f"{where}.actuator", f"must be a name, not {table['actuator']!r}")
        if table["actuator"] not in ACTUATORS:
            raise InputError(f"{where}.actuator", f"unknown actuator {table['actuator']!r}; "
                             f"known: {', '.join(sorted(ACTUATORS))}")
        fields["actuator"] = table["actuator"]
        if base is None:                # the drive's own gear and encoder unless given
            spec = ACTUATORS[table["actuator"]]
            fields.update(gear_ratio=spec.gear_ratio, encoder_lines=spec.encoder_lines)
    for key in ("peak_torque", "continuous_torque", "length_a", "length_b", "max_speed"):
        if key in table:
            fields[key] = _positive(table[key], f"{where}.{key}")
    if "spring_max" in table:
        fields["spring_max"] = _nonnegative(table["spring_max"], f"{where}.spring_max")
    for key in ("gear_ratio", "encoder_lines"):
        if key in table:
            v = table[key]
            if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
                raise InputError(f"{where}.{key}", f"must be a positive integer, not {v!r}")
            fields[key] = v
    if "joint_limit" in table or "joint_limit_deg" in table:
        lim = _angle(table, "joint_limit", where)
        if not 0.0 < lim <= math.pi:
            key = "joint_limit_deg" if "joint_limit_deg" in table else "joint_limit"
            bound = "(0, 180]°" if key == "joint_limit_deg" else "(0, π] rad"
            raise InputError(f"{where}.{key}", f"must be in {bound}, not {table[key]!r}")
        fields["joint_limit"] = lim
    for key in ("link_a", "link_b"):
        if key in table:
            theta = _vector(table[key], 13, f"{where}.{key}")
            if theta[0] <= 0.0:
                raise InputError(f"{where}.{key}[0]", f"mass must be positive, not {theta[0]!r}")
            _check_second_moments(theta, f"{where}.{key}")
            link = LinkParams.from_table(theta)
            try:
                link.check_physical(f"{where}.{key}")
            except ValueError as exc:
                raise InputError(f"{where}.{key}", str(exc).split(": ", 1)[-1]) from None
            fields[key] = link
    mtype = (replace(base, name=name, source=where, **fields) if base is not None
             else ModuleType(name=name, source=where, **fields))
    if mtype.counts_per_rev > MAX_COUNTS_PER_REV:
        key = "encoder_lines" if "encoder_lines" in table else "gear_ratio"
        raise InputError(f"{where}.{key}",
                         f"4 × encoder_lines {mtype.encoder_lines} × gear_ratio "
                         f"{mtype.gear_ratio} = {mtype.counts_per_rev} counts per revolution; "
                         f"the node's 32-bit signed joint count holds at most "
                         f"{MAX_COUNTS_PER_REV} (half a turn each way)")
    spec = ACTUATORS[mtype.actuator]
    if mtype.gear_ratio != spec.gear_ratio:
        raise InputError(f"{where}.gear_ratio",
                         f"{mtype.gear_ratio} is not the gear of actuator {spec.name} "
                         f"({spec.gear_ratio}): the plant takes the drive's inertia, friction "
                         f"and torque from the actuator, which are its own gear's; another "
                         f"gear is another actuator (models/actuators.py)")
    if mtype.peak_torque > spec.peak_torque:
        raise InputError(f"{where}.peak_torque",
                         f"{mtype.peak_torque} N·m exceeds the peak torque of actuator "
                         f"{spec.name} ({spec.peak_torque} N·m), where the plant saturates")
    if mtype.continuous_torque > mtype.peak_torque:
        raise InputError(f"{where}.continuous_torque",
                         f"{mtype.continuous_torque} N·m exceeds peak_torque "
                         f"{mtype.peak_torque} N·m")
    if "spring" in table:
        mtype = replace(mtype, spring=_spring(table["spring"], f"{where}.spring", mtype))
    elif mtype.spring is not None and abs(mtype.spring.torque) > mtype.spring_max:
        raise InputError(f"{where}.spring_max", "smaller than the inherited spring preload")
    return mtype


def robot_from_dict(doc: dict, default_name: str = "robot") -> Robot:
    """Validate a parsed assembly document and build the :class:`Robot`."""
    _check_keys(doc, {"name", "description", "base", "tool", "modules", "module_types",
                      "home", "home_deg"}, "")
    name = doc.get("name", default_name)
    if not isinstance(name, str) or not name:
        raise InputError("name", f"must be a non-empty string, not {name!r}")
    reject_control_characters(name, "name")
    known = dict(MODULE_TYPES)
    user_types = doc.get("module_types", {})
    if not isinstance(user_types, dict):
        raise InputError("module_types", f"must be a table, not {user_types!r}")
    for tname, table in user_types.items():
        reject_control_characters(tname, f"module_types.{tname!r}")
        if tname in MODULE_TYPES:
            raise InputError(f"module_types.{tname}", "redefines a built-in type; choose "
                             "another name and use like = \"" + tname + "\"")
        known[tname] = _module_type(tname, table, known)
    mods = doc.get("modules")
    if not isinstance(mods, list) or not mods:
        raise InputError("modules", "needs at least one [[modules]] entry")
    modules = []
    for k, entry in enumerate(mods):
        where = f"modules[{k}]"
        _check_keys(entry, {"type", "twist", "twist_deg", "spring"}, where)
        if "type" not in entry:
            raise InputError(f"{where}.type", "missing; known types are "
                             f"{', '.join(sorted(known))}")
        tname = _type_name(entry["type"], f"{where}.type", known)
        if tname not in known:
            raise InputError(f"{where}.type", f"unknown module type {tname!r}; known types are "
                             f"{', '.join(sorted(known))}")
        mtype = known[tname]
        if "spring" in entry and mtype.spring_max == 0.0:
            raise InputError(f"{where}.spring", f"module type {tname!r} has no spring")
        twist = _angle(entry, "twist", where)
        if abs(twist) > TWIST_MAX:
            key = "twist_deg" if "twist_deg" in entry else "twist"
            raise InputError(f"{where}.{key}", f"{entry[key]!r} is more than a full turn (give "
                             "the twist within ±360°)")
        modules.append(Module(index=k, type=mtype, twist=twist,
                              spring=_spring(entry.get("spring"), f"{where}.spring", mtype)))
    base = _pose(doc.get("base"), "base")
    tool = _pose(doc.get("tool"), "tool")
    home = None
    if "home" in doc and "home_deg" in doc:
        raise InputError("home", "give home or home_deg, not both")
    if "home" in doc or "home_deg" in doc:
        key = "home" if "home" in doc else "home_deg"
        home = np.array(_vector(doc[key], len(modules), key))
        if key == "home_deg":
            home = np.deg2rad(home)
        for k, mod in enumerate(modules):
            if abs(home[k]) > mod.type.joint_limit:
                raise InputError(f"{key}[{k}]", "outside the joint's range "
                                 f"±{math.degrees(mod.type.joint_limit):g}°")
    _check_plausible(user_types, known, modules, base, tool)
    return Robot(name, modules, base=base, tool=tool, home=home)


#: Ranges a module of a modular arm can have (docs/robot.md "Plausibility"); outside them a
#: description is refused, beyond the ``warn`` figures it is loaded with a warning.
LENGTH_MAX = 1.0            # m, each of a module's two link lengths
LENGTH_WARN = 0.5           # m
MODULE_LENGTH_MIN = 0.01    # m, length_a + length_b: a joint module has a body
MASS_PRECISION = 1e-3       # largest relative error of a link mass in the node's THETA_M word
MASS_WARN = 10.0            # kg per link
MAX_SPEED_MAX = 20.0        # rad/s at the joint: a harmonic drive's output is a few rad/s
TWIST_MAX = 2 * math.pi     # rad
TOOL_MAX = 2.0              # m from the last module's tip interface
TOOL_WARN = 0.5             # m
BASE_MAX = 10.0             # m from the world origin


#: How far a given m·rᵢ² may lie from (m rᵢ)²/m, the value its m and m rᵢ imply: 5 % (Table 1
#: prints three significant figures, which move the product by well under 1 %) or
#: :data:`SECOND_MOMENT_ATOL`, whichever is larger.
SECOND_MOMENT_RTOL = 0.05
SECOND_MOMENT_ATOL = 1e-6   # kg·m²


def _check_second_moments(theta, field: str) -> None:
    """The m·rᵢ² entries (θ₅…θ₇) are redundant: they follow from m and m rᵢ. A description
    whose entries disagree beyond the tolerance is refused, naming the entry (the loader
    recomputes them, so a disagreement would otherwise vanish silently; the built-in Type I's
    Link b has one such misprint, docs/robot.md, and is not a user's description)."""
    m = theta[0]
    for i, axis in enumerate("xyz"):
        implied = theta[1 + i] ** 2 / m
        given = theta[4 + i]
        if abs(given - implied) > max(SECOND_MOMENT_RTOL * abs(implied), SECOND_MOMENT_ATOL):
            raise InputError(f"{field}[{4 + i}]", f"m·r{axis}² = {given:g} kg·m² disagrees "
                             f"with m = {m:g} kg and m·r{axis} = {theta[1 + i]:g} kg·m, which "
                             f"give {implied:.4g} (tolerance {SECOND_MOMENT_RTOL:.0%})")


def _check_plausible(user_types: dict, known: dict, modules, base, tool) -> None:
    """Refuse what no modular arm has (each a named :class:`InputError`), warn on the unusual.

    The ranges are :data:`LENGTH_MAX` … :data:`BASE_MAX` (docs/robot.md "Plausibility"); a
    link's mass must reach the node's THETA_M word with at most :data:`MASS_PRECISION`
    relative error (a 1e-12 kg link reached the node as 0 kg and ran), and fit it.
    """
    import logging

    from mrm_cosim.protocol.fixed import THETA

    log = logging.getLogger("mrm_cosim.models")
    for tname in user_types:
        t = known[tname]
        where = f"module_types.{tname}"
        for key in ("length_a", "length_b"):
            v = getattr(t, key)
            if v > LENGTH_MAX:
                raise InputError(f"{where}.{key}", f"{v:g} m is longer than a module's link "
                                 f"can be (at most {LENGTH_MAX:g} m; lengths are in metres)")
            if v > LENGTH_WARN:
                log.warning("%s.%s: %g m is an unusually long module link", where, key, v)
        if t.length_a + t.length_b < MODULE_LENGTH_MIN:
            raise InputError(f"{where}.length_a", f"length_a + length_b = "
                             f"{t.length_a + t.length_b:g} m is shorter than a joint module "
                             f"can be (at least {MODULE_LENGTH_MIN:g} m)")
        if t.max_speed > MAX_SPEED_MAX:
            raise InputError(f"{where}.max_speed", f"{t.max_speed:g} rad/s is beyond any "
                             f"joint drive's output speed (at most {MAX_SPEED_MAX:g} rad/s)")
        fmt = THETA[0]
        for link in ("link_a", "link_b"):
            m = getattr(t, link).mass
            if m > fmt.max:
                raise InputError(f"{where}.{link}", f"a mass of {m:g} kg does not fit the "
                                 f"node's {fmt.name} word (at most {fmt.max:g} kg)")
            err = abs(fmt.decode(fmt.encode(m)) - m) / m
            if err > MASS_PRECISION:
                raise InputError(f"{where}.{link}", f"a mass of {m:g} kg reaches the node as "
                                 f"{fmt.decode(fmt.encode(m)):g} kg (its {fmt.name} word's step "
                                 f"is {fmt.resolution:g} kg); at least "
                                 f"{fmt.resolution / MASS_PRECISION:g} kg")
            if m > MASS_WARN:
                log.warning("%s.%s: %g kg is an unusually heavy module link", where, link, m)
    if np.linalg.norm(tool[:3, 3]) > TOOL_MAX:
        raise InputError("tool.xyz", f"the tool point is {np.linalg.norm(tool[:3, 3]):g} m "
                         f"from the flange (at most {TOOL_MAX:g} m; lengths are in metres)")
    if np.linalg.norm(tool[:3, 3]) > TOOL_WARN:
        log.warning("tool.xyz: the tool point is %g m from the flange",
                    np.linalg.norm(tool[:3, 3]))
    if np.linalg.norm(base[:3, 3]) > BASE_MAX:
        raise InputError("base.xyz", f"the base is {np.linalg.norm(base[:3, 3]):g} m from the "
                         f"world origin (at most {BASE_MAX:g} m)")
