"""The physical plant: rigid bodies (pinocchio) + harmonic drives, stepped at a fixed 10 µs.

Per joint ``i`` the plant integrates (joint-space, ``n`` joints)::

    (M(q) + diag(J_r)) q̈ + c(q, q̇) + g(q) = τ_m + τ_s(q) − τ_f

* ``M, c, g``: rigid bodies of the robot description (``robot.pinocchio_model()``), evaluated
  by pinocchio with the reflected rotor inertia ``J_r`` as armature (``models.actuators``);
* ``τ_m``: motor torque, the command through the amplifier (``models.drive.CurrentLoop``:
  clip to ± peak torque, first-order current loop);
* ``τ_s``: Type II counterbalance spring ``A cos(q + φ)``;
* ``τ_f``: friction, Coulomb + viscous + Stribeck with true stiction
  (``models.drive.FrictionParams``, ``solve_stick_slip``).

The true parameters are the nominal ones perturbed by a seeded, configurable amount
(:func:`true_parameters`): link inertias by an affine deformation of each body's mass
distribution (always physically valid), rotor inertia, friction and springs by factors. The
controller never sees them.

Integrator (``docs/plant.md`` has its derivation and measured error): a midpoint
(Störmer–Verlet / Moreau) time-stepping scheme, second order for the smooth dynamics, with the
friction law solved implicitly at the velocity level so stuck joints end every step at exactly
zero velocity and their angle does not change by a single bit::

    q_m  = q + h/2 · v
    v⁺   = v + h · M(q_m)⁻¹ (τ̄_m + τ_s(q_m) − c(q_m, v_m) − g(q_m) − b v − τ_F),
           τ_F ∈ F(|v|) · ∂|v⁺|     (set-valued Coulomb/Stribeck part, solved exactly)
    q⁺   = q_m + h/2 · v⁺

with ``τ̄_m`` the exact mean of the motor torque over the step and ``v_m = v + h/2 · a_prev``
a predicted mid-step velocity for the velocity-dependent terms.
"""

from __future__ import annotations

import math
from math import cos, exp, isfinite, sqrt
from dataclasses import dataclass, field, replace

import numpy as np
import pinocchio as pin

from mrm_cosim.models.actuators import ACTUATORS, ActuatorSpec
from mrm_cosim.models.brake import BrakeConfig
from mrm_cosim.models.drive import CurrentLoop, FrictionParams, solve_stick_slip
from mrm_cosim.models.encoder import (
    CYCLE, EncoderCycles, count_changes_lists, counts_per_rad, cycle_counts, joint_counts,
    quadrature_levels,
)
from mrm_cosim.errors import InputError, require_finite, require_nonnegative, require_positive
from mrm_cosim.models.gear import GearConfig

__all__ = ["Perturbation", "PlantConfig", "PlantTruth", "true_parameters", "perturb_inertia",
           "Plant", "SPRING_PHASE_SCALE", "JOINTS", "make_plant"]

JOINTS = ("rigid", "compliant")
"""The joint models a plant can have (``[plant] joints``)."""

SPRING_PHASE_SCALE = 0.1
"""Spring phase perturbation at a full (1.0) spring perturbation, rad: the preload angle is
less certain than its torque (assumption, ``docs/plant.md``)."""

_MAX_PERTURBATION = 0.5


@dataclass(frozen=True)
class Perturbation:
    """How far the true plant is from nominal: relative half-widths of uniform distributions.

    Attributes
    ----------
    links : float
        Link inertial parameters (mass, first and second moments), via a random affine
        deformation of each body (:func:`perturb_inertia`).
    rotor_inertia : float
        Reflected rotor inertia of each joint.
    friction : float
        Each friction parameter of each joint (Coulomb level, static excess, Stribeck
        velocity, viscous coefficient), independently.
    spring : float
        Spring torque amplitude; the phase moves by ``spring · SPRING_PHASE_SCALE`` rad at most.
    """

    links: float = 0.1
    rotor_inertia: float = 0.1
    friction: float = 0.2
    spring: float = 0.1

    def __post_init__(self):
        for name in ("links", "rotor_inertia", "friction", "spring"):
            value = require_nonnegative(getattr(self, name), f"plant.perturbation.{name}")
            if value > _MAX_PERTURBATION:
                raise InputError(f"plant.perturbation.{name}",
                                 f"must be at most {_MAX_PERTURBATION}, not {value!r}")
            object.__setattr__(self, name, value)

    @classmethod
    def uniform(cls, amount: float) -> Perturbation:
        """The same relative amount for every parameter group (0: the nominal plant)."""
        return cls(amount, amount, amount, amount)


