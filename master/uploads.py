"""The master's node-configuration policy: what it uploads to the nodes before period 0.

The master configures the nodes (docs/node.md): each node's mode, tick, watchdog, torque
limits and period timer (CONFIG), its joint controller's and VDC unit's words (PARAM) and its
encoder's home count (CONFIG PRESET), then arms it. :func:`node_uploads` builds those packets
from the robot, the controller and the :class:`Gains`; :func:`startup_sends` is what the master
sends once the link is up. The loop (``cosim.closed_loop``) only carries them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mrm_cosim.errors import InputError
from mrm_cosim.master.cycle import Master, Send
from mrm_cosim.models.actuators import ACTUATORS
from mrm_cosim.models.encoder import counts_per_rad, joint_counts
from mrm_cosim.models.robot import Robot
from mrm_cosim.protocol import packet as ref
from mrm_cosim.protocol.discipline import Discipline
from mrm_cosim.protocol.fixed import FORCE
from mrm_cosim.protocol.joint_program import PID_SHIFT_MAX, JointParams, pid_formats
from mrm_cosim.protocol.regs import MODES, Config, config_payloads, joint_upload, vdc_upload
from mrm_cosim.protocol.safe_stop import SafeStopParams, safe_stop_config, stop_trail_counts
from mrm_cosim.units import CLOCK_HZ

#: The nodes' time-code latency per hop, cycles (docs/link.md: the chain forwards a time-code in
#: 12 cycles a hop), the target phase of node k's period timer loop: ``HOP_TARGET · k``.
HOP_TARGET = 12

__all__ = ["HOP_TARGET", "Gains", "pid_gains", "triple_pole_gains", "hold_gains", "node_uploads",
           "check_node_period", "startup_sends", "dmp_uploads", "dmp_retarget"]


@dataclass(frozen=True)
class Gains:
    """Controller settings uploaded to the nodes or used by the master (SI units).

    Attributes
    ----------
    lam : float, 1/s
        λ of the required joint velocity (master and node alike).
    k_j : float, N·m·s/rad
        VDC joint velocity-error gain.
    K : float
        VDC link velocity-error gain (same for the six axes, N·s/m and N·m·s/rad).
    adapt : float
        Adaptation gain ρ of every parameter (0: no adaptation), with bounds 0.7×/1.3×.
    pid_fpga_hz, pid_1khz_hz : float
        Closed-loop pole frequency of the node's PID and of the master's 1 kHz PID.
    friction_comp : float
        VDC joint friction estimates ``θ̂_J`` (viscous, Coulomb) as this fraction of each
        actuator's nominal (catalogue-level) friction; 0: none. The plant's true friction
        differs from the nominal one by its perturbation, so 1 is a model, not the truth.
    pid_fpga_base_hz, pid_1khz_base_hz : float
        The base joint's (joint 1's) own pole for the node's and the master's PID; 0 (the
        default): the same as the other joints' (``pid_fpga_hz``, ``pid_1khz_hz``). On the
        compliant plant the motor-side encoder sees joint 1's motor alone above the gear's
        anti-resonance, 32 x lighter than the motor + link inertia the pole is placed on
        (docs/experiments.md "Tuning"), so joint 1 may need a pole of its own.
    vdc_base_fb : float
        The share (0..1) of joint 1's velocity error that the master's link level feeds back
        once a period (default 1: all, the paper's VDC). The master sends the nodes
        ``q̇_r,1 = q̇_d,1 + w λ (q_d,1 − q_1)`` and propagates joint 1 at
        ``q̇_d,1 + w (q̇_1 − q̇_d,1)``, so ``K (V_r − V)`` and the differenced ``V̇_r`` carry
        ``w`` times joint 1's error; and node 1's uploaded link gains (both links' ``K``)
        are ``w K`` in a VDC run, so the Link a force node 1 forms from its own measured
        ``q̇_1`` once a period carries ``w`` of it too. At 0 the link level is a feedforward
        of joint 1's desired motion and its feedback is the node's joint law alone (1 µs
        tick), out of the 1 ms sample-and-hold. Joints 2..n are unchanged (nodes 2..n upload ``K``).
    """

    lam: float = 50.0
    k_j: float = 30.0
    K: float = 0.0
    adapt: float = 0.0
    pid_fpga_hz: float = 15.0
    pid_1khz_hz: float = 5.0
    friction_comp: float = 0.0
    pid_fpga_base_hz: float = 0.0
    pid_1khz_base_hz: float = 0.0
    vdc_base_fb: float = 1.0


def _joint_inertia(robot: Robot) -> np.ndarray:
    import pinocchio as pin

    model = robot.pinocchio_model()
    M = pin.crba(model, model.createData(), robot.home)
    return np.diag(M) + np.array([ACTUATORS[m.type.actuator].output_inertia
                                  for m in robot.modules])


def triple_pole_gains(inertia, hz: float) -> dict:
    """PID gains placing a triple pole at ``−2π·hz`` for the inertia ``inertia`` (kg·m², a
    float or an array): ``kp`` N·m/rad, ``ki`` N·m/(rad·s), ``kd`` N·m·s/rad."""
    w = 2 * math.pi * hz
    return {"kp": 3 * inertia * w * w, "ki": inertia * w**3, "kd": 3 * inertia * w}


def hold_gains(params: SafeStopParams, inertia) -> dict:
    """The safe stop's hold gains (SI, :func:`triple_pole_gains` at ``params.hold_hz``) for a
    joint of nominal inertia ``inertia`` (kg·m²): what a VDC or torque-mode node's PID words
    hold (docs/node.md "Safe stop"). While the joint stops only ``kd`` acts (the reference
    follows the count), saturating at the torque limit; at rest the triple pole holds it."""
    return triple_pole_gains(inertia, params.hold_hz)


def pid_gains(robot: Robot, hz: float, base_hz: float = 0.0) -> dict:
    """PID gains placing a triple pole at ``−2π·hz`` for each joint's nominal inertia; joint 1
    (the base joint) at ``−2π·base_hz`` instead when ``base_hz`` is positive (0: ``hz``)."""
    poles = np.full(robot.n, float(hz))
    if base_hz > 0:
        poles[0] = base_hz
    return triple_pole_gains(_joint_inertia(robot), poles)


#: The closed-loop bandwidth the nodes' PID gain words are sized for (Hz): the largest triple
#: pole an experiment may place (``gains.pid_fpga_hz``). Above it the node's PID would fight
#: the harmonic drive's compliance (a first resonance at tens of Hz on arms of this size).
PID_DESIGN_HZ = 200.0


def pid_shifts(robot: Robot, tick_cycles: int = 50) -> list[int]:
    """Each module's node's PID gain shift (:func:`~mrm_cosim.protocol.joint_program.pid_formats`),
    a build parameter of the node: the smallest shift whose KP, KI and KD words hold the gains
    :func:`pid_gains` gives for :data:`PID_DESIGN_HZ` on that joint (at most
    :data:`~mrm_cosim.protocol.joint_program.PID_SHIFT_MAX`). Every run of a robot builds its
    nodes with these, whatever its controller, and :func:`node_uploads` encodes the gains for
    them; any pole up to :data:`PID_DESIGN_HZ` then fits, with 17 or more significant bits in
    each gain word at 15 Hz."""
    g = pid_gains(robot, PID_DESIGN_HZ)
    tick = tick_cycles / CLOCK_HZ
    out = []
    for k, mod in enumerate(robot.modules):
        rad = 2 * np.pi / mod.type.counts_per_rev
        need = {"kp": g["kp"][k] * rad, "ki": g["ki"][k] * rad * tick, "kd": g["kd"][k]}
        s = 0
        while s < PID_SHIFT_MAX and any(abs(need[n]) > f.max
                                        for n, f in pid_formats(s).items()):
            s += 1
        out.append(s)
    return out


def trail_cap_counts(kp: float, peak_torque: float, counts_per_rev: int) -> int:
    """The largest STOP_TRAIL (counts, rounded down) whose position error asks the hold's P
    term (``kp``, N·m/rad) for at most half the joint's ``peak_torque``: after rest the
    frozen target is up to the trail from the joint, and a pull-back that saturates the
    torque (joint 1 of the mrm3: 0.19 mrad at its 11 N·m; 1 mrad gave no standstill in
    0.2 s on the downward cut, 2 mrad a 2.6 mrad slip after the brake) swings the joint as
    the first version's hold did (docs/node.md "Safe stop")."""
    return math.floor(0.5 * peak_torque / kp * counts_per_rev / (2 * math.pi))


def node_uploads(robot: Robot, controller: str, gains: Gains, tick_cycles: int = 50,
                 timeout_cycles: int | None = None, period_cycles: int = 50_000,
                 commit_cycles: int | None = None, sync_window: int = 2_500,
                 safe_stop: SafeStopParams | None = None,
                 discipline: tuple[int, int] | None = None) -> list[tuple[int, int, bytes]]:
    """``(dest, type, payload)`` packets that configure every node before the run.

    ``discipline``: ``(kp, ki)`` turns on every node's period timer loop on the time-code
    (CONFIG TC_DISCIPLINE, :mod:`~mrm_cosim.protocol.discipline`), node k's target phase its
    time-code latency, :data:`HOP_TARGET` cycles a hop (docs/clocks.md); None: off (the
    register's reset value, nothing sent).

    Safe stop (docs/node.md "Safe stop", :mod:`~mrm_cosim.protocol.safe_stop`): every node
    gets STOP_CYCLES, BRAKE_CYCLES and, with the standstill rule on, STANDSTILL and
    STANDSTILL_TICKS from ``safe_stop`` (None: :class:`SafeStopParams`' defaults;
    :func:`safe_stop_config` at ``tick_cycles``), STOP_TRAIL (``stop_trail`` in the joint's
    counts, :func:`stop_trail_counts`, at most :func:`trail_cap_counts` of its hold's
    ``kp``; not sent when 0, its reset value), and, unless
    ``controller`` is ``pid-fpga`` (whose nodes hold with their tracking PID), PID words
    holding the hold gains
    (:func:`hold_gains` at ``safe_stop.hold_hz`` for each joint's nominal inertia): VDC and
    torque-mode nodes read them only while they hold.

    Homing: the arm rests at ``robot.home`` until period 0 (the brakes hold it), and a node's
    incremental encoder counts from 0 at its reset, so each node's count is preset (CONFIG
    PRESET) to the count of its joint's home angle, ``floor(home · CPR / 2π)``, what the
    plant's encoder shows there. Without it a robot whose home is not all zeros ran with
    every joint's angle off by its home angle, in the master and in the node alike.

    ``period_cycles`` (the master's period), ``commit_cycles`` (the phase at which Comm D takes
    effect) and ``sync_window`` set the nodes' period timer (docs/node.md "Timing"); the
    timing record goes first, so it arrives within the first period after reset. The default
    commit phase is a fifth of the period (200 µs of 1 ms: the measured Comm D reaches the last
    of three nodes at ~82 µs; docs/node.md "Timing" says why the margin). The VDC's
    backward difference (1/T) and adaptation step (ρ·T) are for this period. The default
    watchdog timeout is two periods, at least 2 ms (docs/node.md "Watchdog"): the nodes hear
    from the master once a period, so a timeout that did not follow a longer period would trip
    every node, and before period 0 they hear nothing for up to 1 ms after their ARM.
    """
    if commit_cycles is None:
        commit_cycles = period_cycles // 5
    if timeout_cycles is None:
        # two periods, and never less than the silence between the uploads' ARM and period 0
        # (up to START_CYCLE, 1 ms): two 0.4 ms periods tripped every node before period 0
        timeout_cycles = max(2 * period_cycles, 2 * 50_000)
    mode = {"vdc": MODES["vdc"], "pid-fpga": MODES["pid"], "pid-1khz": MODES["torque"]}
    check_node_period(period_cycles, tick_cycles, commit_cycles, sync_window)
    if safe_stop is None:
        safe_stop = SafeStopParams()
    elif not isinstance(safe_stop, SafeStopParams):
        raise InputError("safe_stop", f"must be a SafeStopParams, not {safe_stop!r}")
    if safe_stop.hold_hz > PID_DESIGN_HZ:
        raise InputError("safe_stop.hold_hz", f"{safe_stop.hold_hz!r} Hz is above the "
                         f"{PID_DESIGN_HZ:g} Hz the nodes' PID words are sized for")
    stop_cfg = safe_stop_config(safe_stop, tick_cycles=tick_cycles)
    out = [(k + 1, ref.PacketType.CONFIG, p) for k in range(robot.n) for p in config_payloads(
        {Config.PERIOD: period_cycles, Config.COMMIT: commit_cycles,
         Config.SYNC_WINDOW: sync_window})]
    if discipline is not None:
        kp, ki = discipline
        out += [(k, ref.PacketType.CONFIG, p) for k in range(1, robot.n + 1)
                for p in config_payloads({Config.TC_DISCIPLINE: Discipline(
                    target=HOP_TARGET * k, kp=kp, ki=ki).word})]
    # The PID words: the node's PID where it runs it, else the safe stop's hold gains (a
    # tracking gain a run never uses must not stop it: gains.pid_fpga_hz is bounded for the
    # pid-fpga runs alone).
    pid = (pid_gains(robot, gains.pid_fpga_hz, gains.pid_fpga_base_hz) if controller == "pid-fpga"
           else hold_gains(safe_stop, _joint_inertia(robot)))
    home_counts = joint_counts(robot.home, counts_per_rad(robot.counts_per_rev))
    shifts = pid_shifts(robot, tick_cycles)
    # VDC's base-joint share w (Gains.vdc_base_fb): node 1 forms its Link a force from its
    # own measured joint-1 velocity, so its link gains are w K (w = 1: the paper's upload)
    link_share = np.ones(robot.n)
    if controller == "vdc":
        link_share[0] = gains.vdc_base_fb
    for k, mod in enumerate(robot.modules):
        dest = k + 1
        peak = FORCE.encode(mod.type.peak_torque)
        cfg = {Config.MODE: mode[controller], Config.TICK: tick_cycles,
               Config.TIMEOUT: timeout_cycles, Config.RAMP: FORCE.encode(0.01),
               Config.TAU_MIN: -peak, Config.TAU_MAX: peak, **stop_cfg}
        trail = min(stop_trail_counts(safe_stop, mod.type.counts_per_rev),
                    trail_cap_counts(pid["kp"][k], mod.type.peak_torque,
                                     mod.type.counts_per_rev))
        if trail:
            cfg[Config.STOP_TRAIL] = trail
        out += [(dest, ref.PacketType.CONFIG, p) for p in config_payloads(cfg)]
        theta = robot.nominal_theta[k]
        lo = np.minimum(0.7 * theta, 1.3 * theta)
        hi = np.maximum(0.7 * theta, 1.3 * theta)
        out += [(dest, ref.PacketType.PARAM, p) for p in
                vdc_upload(theta, np.full((2, 6), gains.K * link_share[k]),
                           np.full((2, 13), gains.adapt),
                           lo, hi, period=period_cycles / CLOCK_HZ)]
        spec = ACTUATORS[mod.type.actuator]
        joint = JointParams.from_float(
            counts_per_rev=mod.type.counts_per_rev, tick_cycles=tick_cycles, lam=gains.lam,
            k_j=gains.k_j, inertia=spec.output_inertia,
            viscous=gains.friction_comp * spec.viscous_friction,
            coulomb=gains.friction_comp * spec.coulomb_friction,
            k_p=pid["kp"][k], k_i=pid["ki"][k], k_d=pid["kd"][k], i_max=0.05,
            pid_shift=shifts[k], field=f"joint{dest}")
        out += [(dest, ref.PacketType.PARAM, p) for p in joint_upload(joint)]
        out += [(dest, ref.PacketType.CONFIG, p)
                for p in config_payloads({Config.PRESET: int(home_counts[k])})]
        out += [(dest, ref.PacketType.CONFIG, p) for p in config_payloads({Config.ARM: 1})]
    return out


def check_node_period(period_cycles: int, tick_cycles: int = 50,
                      commit_cycles: int | None = None, sync_window: int = 2_500) -> None:
    """The nodes' period timer's rules (docs/node.md "Timing"), the one place they are
    checked: ``period_cycles`` a multiple of the control tick below 2^24 (the PERIOD
    register), the commit phase and the sync window inside the period. ``InputError`` naming
    the argument that breaks them (``commit_cycles`` None: the default, a fifth of the
    period)."""
    if (isinstance(period_cycles, bool) or not isinstance(period_cycles, int)
            or period_cycles % tick_cycles or not 0 < period_cycles < (1 << 24)):
        raise InputError("period_cycles", f"must be a multiple of the tick ({tick_cycles}) "
                         f"below 2^24, not {period_cycles!r}")
    if commit_cycles is not None and not 0 <= commit_cycles < period_cycles:
        raise InputError("commit_cycles", f"must lie in [0, {period_cycles}), "
                         f"not {commit_cycles!r}")
    if not 0 <= sync_window < period_cycles:
        raise InputError("sync_window", f"must lie in [0, {period_cycles}), not {sync_window!r}")


def startup_sends(uploads, master: Master, q0, seq: int) -> tuple[list[Send], int]:
    """What the master sends once the link is up, before period 0: every upload ``(dest, type,
    payload)`` with sequence numbers counting on from ``seq``, then its initial Comm D (at the
    plant's posture ``q0``). Returns the sends and the last sequence number used."""
    sends = []
    for dest, ptype, payload in uploads:
        seq = (seq + 1) & 0xFF
        sends.append(Send("packet", dest, int(ptype), payload, seq))
    return sends + list(master.initial_packets(q0)), seq


def dmp_uploads(robot: Robot, dmp, step_cycles: int = 50_000,
                period_cycles: int = 50_000) -> list[tuple[int, int, bytes]]:
    """``(dest, type, payload)`` packets that deploy one primitive per joint (docs/dmp.md):
    each node's generator words (PARAM, bank DMP) and its step (CONFIG DMP_STEP). The master
    starts them (:class:`master.cycle.Master` with ``references="dmp"``); the node's upload
    check (Comm A's CRC and count) reads the deployment back.

    Everything is checked before anything is sent, each failure an :class:`InputError`
    naming the field: one primitive per joint, a step the generator's recurrence is stable
    at (``dmp.tau``), that divides the period (``dmp.step_cycles``), start and goal inside the
    joint's limits (``dmp.x0[k]``, ``dmp.g[k]``), every word fitting its format
    (``dmp.joint<k>.<word>``, :meth:`protocol.dmp.DmpParams.from_float`).
    """
    from mrm_cosim.protocol.dmp import DmpParams, dmp_param_payloads

    if dmp.n_dof != robot.n:
        raise InputError("dmp", f"has {dmp.n_dof} degrees of freedom; {robot.name} has "
                                f"{robot.n} joints")
    if (isinstance(step_cycles, bool) or not isinstance(step_cycles, int)
            or not 2 <= step_cycles < (1 << 24)):
        raise InputError("dmp.step_cycles", f"must be an integer 2..2^24-1, not "
                                            f"{step_cycles!r}")
    if period_cycles % step_cycles:
        raise InputError("dmp.step_cycles", f"{step_cycles} does not divide the period "
                                            f"({period_cycles} cycles): the generator steps "
                                            "on the period grid")
    try:
        dmp.check_step(step_cycles / CLOCK_HZ)
    except InputError as exc:
        raise InputError("dmp.tau", f"{dmp.tau!r} s: {exc.message}") from None
    lim = robot.joint_limits
    for name, values in (("x0", dmp.x0), ("g", dmp.g)):
        for k, v in enumerate(values):
            if not abs(v) <= lim[k]:
                raise InputError(f"dmp.{name}[{k}]", f"{v!r} rad is outside joint {k + 1}'s "
                                 f"limits (±{lim[k]:.4g} rad)")
    out = []
    for k, mod in enumerate(robot.modules):
        params = DmpParams.from_float(
            dmp.weights[k], dmp.centers, dmp.widths, dmp.alpha, dmp.beta, dmp.alpha_s,
            dmp.tau, float(dmp.x0[k]), float(dmp.g[k]), float(dmp.xd0[k]),
            bool(dmp.goal_scaling[k]), counts_per_rev=mod.type.counts_per_rev,
            step_cycles=step_cycles, field=f"dmp.joint{k + 1}")
        out += [(k + 1, ref.PacketType.PARAM, p) for p in dmp_param_payloads(params)]
        out += [(k + 1, ref.PacketType.CONFIG, p)
                for p in config_payloads({Config.DMP_STEP: step_cycles})]
    return out


def dmp_retarget(robot: Robot, dmp, goals=None, tau: float | None = None,
                 step_cycles: int = 50_000) -> list[tuple[int, int, bytes]]:
    """``(dest, type, payload)`` packets that change running primitives: a new goal per joint
    (rad, shape (n,)) and/or a new time constant τ (s) for every joint, one PARAM word each
    (bank DMP: GOAL, INVTAU), taken by each generator at the start of its next step
    (docs/dmp.md). ``dmp`` is the deployed primitive (for the stability of the new τ).

    Checked like the deploy, each refusal naming its field: a goal outside the joint's limits
    or its word (``goals[k]``), a τ of zero or below, too long for the INVTAU word, or too
    short for the step (``tau``).
    """
    import math

    from mrm_cosim.errors import require_positive
    from mrm_cosim.protocol.dmp import INVTAU, Reg
    from mrm_cosim.protocol.fixed import POS
    from mrm_cosim.protocol.regs import Bank, param_payloads

    words: dict[int, dict[int, int]] = {k: {} for k in range(robot.n)}
    if goals is not None:
        g = np.asarray(goals, dtype=float)
        if g.shape != (robot.n,):
            raise InputError("goals", f"must have one goal per joint ({robot.n}), not "
                                      f"shape {g.shape}")
        lim = robot.joint_limits
        for k, mod in enumerate(robot.modules):
            if not (np.isfinite(g[k]) and abs(g[k]) <= lim[k]):
                raise InputError(f"goals[{k}]", f"{g[k]!r} rad is outside joint {k + 1}'s "
                                 f"limits (±{lim[k]:.4g} rad)")
            kc = mod.type.counts_per_rev / (2 * math.pi)
            words[k][int(Reg.GOAL)] = POS.encode_checked(g[k] * kc, f"goals[{k}]")
    if tau is not None:
        tau = require_positive(tau, "tau")
        try:
            dmp.with_tau(tau).check_step(step_cycles / CLOCK_HZ)
        except InputError as exc:
            raise InputError("tau", exc.message) from None
        w = INVTAU.encode_checked(1.0 / tau, "tau")
        if w <= 0:
            raise InputError("tau", f"{tau!r} s is too long for the INVTAU word "
                                    f"(1/τ ≥ {INVTAU.resolution:g} /s)")
        for k in range(robot.n):
            words[k][int(Reg.INVTAU)] = w
    return [(k + 1, ref.PacketType.PARAM, p) for k in range(robot.n) if words[k]
            for p in param_payloads(Bank.DMP, words[k])]
