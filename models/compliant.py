"""The compliant plant: every joint a two-inertia system through its harmonic drive.

Per joint ``i``, with the motor angle ``θ`` referred to the output (motor angle / gear ratio)::

    B θ̈            = τ_m + ε − τ_J − τ_F(θ̇)             motor + wave generator side
    M(q) q̈ + c + g = τ_J + τ_s(q)                        link side (pinocchio, no armature)
    τ_J = T(δ) + z + d δ̇ + r,   δ = θ − q + φ0            the gear
    dz/dδ = σ (1 − z / F_h · sgn δ̇)                      its hysteresis (Dahl)

* ``B``: the actuator's output-referred rotor inertia (rotor, wave generator, encoder disc:
  ``models.actuators``), the armature the rigid plant adds to ``M(q)``;
* ``T``: Harmonic Drive's piecewise-linear torque–torsion curve (``models.gear``) of the
  gear's deflection ``δ`` (``φ0``: the static deflection at the reset pose, where the encoders
  are zeroed, :meth:`CompliantPlant.reset`); ``z``: the hysteresis, a Dahl friction torque of
  amplitude ``F_h = T(a)`` (``2a`` the catalogue's hysteresis loss: the loop's width at zero
  torque), ``models.gear.dahl``; ``d δ̇``: structural damping. ``[plant.gear] hysteresis =
  "play"`` replaces ``T(δ) + z`` by the earlier dead-zone model ``T(play_a(δ))`` (damping only
  while engaged);
* ``r = A sin(2 N θ + φ)``: the wave generator's torque ripple, twice per motor revolution;
* ``ε``: current-sensor noise, white over each plant step (the current loop follows the sensor,
  so the noise becomes motor torque); ``τ_m``: the amplifier as in the rigid plant;
* ``τ_F``: the whole joint friction (Coulomb + Stribeck + viscous, with stiction) on the motor
  side, where a harmonic drive's losses are (wave-generator bearing, tooth mesh, motor
  bearings: the catalogue's no-load running and starting torques are input-side figures);
* ``τ_s``: the counterbalance spring, between the links.

The encoder is on the motor (2000 lines × 4 × 100 counts per output revolution): the nodes
count ``θ``, not ``q``. ``q``, ``qd`` are the link's (what the tip error is measured on).

Integrator: the rigid plant's midpoint scheme on both sides; the gear torque at the mid-step
positions with the damping on the start velocities; the link by one ABA; the motor's friction
solved exactly at the velocity level (scalar: the set-valued law ``B(ω⁺ − ω) = h(ρ − F s)``,
``s ∈ Sgn ω⁺``, has the closed-form solution). Stable while ``h²ω² + 2hc ≤ 4`` for the gear
mode (``models.gear.step_bound``, checked at construction, with the Dahl element's largest
tangent stiffness ``2σ`` added to the curve's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from math import cos, exp, isfinite, sin

import numpy as np
import pinocchio as pin

from mrm_cosim.errors import InputError
from mrm_cosim.models.encoder import (
    EncoderCycles, cycle_counts, joint_counts, quadrature_levels,
)
from mrm_cosim.models.gear import (
    GEARS, STEP_MARGIN, check_step, dahl, deflection, gear_torque, play,
)
from mrm_cosim.models.plant import Plant, PlantConfig, PlantTruth, true_parameters

__all__ = ["GearTruth", "gear_truth", "CompliantPlant"]


@dataclass(frozen=True, eq=False)
class GearTruth:
    """The compliant joints' true parameters (diagnostics and tests; no controller reads them).

    Attributes
    ----------
    t1, t2, k1, k2, k3 : ndarray, shape (n,)
        Each gear's curve (N·m, N·m/rad), the stiffness scaled and spread.
    half_play : ndarray, shape (n,), rad
        Half the hysteresis loss where the play model is chosen, else 0.
    hyst_torque : ndarray, shape (n,), N·m
        The Dahl element's amplitude ``F_h = T(a)`` (0: no Dahl hysteresis).
    hyst_sigma : ndarray, shape (n,), N·m/rad
        The Dahl element's stiffness ``σ``.
    damping : ndarray, shape (n,), N·m·s/rad
    motor_inertia : ndarray, shape (n,), kg·m², output-referred
    ratio : ndarray, shape (n,)
        Gear ratio (the ripple is at ``2 · ratio`` per output revolution of the motor).
    ripple, ripple_phase : ndarray, shape (n,), N·m and rad
    noise : ndarray, shape (n,), N·m rms
    """

    t1: np.ndarray
    t2: np.ndarray
    k1: np.ndarray
    k2: np.ndarray
    k3: np.ndarray
    half_play: np.ndarray
    hyst_torque: np.ndarray
    hyst_sigma: np.ndarray
    damping: np.ndarray
    motor_inertia: np.ndarray
    ratio: np.ndarray
    ripple: np.ndarray
    ripple_phase: np.ndarray
    noise: np.ndarray

    def k_max(self) -> np.ndarray:
        return np.maximum(np.maximum(self.k1, self.k2), self.k3)


def gear_streams(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    """The gear draws' and the noise's generators: children 4 and 5 of the plant seed's
    ``SeedSequence`` (children 0-3 are the rigid parameters', left as they are)."""
    ss = np.random.SeedSequence(int(seed)).spawn(6)
    return np.random.default_rng(ss[4]), np.random.default_rng(ss[5])


def gear_truth(truth: PlantTruth, config: PlantConfig, seed: int) -> GearTruth:
    """The true gears of a plant: the catalogue curve (``models.gear.GEARS``) per actuator,
    times ``stiffness_scale``, each joint's stiffness times ``1 + spread · u`` (``u`` uniform
    in [−1, 1] from the seed), the damping from the damping ratio, ripple phases drawn; the
    hysteresis as ``config.gear.hysteresis`` says: Dahl amplitude ``F_h = T(a)`` on the joint's
    own (scaled) curve, ``σ = hysteresis_stiffness · K1``, or the play's half width ``a``."""
    g = config.gear
    n = len(truth.actuators)
    for k, spec in enumerate(truth.actuators):
        if spec.name not in GEARS:
            raise InputError(f"modules[{k}].actuator", f"no gear data for {spec.name!r}; "
                             f"known: {', '.join(sorted(GEARS))}")
    rng, _ = gear_streams(seed)
    u = rng.uniform(-1.0, 1.0, size=n)
    phase = rng.uniform(0.0, 2.0 * math.pi, size=n)
    factor = g.stiffness_scale * (1.0 + g.stiffness_spread * u)
    gears = [GEARS[s.name] for s in truth.actuators]
    k1 = np.array([x.k1 for x in gears]) * factor
    k2 = np.array([x.k2 for x in gears]) * factor
    k3 = np.array([x.k3 for x in gears]) * factor
    t1 = np.array([x.t1 for x in gears])
    t2 = np.array([x.t2 for x in gears])
    a = np.array([0.5 * x.hysteresis for x in gears])
    fh = np.array([gear_torque(float(a[i]), float(t1[i]), float(t2[i]), float(k1[i]),
                               float(k2[i]), float(k3[i])) for i in range(n)])
    dahl_on = g.hysteresis == "dahl"
    B = np.asarray(truth.rotor_inertia, dtype=float).copy()
    peak = np.asarray(truth.peak_torque, dtype=float)
    return GearTruth(
        t1=t1, t2=t2, k1=k1, k2=k2, k3=k3,
        half_play=a if g.hysteresis == "play" else np.zeros(n),
        hyst_torque=fh if dahl_on else np.zeros(n),
        hyst_sigma=g.hysteresis_stiffness * k1 if dahl_on else np.zeros(n),
        damping=2.0 * g.damping_ratio * np.sqrt(k1 * B), motor_inertia=B,
        ratio=np.array([float(s.gear_ratio) for s in truth.actuators]),
        ripple=g.ripple * peak, ripple_phase=phase, noise=g.current_noise * peak)


def compiled_kernel():
    """:mod:`models.compliant_kernel_src` if its functions are compiled (the model backend's
    :func:`cosim.model_kernel.load` compiles them with numba, next to the rigid plant's), else
    None (the Python step runs)."""
    from mrm_cosim.models import compliant_kernel_src as k

    return k if hasattr(k.pre, "py_func") else None


class CompliantPlant(Plant):
    """The robot's plant with compliant joints (module docstring); the :class:`Plant`
    interface, its encoder on the motor side.

    Parameters
    ----------
    robot, config, seed, truth
        As :class:`Plant` (``config.joints`` is not read: this class is the compliant plant).
    gears : GearTruth, optional
        Use these gears instead of :func:`gear_truth`'s (tests, what-if studies).

    Raises
    ------
    InputError
        A gear the step cannot integrate stably (``plant.gear.stiffness_scale``,
        ``plant.gear.damping_ratio`` or ``plant.gear.hysteresis_stiffness``, with the largest
        step allowed).
    """

    def __init__(self, robot, config: PlantConfig | None = None, seed: int = 0, *,
                 truth: PlantTruth | None = None, gears: GearTruth | None = None):
        config = PlantConfig() if config is None else config
        truth = true_parameters(robot, config, seed) if truth is None else truth
        self._gear = gear_truth(truth, config, seed) if gears is None else gears
        self._seed = int(seed)
        super().__init__(robot, config, seed, truth=truth)
        # the link side: the rigid bodies without the rotors (they are the motor side now)
        model = pin.Model(truth.model)
        model.armature = np.zeros(self.n)
        self._model = model
        self._data = model.createData()
        gt = self._gear
        home = np.zeros(self.n) if getattr(robot, "home", None) is None else robot.home
        M = pin.crba(model, model.createData(), np.asarray(home, dtype=float))
        M = np.triu(M) + np.triu(M, 1).T
        self.step_bound = check_step(self.dt, gt.k_max(), gt.damping, gt.motor_inertia, M,
                                     STEP_MARGIN, "plant.gear.stiffness_scale",
                                     "plant.gear.damping_ratio", gt.hyst_sigma,
                                     "plant.gear.hysteresis_stiffness")
        self._gl = [gt.t1.tolist(), gt.t2.tolist(), gt.k1.tolist(), gt.k2.tolist(),
                    gt.k3.tolist()]
        self._a = gt.half_play.tolist()
        self._fh = gt.hyst_torque.tolist()
        self._sig = gt.hyst_sigma.tolist()
        # the play model where any joint has a play (a GearTruth's choice), else Dahl
        self._play = [1.0 if x > 0.0 else 0.0 for x in self._a]
        self._dg = gt.damping.tolist()
        self._inv_b = (1.0 / gt.motor_inertia).tolist()
        self._bm = gt.motor_inertia.tolist()
        self._ripple = gt.ripple.tolist()
        self._rphase = gt.ripple_phase.tolist()
        self._r2 = (2.0 * gt.ratio).tolist()
        self._noise = gt.noise.tolist()
        self._lf = np.zeros(self.n)              # the link's generalised force (ABA's input)
        self.reset(home)

    @property
    def gears(self) -> GearTruth:
        """The true gears (diagnostics and tests only)."""
        return self._gear

    # --- state -------------------------------------------------------------------------------
    def reset(self, q0, qd0=None, tau_motor0=None, theta0=None, theta_d0=None) -> None:
        """Start again at time 0: link state as :meth:`Plant.reset`; the encoders zeroed with
        the robot at ``q0`` under its own weight (calibrated there: the gears carry the
        static torque ``g(q0) − τ_s(q0)`` at the catalogue curve's deflection, which the
        motor angle ``θ`` then counts from: :attr:`preload`); the motor at ``theta0`` (default
        ``q0``) moving at ``theta_d0`` (default ``qd0``); the hysteresis unloaded (Dahl torque 0,
        the play centred); the noise stream
        restarted (same seed, same noise)."""
        super().reset(q0, qd0, tau_motor0)
        if not hasattr(self, "_gl"):             # Plant.__init__'s reset, before the gears
            return
        q = np.array(self._q)
        static = pin.computeGeneralizedGravity(self._model, self._data, q)
        for i, amp, phase in self._springs:
            static[i] -= amp * cos(q[i] + phase)
        t1, t2, k1, k2, k3 = self._gl
        self._off = [deflection(float(static[i]), t1[i], t2[i], k1[i], k2[i], k3[i])
                     for i in range(self.n)]
        self._th = list(self._q) if theta0 is None else self._vector(theta0, "theta0").tolist()
        self._w = list(self._v) if theta_d0 is None else \
            self._vector(theta_d0, "theta_d0").tolist()
        self._y = [self._th[i] - self._q[i] + self._off[i] for i in range(self.n)]
        self._z = [0.0] * self.n
        self._am_prev = [0.0] * self.n
        self._th_start = list(self._th)
        self._w_start = list(self._w)
        self._tau_j = [0.0] * self.n
        _, self._rng = gear_streams(self._seed)
        if self._kern is not None:
            self._C[self._kern.OFF] = self._off
            self._bind_state()

    @property
    def preload(self) -> np.ndarray:
        """The gears' deflection at the last reset's pose under the robot's weight, rad: the
        motor angle ``θ`` (and the encoder) count from it (``θ − q + preload`` is the gear's
        deflection)."""
        return np.array(self._off)

    @property
    def theta(self) -> np.ndarray:
        """Motor angles referred to the output (motor angle / gear ratio), rad (a copy), from
        the encoders' zero (:attr:`preload`)."""
        return np.array(self._th)

    @property
    def theta_d(self) -> np.ndarray:
        """Motor velocities referred to the output, rad/s (a copy)."""
        return np.array(self._w)

    @property
    def gear_torques(self) -> np.ndarray:
        """The gears' torques of the last step (elastic + damping + ripple), N·m (a copy)."""
        return np.array(self._tau_j)

    # --- the compiled step ---------------------------------------------------------------------
    def use_kernel(self, kern) -> None:
        """Run :meth:`step` on compiled code from now on (the model backend asks when its
        numba kernel is loaded; ``kern`` is the rigid plant's and is not used):
        :mod:`models.compliant_kernel_src` compiled by numba, the same float operations in the
        same order, the noise draw and pinocchio's ABA called from Python between them; the
        results are the Python step's bit for bit. The state moves into one array (the list
        attributes become views of its rows)."""
        k = compiled_kernel()
        if k is None:
            return
        C = np.zeros((k.C_ROWS, self.n))
        C[k.ALPHA], C[k.BETA], C[k.PEAK] = self._alpha, self._beta, self._peak
        C[k.FC], C[k.FSX], C[k.INV_VS], C[k.VISC] = \
            self._fc, self._fs_excess, self._inv_vs, self._visc
        for i, amp, phase in self._springs:
            C[k.AMP, i], C[k.PHASE, i], C[k.HAS_SPRING, i] = amp, phase, 1.0
        C[k.T1], C[k.T2], C[k.K1], C[k.K2], C[k.K3] = self._gl
        C[k.HALF], C[k.DG], C[k.BM] = self._a, self._dg, self._bm
        C[k.FH], C[k.SIG], C[k.PLAY] = self._fh, self._sig, self._play
        C[k.RIPPLE], C[k.RPHASE], C[k.R2], C[k.SIGMA] = \
            self._ripple, self._rphase, self._r2, self._noise
        C[k.OFF] = self._off
        self._C = C
        self._kern = k
        self._bind_state()

    def _bind_state(self) -> None:
        """The state lists into the kernel's array, the list attributes as its rows."""
        k = self._kern
        S = self._S = np.zeros((k.S_ROWS, self.n))
        for row, name in ((k.Q, "_q"), (k.V, "_v"), (k.A_PREV, "_a_prev"),
                          (k.Q_START, "_q_start"), (k.V_START, "_v_start"), (k.TH, "_th"),
                          (k.W, "_w"), (k.AM_PREV, "_am_prev"), (k.TH_START, "_th_start"),
                          (k.W_START, "_w_start"), (k.Y, "_y"), (k.Z, "_z"), (k.TAU, "_tau"),
                          (k.TAU_J, "_tau_j"), (k.BRAKE, "_bh"), (k.BRAKE_SLIP, "_bs")):
            if hasattr(self, name):
                S[row] = getattr(self, name)
            setattr(self, name, S[row])
        self._qm, self._vm, self._lf = S[k.QM], S[k.VM], S[k.LF]

    def kernel_parts(self) -> tuple:
        """For a compiled caller that runs :meth:`step` itself (the model backend's fast
        path, :meth:`cosim.model.ModelBackend.fast_path`), after :meth:`use_kernel`: ``(S, C,
        model, data, qm, vm, force, noise, stepped)``: the state and constant arrays,
        pinocchio's model and data and the rows ``pin.aba`` reads, ``noise(k)`` (the next
        ``k`` steps' current-sensor draws from the plant's stream, shape (k, n): the values
        ``k`` steps draw one after the other) and :meth:`_stepped_by`. A step is
        :meth:`_step_compiled`'s sequence: ``pre(S, C, cmd, noise(1)[0], dt, dt / 2,
        friction_on)`` (:func:`models.compliant_kernel_src.pre`), ``finish`` on ``pin.aba(model,
        data, qm, vm, force)``; and ``stepped(k)`` after ``k`` such steps, the brakes idle
        (:attr:`brake_idle`: the brake timers have nothing to advance)."""
        if self._kern is None:
            raise RuntimeError("kernel_parts needs use_kernel first")
        n, rng = self.n, self._rng
        S = self._S

        def noise(steps: int):
            return rng.standard_normal((steps, n))

        return (S, self._C, self._model, self._data, self._qm, self._vm, self._lf, noise,
                self._stepped_by)

    def _step_compiled(self, arr: np.ndarray) -> None:
        """:meth:`step` on the compiled functions (:meth:`use_kernel`)."""
        k, S, h = self._kern, self._S, self.dt
        hh = 0.5 * h
        for x in arr.tolist():
            if not isfinite(x):
                raise InputError("tau_cmd", f"must be finite, not {arr.tolist()!r}")
        noise = self._rng.standard_normal(self.n)
        k.pre(S, self._C, arr, noise, h, hh, self._has_friction)
        k.finish(S, pin.aba(self._model, self._data, S[k.QM], S[k.VM], S[k.LF]), h, hh)
        self._steps += 1
        self._stepped = True
        self._brake_advance()

    # --- stepping ----------------------------------------------------------------------------
    def step(self, tau_cmd) -> None:
        """Advance one step of ``dt`` with the torque command held over it (as
        :meth:`Plant.step`)."""
        arr = self._command(tau_cmd)
        if self._kern is not None:
            self._step_compiled(arr)
            return
        cmd = arr.tolist()
        for x in cmd:
            if not isfinite(x):
                raise InputError("tau_cmd", f"must be finite, not {cmd!r}")
        noise = self._rng.standard_normal(self.n).tolist()
        h = self.dt
        hh = 0.5 * h
        n = self.n
        q, v, a_prev = self._q, self._v, self._a_prev
        th, w, am_prev, y, z = self._th, self._w, self._am_prev, self._y, self._z
        tau, tau_j = self._tau, self._tau_j
        qm, vm, lf = self._qm, self._vm, self._lf
        alpha, beta, peak = self._alpha, self._beta, self._peak
        fc, fsx, inv_vs, visc = self._fc, self._fs_excess, self._inv_vs, self._visc
        t1, t2, k1, k2, k3 = self._gl
        half, dg, bm, off = self._a, self._dg, self._bm, self._off
        fh, sig, use_play = self._fh, self._sig, self._play
        ripple, rphase, r2, sigma = self._ripple, self._rphase, self._r2, self._noise
        friction = self._has_friction
        bh, bs = self._bh, self._bs
        self._q_start = q[:]
        self._v_start = v[:]
        self._th_start = th[:]
        self._w_start = w[:]
        thm = [0.0] * n
        for i in range(n):
            # amplifier: saturate, the sensor noise, the current loop's exact response
            u = cmd[i]
            p = peak[i]
            if u > p:
                u = p
            elif u < -p:
                u = -p
            u = u + sigma[i] * noise[i]
            d = tau[i] - u
            tau[i] = u + d * alpha[i]
            vi = v[i]
            qm[i] = q[i] + hh * vi
            vm[i] = vi + hh * a_prev[i]
            thm[i] = th[i] + hh * w[i]
            # the gear at mid-step: curve + Dahl hysteresis + damping (or the play option), ripple
            delta = thm[i] - qm[i] + off[i]
            if use_play[i] != 0.0:
                yi = play(y[i], delta, half[i])
                tj = gear_torque(yi, t1[i], t2[i], k1[i], k2[i], k3[i])
                if yi != y[i] or half[i] == 0.0:
                    tj += dg[i] * (w[i] - vi)
                y[i] = yi
            else:
                zi = dahl(z[i], delta - y[i], fh[i], sig[i])
                z[i] = zi
                y[i] = delta
                tj = gear_torque(delta, t1[i], t2[i], k1[i], k2[i], k3[i]) + zi
                tj += dg[i] * (w[i] - vi)
            tj += ripple[i] * sin(r2[i] * thm[i] + rphase[i])
            tau_j[i] = tj
            lf[i] = tj
            # motor side: mean motor torque − gear − viscous, then the exact friction solve
            wi = w[i]
            rho = u + d * beta[i] - tj - visc[i] * wi
            pm = bm[i] * wi + h * rho
            if friction or bh[i] != 0.0:
                x = wi * inv_vs[i]
                lv = fc[i] + fsx[i] * exp(-x * x)
                if bh[i] != 0.0:                    # an engaged brake: held or slipping
                    lv += bh[i] if wi == 0.0 else bs[i]
                level = h * lv
                if pm > level:
                    wn = (pm - level) / bm[i]
                elif pm < -level:
                    wn = (pm + level) / bm[i]
                else:
                    wn = 0.0
            else:
                wn = pm / bm[i]
            am_prev[i] = (wn - wi) / h
            w[i] = wn
            th[i] = thm[i] + hh * wn
        for i, amp, phase in self._springs:
            lf[i] += amp * cos(qm[i] + phase)
        acc = pin.aba(self._model, self._data, qm, vm, lf).tolist()
        for i in range(n):
            vn = v[i] + h * acc[i]
            a_prev[i] = (vn - v[i]) / h
            v[i] = vn
            q[i] = qm[i] + hh * vn
        self._steps += 1
        self._stepped = True
        self._brake_advance()

    # --- encoder: on the motor ---------------------------------------------------------------
    def encoder_counts(self) -> np.ndarray:
        """Exact encoder counts of the motor, ``floor(θ · counts_per_rev / 2π)``, int64."""
        return joint_counts(np.array(self._th), self._k)

    def encoder_cycles(self) -> EncoderCycles:
        """As :meth:`Plant.encoder_cycles`, for the motor-side encoder."""
        if not self._stepped:
            raise RuntimeError("no step taken since the last reset")
        c = cycle_counts(np.array(self._th_start), np.array(self._w_start),
                         np.array(self._am_prev), np.array(self._th), self.dt,
                         self.cycles_per_step, self._k)
        a, b = quadrature_levels(c)
        return EncoderCycles(c, a, b)

    def motion(self) -> tuple[list, list, list, list]:
        """As :meth:`Plant.motion`, for the motor-side encoder (``θ``)."""
        if not self._stepped:
            raise RuntimeError("no step taken since the last reset")
        return self._th_start, self._w_start, self._am_prev, self._th