@dataclass(frozen=True)
class PlantConfig:
    """Plant settings.

    Attributes
    ----------
    dt : float, s
        Fixed step; a whole number of FPGA cycles (default 10 µs = 500 cycles of 20 ns).
    perturbation : Perturbation or float
        True-versus-nominal spread; a float means :meth:`Perturbation.uniform`.
    friction : bool
        Joint friction on (off only for checks against friction-free references).
    springs : bool
        Type II counterbalance springs on.
    current_loop : bool
        Amplifier current loop lag on; off makes the amplifier an ideal (still saturating)
        torque source.
    current_bandwidth : float or None, Hz
        Overrides every actuator's current-loop bandwidth.
    cycle : float, s
        FPGA clock period the encoder lines are produced for.
    joints : str
        ``"rigid"`` (this module's :class:`Plant`) or ``"compliant"`` (each joint a two-inertia
        system through its harmonic drive: :class:`models.compliant.CompliantPlant`).
    gear : GearConfig
        The compliant joints' settings (unused by the rigid plant).
    brake : BrakeConfig
        The joints' holding brakes (``[plant.brake]``, :mod:`models.brake`); released unless
        :meth:`Plant.set_brake` engages them.
    """

    dt: float = 1e-5
    perturbation: Perturbation | float = field(default_factory=Perturbation)
    friction: bool = True
    springs: bool = True
    current_loop: bool = True
    current_bandwidth: float | None = None
    cycle: float = CYCLE
    joints: str = "rigid"
    gear: GearConfig = field(default_factory=GearConfig)
    brake: BrakeConfig = field(default_factory=BrakeConfig)

    def __post_init__(self):
        if self.joints not in JOINTS:
            raise InputError("plant.joints", f"must be one of {', '.join(map(repr, JOINTS))}, "
                             f"not {self.joints!r}")
        if not isinstance(self.gear, GearConfig):
            raise InputError("plant.gear", f"must be a table, not {self.gear!r}")
        if not isinstance(self.brake, BrakeConfig):
            raise InputError("plant.brake", f"must be a table, not {self.brake!r}")
        dt = require_positive(self.dt, "plant.dt")
        cycle = require_positive(self.cycle, "plant.cycle")
        cycles = round(dt / cycle)
        if cycles < 1 or abs(cycles * cycle - dt) > 1e-9 * dt:
            raise InputError("plant.dt", f"must be a whole number of FPGA cycles of {cycle!r} s, "
                             f"not {dt!r}")
        if dt > 1e-3:
            raise InputError("plant.dt", f"must be at most 1 ms for an accurate plant, not {dt!r}")
        object.__setattr__(self, "dt", dt)
        object.__setattr__(self, "cycle", cycle)
        p = self.perturbation
        if not isinstance(p, Perturbation):
            amount = require_finite(p, "plant.perturbation")
            if not 0.0 <= amount <= _MAX_PERTURBATION:
                raise InputError("plant.perturbation",
                                 f"must be in [0, {_MAX_PERTURBATION}], not {p!r}")
            p = Perturbation.uniform(amount)
        object.__setattr__(self, "perturbation", p)
        if self.current_bandwidth is not None:
            object.__setattr__(self, "current_bandwidth",
                               require_positive(self.current_bandwidth, "plant.current_bandwidth"))
        for name in ("friction", "springs", "current_loop"):
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"plant.{name}", f"must be true or false, not "
                                 f"{getattr(self, name)!r}")

    @property
    def cycles_per_step(self) -> int:
        """FPGA cycles per plant step."""
        return round(self.dt / self.cycle)


@dataclass(frozen=True, eq=False)
class PlantTruth:
    """The plant's true parameters. Diagnostics and tests only: no controller may read them.

    Attributes
    ----------
    model : pinocchio.Model
        True rigid bodies, with ``armature`` set to ``rotor_inertia``.
    rotor_inertia : ndarray, shape (n,), kg·m²
        Reflected rotor inertia at the joint.
    friction : FrictionParams
    spring_torque, spring_phase : ndarray, shape (n,), N·m and rad
        ``τ_s = spring_torque · cos(q + spring_phase)`` (0 where no spring is fitted).
    peak_torque : ndarray, shape (n,), N·m
    current_time_constant : ndarray, shape (n,), s
    counts_per_rev : ndarray of int64, shape (n,)
        Encoder counts per joint revolution of each module (its type's encoder_lines × 4 ×
        gear_ratio: a module may fit another encoder than its actuator's catalogue one).
    actuators : tuple of ActuatorSpec
    """

    model: pin.Model
    rotor_inertia: np.ndarray
    friction: FrictionParams
    spring_torque: np.ndarray
    spring_phase: np.ndarray
    peak_torque: np.ndarray
    current_time_constant: np.ndarray
    counts_per_rev: np.ndarray
    actuators: tuple[ActuatorSpec, ...]

    def with_friction(self, **changes) -> PlantTruth:
        """A copy whose friction has the given fields replaced (arrays of shape (n,))."""
        return replace(self, friction=replace(self.friction, **changes))


def perturb_inertia(inertia: pin.Inertia, amount: float, rng: np.random.Generator) -> pin.Inertia:
    """A rigid body deformed by a random affine map of its mass distribution.

    Every point ``x`` of the body moves to ``A x + t`` and the density scales by ``s``:
    ``s = 1 + amount · u``, ``A = E + amount/2 · Z``, ``t = amount · ρ · ξ`` with
    ``u, Z_ij, ξ_k`` uniform in [−1, 1] and ``ρ`` the rms distance of the mass from the body
    origin. Mass, first moment and second moments change together, and the result is the
    inertia of a real mass distribution (the pseudo-inertia ``s T J Tᵀ`` of Wensing, Kim and
    Slotine, IEEE RA-L 2018, stays positive definite). Draws 13 numbers whatever ``amount``
    is; ``amount == 0`` returns the body unchanged.
    """
    u = rng.uniform(-1.0, 1.0)
    Z = rng.uniform(-1.0, 1.0, size=(3, 3))
    xi = rng.uniform(-1.0, 1.0, size=3)
    if amount == 0.0:
        return pin.Inertia(inertia)
    m = inertia.mass
    c = np.array(inertia.lever)
    Ic = np.array(inertia.inertia)
    sigma = 0.5 * np.trace(Ic) * np.eye(3) - Ic        # second moment about the centre of mass
    rho = math.sqrt(c @ c + np.trace(sigma) / m)
    s = 1.0 + amount * u
    A = np.eye(3) + 0.5 * amount * Z
    t = amount * rho * xi
    sigma_new = s * (A @ sigma @ A.T)
    Ic_new = np.trace(sigma_new) * np.eye(3) - sigma_new
    Ic_new = 0.5 * (Ic_new + Ic_new.T)
    return pin.Inertia(s * m, A @ c + t, Ic_new)


def _scale(nominal: np.ndarray, amount: float, rng: np.random.Generator) -> np.ndarray:
    z = rng.uniform(-1.0, 1.0, size=nominal.shape)
    return nominal if amount == 0.0 else nominal * (1.0 + amount * z)


def _module_spring(module):
    spring = getattr(module, "spring", None)
    if spring is None and not hasattr(module, "spring"):
        spring = getattr(module.type, "spring", None)
    return spring


def true_parameters(robot, config: PlantConfig | None = None, seed: int = 0) -> PlantTruth:
    """The plant's true parameters for a robot, a configuration and a seed (deterministic).

    Parameters
    ----------
    robot : models.robot.Robot
        Needs ``n``, ``modules`` (``module.type.actuator``, ``module.spring``) and
        ``pinocchio_model()``.
    config : PlantConfig
    seed : int
        Seed of the perturbation; each parameter group has its own stream
        (``numpy.random.SeedSequence(seed).spawn(4)``), so changing one group's amount leaves
        the others' draws alone.

    Raises
    ------
    InputError
        Unknown actuator name, or a bad seed.
    """
    config = PlantConfig() if config is None else config
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError("seed", f"must be a non-negative integer, not {seed!r}")
    p = config.perturbation
    n = robot.n
    specs = []
    for k, module in enumerate(robot.modules):
        name = module.type.actuator
        if name not in ACTUATORS:       # a Robot built in code (a file's are checked at load)
            where = (module.type.source if module.type.source.startswith("module_types.")
                     else f"modules[{k}]")
            raise InputError(f"{where}.actuator", f"unknown actuator {name!r}; known: "
                             f"{', '.join(sorted(ACTUATORS))}")
        specs.append(ACTUATORS[name])
    rng_links, rng_rotor, rng_friction, rng_spring = (
        np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(4))

    model = robot.pinocchio_model()
    if model.nv != n:
        raise InputError("robot", f"pinocchio model has {model.nv} joints, robot {n}")
    for j in range(1, model.njoints):
        model.inertias[j] = perturb_inertia(model.inertias[j], p.links, rng_links)

    rotor = _scale(np.array([s.output_inertia for s in specs]), p.rotor_inertia, rng_rotor)
    model.armature = rotor.copy()

    fc = np.array([s.coulomb_friction for s in specs])
    excess = np.array([s.static_friction - s.coulomb_friction for s in specs])
    vs = np.array([s.stribeck_velocity for s in specs])
    b = np.array([s.viscous_friction for s in specs])
    fc_true = _scale(fc, p.friction, rng_friction)
    excess_true = _scale(excess, p.friction, rng_friction)
    friction = FrictionParams(fc_true, fc_true + excess_true,
                              _scale(vs, p.friction, rng_friction),
                              _scale(b, p.friction, rng_friction))

    amp = np.zeros(n)
    phase = np.zeros(n)
    for k, module in enumerate(robot.modules):
        spring = _module_spring(module)
        if spring is not None:
            amp[k] = spring.torque
            phase[k] = spring.phase
    amp_true = _scale(amp, p.spring, rng_spring)
    z = rng_spring.uniform(-1.0, 1.0, size=n)
    phase_true = phase if p.spring == 0.0 else phase + p.spring * SPRING_PHASE_SCALE * z
    phase_true = np.where(amp == 0.0, 0.0, phase_true)

    if config.current_bandwidth is not None:
        tau_i = np.full(n, 1.0 / (2.0 * math.pi * config.current_bandwidth))
    else:
        tau_i = np.array([s.current_time_constant for s in specs])
    return PlantTruth(
        model=model, rotor_inertia=rotor, friction=friction, spring_torque=amp_true,
        spring_phase=phase_true, peak_torque=np.array([s.peak_torque for s in specs]),
        current_time_constant=tau_i,
        counts_per_rev=np.asarray(robot.counts_per_rev, dtype=np.int64),
        actuators=tuple(specs))


class Plant:
    """The robot's physical plant, advanced in fixed steps by the co-simulation.

    Parameters
    ----------
    robot : models.robot.Robot
    config : PlantConfig, optional
    seed : int
        Seed of the true-versus-nominal perturbation.
    truth : PlantTruth, optional
        Use these true parameters instead of drawing them (what-if studies, tests).

    Attributes
    ----------
    n : int
        Number of joints.
    dt : float, s
    cycles_per_step : int
        FPGA cycles per step (500 at 10 µs and 50 MHz).

    Notes
    -----
    State is ``q``, ``qd``, ``tau_motor`` and ``t``; the same inputs, config and seed give the
    same trajectory bit for bit. The initial state is ``robot.home`` at rest with zero motor
    torque.

    The per-joint arithmetic of a step runs on Python floats (for the handful of joints of an
    arm that is about three times faster than a chain of tiny numpy operations); pinocchio works
    on preallocated arrays, and the set-valued friction solve on numpy arrays.
    """

    def __init__(self, robot, config: PlantConfig | None = None, seed: int = 0, *,
                 truth: PlantTruth | None = None):
        self.config = PlantConfig() if config is None else config
        self._truth = true_parameters(robot, self.config, seed) if truth is None else truth
        tr = self._truth
        n = self.n = robot.n
        if tr.model.nv != n:
            raise InputError("truth", f"has {tr.model.nv} joints, the robot {n}")
        self.dt = self.config.dt
        self.cycles_per_step = self.config.cycles_per_step
        self._model = tr.model
        self._data = tr.model.createData()
        loop = CurrentLoop(tr.current_time_constant if self.config.current_loop
                           else np.zeros(n), tr.peak_torque, self.dt)
        self._alpha = loop.alpha.tolist()
        self._beta = loop.beta.tolist()
        self._peak = tr.peak_torque.tolist()
        fr = tr.friction if self.config.friction else FrictionParams.zero(n)
        self._has_friction = bool(self.config.friction)
        self._fc = fr.coulomb.tolist()
        self._fs_excess = (fr.static - fr.coulomb).tolist()
        self._inv_vs = (1.0 / fr.stribeck_velocity).tolist()
        self._visc = fr.viscous.tolist()
        amp = tr.spring_torque if self.config.springs else np.zeros(n)
        self._springs = [(i, float(amp[i]), float(tr.spring_phase[i]))
                         for i in range(n) if amp[i] != 0.0]
        self._k = counts_per_rad(tr.counts_per_rev)
        self._kl = self._k.tolist()
        # state (Python floats) and pinocchio's preallocated inputs
        self._q = [0.0] * n
        self._v = [0.0] * n
        self._tau = [0.0] * n
        self._a_prev = [0.0] * n
        self._q_start = [0.0] * n
        self._v_start = [0.0] * n
        self._qm = np.zeros(n)
        self._vm = np.zeros(n)
        self._force = np.zeros(n)
        self._rho = [0.0] * n
        self._level = [0.0] * n
        self._sign = [0.0] * n
        self._lower = np.tril_indices(n, -1)
        # the holding brakes (models.brake): at the joint, static and slipping; the rows the
        # step reads (the level where engaged, else 0) and the command's progress
        bc = self.config.brake
        self._brake_hold = bc.holding_at_joint(tr.actuators)
        self._brake_slip = [bc.slip_ratio * x for x in self._brake_hold]
        self._brake_engage, self._brake_release = bc.steps(self.dt)
        self._bh = [0.0] * n
        self._bs = [0.0] * n
        self._stepped = False
        self._kern = None                       # use_kernel: the compiled step's functions
        self._S = None
        home = getattr(robot, "home", None)
        self.reset(np.zeros(n) if home is None else home)

    # --- state -------------------------------------------------------------------------------
    @property
    def q(self) -> np.ndarray:
        """Joint angles, rad, shape (n,) (a copy)."""
        return np.array(self._q)

    @property
    def qd(self) -> np.ndarray:
        """Joint velocities, rad/s, shape (n,) (a copy)."""
        return np.array(self._v)

    @property
    def tau_motor(self) -> np.ndarray:
        """Motor torque at the joint after current-loop lag and saturation, N·m (a copy)."""
        return np.array(self._tau)

    @property
    def t(self) -> float:
        """Simulated time since the last reset, s (``steps · dt``, no accumulated rounding)."""
        return self._steps * self.dt

    @property
    def steps(self) -> int:
        """Steps taken since the last reset."""
        return self._steps

    def _vector(self, value, field_name: str) -> np.ndarray:
        try:
            a = np.array(value, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise InputError(field_name, f"must be {self.n} numbers, not {value!r}") from None
        if a.shape != (self.n,):
            raise InputError(field_name, f"must have {self.n} values, not {a.size}")
        if not np.all(np.isfinite(a)):
            raise InputError(field_name, f"must be finite, not {a.tolist()!r}")
        return a

    def reset(self, q0, qd0=None, tau_motor0=None) -> None:
        """Start again at time 0 from the given state.

        Parameters
        ----------
        q0 : array_like, shape (n,), rad
        qd0 : array_like, shape (n,), rad/s, optional (default at rest)
        tau_motor0 : array_like, shape (n,), N·m, optional (default 0)
            Initial motor torque, within ± peak torque.
        """
        q0 = self._vector(q0, "q0")
        v0 = np.zeros(self.n) if qd0 is None else self._vector(qd0, "qd0")
        t0 = np.zeros(self.n) if tau_motor0 is None else self._vector(tau_motor0, "tau_motor0")
        over = np.abs(t0) > self._truth.peak_torque
        if np.any(over):
            k = int(np.argmax(over))
            raise InputError(f"tau_motor0[{k}]", f"|{t0[k]}| N·m exceeds the peak torque "
                             f"{self._truth.peak_torque[k]} N·m")
        self._q = q0.tolist()
        self._v = v0.tolist()
        self._tau = t0.tolist()
        self._a_prev = [0.0] * self.n
        self._steps = 0
        self._stepped = False
        self._brake_reset()
        if self._kern is not None:
            self._bind_state()

    # --- the holding brakes --------------------------------------------------------------------
    def _brake_reset(self) -> None:
        n = self.n
        self._brake_cmd = [False] * n           # commanded engaged
        self._brake_eff = [False] * n           # engaged (the torque acts)
        self._brake_left = [0] * n              # steps until the effective state follows
        self._brake_on = False                  # any engaged: the step's friction solve runs
        self._bh = [0.0] * n
        self._bs = [0.0] * n

    def set_brake(self, engage) -> None:
        """Command the joints' holding brakes from the next step on (the command holds until
        changed; :mod:`models.brake`): ``engage`` array_like of bool, shape (n,), True engages.
        The torque follows ``engage_time`` / ``release_time`` later (whole steps)."""
        cmd = self._brake_cmd
        for i, e in enumerate(self._brake_mask(engage)):
            if e == cmd[i]:
                continue
            cmd[i] = e
            if e == self._brake_eff[i]:
                self._brake_left[i] = 0         # taken back before it acted
            else:
                self._brake_left[i] = self._brake_engage if e else self._brake_release

    def _brake_mask(self, engage) -> list[bool]:
        try:
            a = np.asarray(engage)
        except (TypeError, ValueError):
            a = None
        if a is None or a.shape != (self.n,) or a.dtype.kind not in "bui":
            raise InputError("brake", f"must be {self.n} booleans, not {engage!r}")
        return [bool(x) for x in a.tolist()]

    @property
    def brake_engaged(self) -> np.ndarray:
        """Which joints' brakes hold (their torque acts), bool, shape (n,)."""
        return np.array(self._brake_eff, dtype=bool)

    @property
    def brake_idle(self) -> bool:
        """Every brake released and none commanded: the step is the brake-free one (a caller
        that steps the plant itself, :meth:`kernel_parts`, may run only then)."""
        return not (any(self._brake_cmd) or self._brake_on or any(self._brake_left))

    def _brake_advance(self) -> None:
        """After a step: the commands' timers; the levels the next step reads."""
        left = self._brake_left
        if not any(left):
            return
        eff, bh, bs = self._brake_eff, self._bh, self._bs
        for i in range(self.n):
            if left[i]:
                left[i] -= 1
                if not left[i]:
                    eff[i] = self._brake_cmd[i]
                    bh[i] = self._brake_hold[i] if eff[i] else 0.0
                    bs[i] = self._brake_slip[i] if eff[i] else 0.0
        self._brake_on = any(eff)

    # --- the compiled step ---------------------------------------------------------------------
    def use_kernel(self, kern) -> None:
        """Run :meth:`step` on compiled code from now on: ``kern`` is
        :mod:`models.plant_kernel_src` with its functions compiled (numba), the same float
        operations in the same order, pinocchio called from Python between them; the results
        are those of the Python step bit for bit. The state moves into one array (the list
        attributes become views of its rows)."""
        from mrm_cosim.models import plant_kernel_src as ks

        C = np.zeros((ks.C_ROWS, self.n))
        C[ks.ALPHA], C[ks.BETA], C[ks.PEAK] = self._alpha, self._beta, self._peak
        C[ks.FC], C[ks.FSX], C[ks.INV_VS], C[ks.VISC] = \
            self._fc, self._fs_excess, self._inv_vs, self._visc
        for i, amp, phase in self._springs:
            C[ks.AMP, i], C[ks.PHASE, i], C[ks.HAS_SPRING, i] = amp, phase, 1.0
        self._C = C
        self._kern = kern
        self._bind_state()

    def _bind_state(self) -> None:
        """The state lists into the kernel's array, the list attributes as its rows."""
        from mrm_cosim.models import plant_kernel_src as ks

        S = self._S = np.zeros((ks.S_ROWS, self.n))
        for row, name in ((ks.Q, "_q"), (ks.V, "_v"), (ks.TAU, "_tau"), (ks.A_PREV, "_a_prev"),
                          (ks.Q_START, "_q_start"), (ks.V_START, "_v_start"),
                          (ks.BRAKE, "_bh"), (ks.BRAKE_SLIP, "_bs")):
            S[row] = getattr(self, name)
            setattr(self, name, S[row])
        self._qm, self._vm = S[ks.QM], S[ks.VM]

    def _step_kernel(self, arr: np.ndarray) -> None:
        """:meth:`step` on the compiled functions (:meth:`use_kernel`); ``arr`` of shape (n,)."""
        from mrm_cosim.models.plant_kernel_src import FORCE, QM, VM

        k, S, h = self._kern, self._S, self.dt
        hh = 0.5 * h
        sliding = k.pre(S, self._C, arr, hh)
        if sliding < 0:
            raise InputError("tau_cmd", f"must be finite, not {arr.tolist()!r}")
        model, data = self._model, self._data
        done = False
        fr = self._has_friction or self._brake_on
        if not fr or sliding:
            k.free_force(S, 1.0 if fr else 0.0)
            done = k.free_end(S, pin.aba(model, data, S[QM], S[VM], S[FORCE]), h, fr)
        if not done:
            self._stick_slip_kernel()
        k.finish(S, h, hh)
        self._steps += 1
        self._stepped = True
        self._brake_advance()

    def _stick_slip_kernel(self) -> None:
        """:meth:`_step_kernel`'s set-valued friction solve (after ``pre``, where the free step
        does not apply): the end velocities into the state's ``NEW`` row."""
        k, S = self._kern, self._S
        model, data, qm = self._model, self._data, self._qm
        if not k.stuck(S, pin.nonLinearEffects(model, data, qm, self._vm)):
            M = pin.crba(model, data, qm)                  # upper triangle filled
            if k.likely_pattern(S, M, self.dt) != 1:
                self._solve_kernel(M)

    def _solve_kernel(self, M: np.ndarray) -> None:
        """The stick-slip solve's general case (``M`` from ``crba``, upper triangle)."""
        from mrm_cosim.models.plant_kernel_src import FORCE, LEVEL, NEW, V

        S, h = self._S, self.dt
        M[self._lower] = M.T[self._lower]
        S[NEW], _ = solve_stick_slip(M, h * S[FORCE], S[V].copy(), h * S[LEVEL])

    def kernel_parts(self) -> tuple:
        """For a compiled caller that runs :meth:`step` itself (the model backend's fast
        path, :meth:`cosim.model.ModelBackend.fast_path`), after :meth:`use_kernel`: ``(S, C,
        model, data, qm, vm, force, solve, stepped)``: the state and constant arrays,
        pinocchio's model and data and the rows it reads, :meth:`_solve_kernel` and
        :meth:`_stepped_by`. A step is :meth:`_step_kernel`'s sequence:
        ``pre_free(S, C, cmd, dt / 2, friction)`` (:func:`models.plant_kernel_src.pre_free`);
        where it returns 1, ``free_end`` on ``pin.aba(model, data, qm, vm, force)``; where it
        returns 0 or ``free_end`` fails, ``stuck`` on ``pin.nonLinearEffects(model, data, qm,
        vm)``, else ``likely_pattern`` on ``pin.crba(model, data, qm)``, else ``solve(M)``;
        then ``finish``; and ``stepped(k)`` after ``k`` such steps."""
        from mrm_cosim.models.plant_kernel_src import FORCE

        if self._kern is None:
            raise RuntimeError("kernel_parts needs use_kernel first")
        S = self._S
        return (S, self._C, self._model, self._data, self._qm, self._vm, S[FORCE],
                self._solve_kernel, self._stepped_by)

    @property
    def friction_on(self) -> bool:
        """Whether the plant has joint friction (the stick-slip solve may run)."""
        return self._has_friction

    def _stepped_by(self, k: int) -> None:
        """``k`` steps were taken by a :meth:`kernel_parts` caller."""
        if k:
            self._steps += k
            self._stepped = True

    # --- stepping ----------------------------------------------------------------------------
    def _command(self, tau_cmd) -> np.ndarray:
        """``tau_cmd`` as a float array of shape (n,), or :class:`InputError` naming it (its
        values are checked for finiteness where each step path reads them)."""
        try:
            arr = np.asarray(tau_cmd, dtype=float)
        except (TypeError, ValueError):
            raise InputError("tau_cmd", f"must be {self.n} numbers, not {tau_cmd!r}") from None
        if arr.shape != (self.n,):
            raise InputError("tau_cmd", f"must have shape ({self.n},), not {arr.shape}")
        return arr

    def step(self, tau_cmd) -> None:
        """Advance one step of ``dt`` with the torque command held over it.

        Parameters
        ----------
        tau_cmd : array_like, shape (n,), N·m at the joint
            Command to the amplifier (clipped at ± peak torque there).

        Raises
        ------
        InputError
            A command of the wrong length or not finite (the state is left unchanged).
        """
        arr = self._command(tau_cmd)
        if self._kern is not None:
            self._step_kernel(arr)
            return
        cmd = arr.tolist()
        for x in cmd:
            if not isfinite(x):
                raise InputError("tau_cmd", f"must be finite, not {cmd!r}")
        h = self.dt
        hh = 0.5 * h
        q, v, tau, a_prev = self._q, self._v, self._tau, self._a_prev
        qm, vm = self._qm, self._vm
        rho, level, sign = self._rho, self._level, self._sign
        alpha, beta, peak = self._alpha, self._beta, self._peak
        fc, fsx, inv_vs, visc = self._fc, self._fs_excess, self._inv_vs, self._visc
        bh, bs = self._bh, self._bs
        self._q_start = q[:]
        self._v_start = v[:]
        sliding = True
        for i in range(self.n):
            # amplifier: saturate, then the current loop's exact response to a held command
            u = cmd[i]
            p = peak[i]
            if u > p:
                u = p
            elif u < -p:
                u = -p
            d = tau[i] - u
            tau[i] = u + d * alpha[i]
            vi = v[i]
            qm[i] = q[i] + hh * vi
            vm[i] = vi + hh * a_prev[i]
            x = vi * inv_vs[i]
            level[i] = fc[i] + fsx[i] * exp(-x * x)
            if bh[i] != 0.0:                                # an engaged brake: held or slipping
                level[i] += bh[i] if vi == 0.0 else bs[i]
            rho[i] = u + d * beta[i] - visc[i] * vi          # mean motor torque − viscous
            if vi > 0.0:
                sign[i] = 1.0
            elif vi < 0.0:
                sign[i] = -1.0
            else:
                sign[i] = 0.0
                sliding = False
        for i, amp, phase in self._springs:
            rho[i] += amp * cos(qm[i] + phase)

        if not (self._has_friction or self._brake_on):
            v_new = self._free_step(rho, 0.0)
        else:
            v_new = self._free_step(rho, 1.0) if sliding else None
            if v_new is not None and any(v_new[i] * sign[i] <= 0.0 for i in range(self.n)):
                v_new = None
            if v_new is None:
                v_new = self._stick_slip_step(rho, level, sign)

        for i in range(self.n):
            w = v_new[i]
            a_prev[i] = (w - v[i]) / h
            v[i] = w
            q[i] = qm[i] + hh * w
        self._steps += 1
        self._stepped = True
        self._brake_advance()

    def _free_step(self, rho, with_friction: float) -> list:
        """End-of-step velocity when every joint slides (or there is no friction): one ABA."""
        f = self._force
        level, sign = self._level, self._sign
        for i in range(self.n):
            f[i] = rho[i] - with_friction * level[i] * sign[i]
        a = pin.aba(self._model, self._data, self._qm, self._vm, f).tolist()
        h, v = self.dt, self._v
        return [v[i] + h * a[i] for i in range(self.n)]

    def _stick_slip_step(self, rho, level, sign) -> list:
        """End-of-step velocity when some joint is at rest or reverses: the set-valued solve.

        First the likely answer is checked cheaply: joints at rest stay stuck, sliding joints
        keep their direction. If that pattern is consistent it is the unique solution;
        otherwise :func:`models.drive.solve_stick_slip` searches for the right one.
        """
        model, data, n, h = self._model, self._data, self.n, self.dt
        bias = pin.nonLinearEffects(model, data, self._qm, self._vm).tolist()
        force = [rho[i] - bias[i] for i in range(n)]
        free = [i for i in range(n) if sign[i] != 0.0]
        if not free and all(abs(force[i]) <= level[i] for i in range(n)):
            # Every joint at rest and each joint's static friction holds its net torque: nothing
            # moves (at rest there is no inertial coupling between the joints).
            return [0.0] * n
        M = pin.crba(model, data, self._qm)           # upper triangle filled
        if free and len(free) < n:
            v_new = self._likely_pattern(M.tolist(), force, level, sign, free)
            if v_new is not None:
                return v_new
        M[self._lower] = M.T[self._lower]            # the general solver needs both triangles
        v_new, _ = solve_stick_slip(M, h * np.array(force), np.array(self._v),
                                    h * np.array(level))
        return v_new.tolist()

    def _likely_pattern(self, Ml, force, level, sign, free) -> list | None:
        """The step if joints at rest stay stuck and sliding joints keep sliding, else None.

        With the stuck joints' velocity change zero, the sliding joints obey
        ``M_FF Δv_F = h (force_F − level_F sgn v_F)``; the pattern is the solution when every
        sliding joint keeps its sign and every stuck joint's holding impulse
        ``h force_S − M_SF Δv_F`` is within ``h level_S``. Pure Python on the small blocks.
        """
        n, h, v = self.n, self.dt, self._v
        A = [[Ml[i][j] if i <= j else Ml[j][i] for j in free] for i in free]
        b = [h * (force[i] - level[i] * sign[i]) for i in free]
        dv = _cholesky_solve(A, b)
        if dv is None:
            return None
        v_new = [0.0] * n
        for k, i in enumerate(free):
            w = v[i] + dv[k]
            if w * sign[i] <= 0.0:
                return None
            v_new[i] = w
        for i in range(n):
            if sign[i] == 0.0:
                hold = h * force[i]
                for k, j in enumerate(free):
                    hold -= (Ml[i][j] if i < j else Ml[j][i]) * dv[k]
                if abs(hold) > h * level[i] * (1.0 + 1e-12):
                    return None
        return v_new

    # --- encoder -----------------------------------------------------------------------------
    def encoder_counts(self) -> np.ndarray:
        """Exact encoder counts ``floor(q · counts_per_rev / 2π)``, int64, shape (n,)."""
        return joint_counts(np.array(self._q), self._k)

    def encoder_cycles(self) -> EncoderCycles:
        """Counts and A/B line levels for each FPGA cycle of the last step.

        Returns
        -------
        EncoderCycles
            ``counts`` (int64), ``a``, ``b`` (uint8), each of shape (cycles_per_step, n);
            row ``k`` is what the FPGA samples in cycle ``k`` of the step (angle at
            ``t_start + (k + 1) · cycle``); the last row equals :meth:`encoder_counts`.

        Raises
        ------
        RuntimeError
            Before the first step after a reset.
        models.encoder.EncoderOverspeed
            If a joint moved more than one count in one cycle.
        """
        if not self._stepped:
            raise RuntimeError("no step taken since the last reset")
        c = cycle_counts(np.array(self._q_start), np.array(self._v_start),
                         np.array(self._a_prev), np.array(self._q), self.dt,
                         self.cycles_per_step, self._k)
        a, b = quadrature_levels(c)
        return EncoderCycles(c, a, b)


    @property
    def counts_per_rad(self) -> np.ndarray:
        """Encoder counts per rad of joint angle, float64, shape (n,) (the plant's own array:
        read it, do not write it)."""
        return self._k

    def motion(self) -> tuple[list, list, list, list]:
        """The last step's motion as :meth:`encoder_changes` samples it: start angles (rad),
        start velocities (rad/s), the step's constant acceleration (rad/s²) and end angles
        (rad), lists of n floats (for a compiled consumer of the changes,
        :func:`cosim.model_kernel_src.step_changes`).

        Raises
        ------
        RuntimeError
            Before the first step after a reset.
        """
        if not self._stepped:
            raise RuntimeError("no step taken since the last reset")
        return self._q_start, self._v_start, self._a_prev, self._q

    def encoder_changes(self) -> list:
        """The count changes of the last step, per joint: what :meth:`encoder_cycles` shows,
        as events (no per-cycle arrays; for consumers that only need the changes).

        Returns
        -------
        list of n lists of (int, int)
            Per joint, ``(cycle, new count)`` in increasing cycle order, cycle ``0 …
            cycles_per_step − 1`` of the step; the count before the first change is the
            previous step's last (or :meth:`encoder_counts` before the step).

        Raises
        ------
        RuntimeError, models.encoder.EncoderOverspeed
            As :meth:`encoder_cycles`.
        """
        if not self._stepped:
            raise RuntimeError("no step taken since the last reset")
        motion = [x.tolist() if isinstance(x, np.ndarray) else x for x in self.motion()]
        return count_changes_lists(*motion, self.dt, self.cycles_per_step, self._kl)[1]

def make_plant(robot, config: PlantConfig | None = None, seed: int = 0) -> Plant:
    """The plant ``config.joints`` asks for: :class:`Plant` (rigid) or
    :class:`models.compliant.CompliantPlant`."""
    config = PlantConfig() if config is None else config
    if config.joints == "compliant":
        from mrm_cosim.models.compliant import CompliantPlant

        return CompliantPlant(robot, config, seed)
    return Plant(robot, config, seed)


def _cholesky_solve(A: list, b: list) -> list | None:
    """Solve ``A x = b`` for a small symmetric positive definite ``A`` (lists); None if not SPD."""
    k = len(b)
    L = [[0.0] * k for _ in range(k)]
    for j in range(k):
        Lj = L[j]
        d = A[j][j]
        for p in range(j):
            d -= Lj[p] * Lj[p]
        if not d > 0.0:
            return None
        d = sqrt(d)
        Lj[j] = d
        for i in range(j + 1, k):
            Li = L[i]
            x = A[i][j]
            for p in range(j):
                x -= Li[p] * Lj[p]
            Li[j] = x / d
    y = [0.0] * k
    for i in range(k):
        x = b[i]
        Li = L[i]
        for p in range(i):
            x -= Li[p] * y[p]
        y[i] = x / Li[i]
    for i in range(k - 1, -1, -1):
        x = y[i]
        for p in range(i + 1, k):
            x -= L[p][i] * y[p]
        y[i] = x / L[i][i]
    return y
