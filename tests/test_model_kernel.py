"""The ``model`` backend's compiled inner loop (cosim.model_kernel) against the references it
was translated from: the joint engine's tick (:class:`~hdl.node.joint_ref.JointModel`) over
random words, the encoder interface (:class:`~cosim.model_node.EncoderEvents`) over random
walks, and whole closed loops — the same trace hashes, reply payloads and node state on the
compiled and the pure-Python path, three controllers, ``mrm3`` and ``mrm6``."""

import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mrm_cosim.cosim import model_kernel as mk
from mrm_cosim.cosim import model_kernel_src as src
from mrm_cosim.cosim.model_node import EncoderEvents
from mrm_cosim.hdl.node.encoder_ref import EncoderParams
from mrm_cosim.hdl.node.joint_ref import JointModel
from mrm_cosim.protocol.fixed import WORD_MAX, WORD_MIN
from mrm_cosim.protocol.joint_program import PID_SHIFT_MAX, JointParams

from .test_model_backend import _walk

kern = mk.load()
needs_numba = pytest.mark.skipif(kern is None, reason="numba cannot run here")

words = st.one_of(st.integers(WORD_MIN, WORD_MAX), st.sampled_from([WORD_MIN, WORD_MAX, 0, -1]))


@pytest.mark.parametrize("pid_shift", range(PID_SHIFT_MAX + 1))
def test_no_rounding_point_leaves_int64(pid_shift):
    """The largest sum each rounding point can form, with every word at its extreme, stays
    below 2^63: summands are products of two 24-bit words (≤ 2^46) or of a word and a
    difference of two (≤ 2^47), or a sum of two words (≤ 2^24), shifted left by the point's
    alignment."""
    pts = mk._points(pid_shift)
    w, p, pd = 2**23, 2**46, 2**47         # a word, word × word, word × (word − word)
    bound = {"E": [w, w], "QDR": [w, p], "QDDR": [w, pd], "SG": [p, p],
             "TAU_VDC": [2 * w, p, p, p, pd], "TAU_PID": [w, p, p, p, pd],
             "I_CARRY": [w, w, w], "I_LO": [w, w, w, w], "I_HI": [w, w], "TAU_D": [w],
             "TS": [p], "VD": [w, p], "DQ": [p], "QD": [w, p]}
    assert set(bound) == set(src.POINTS)
    for i, name in enumerate(src.POINTS):
        shifts, r = pts[6 * i:6 * i + 5], pts[6 * i + 5]
        assert not any(shifts[len(bound[name]):])
        total = sum(m << s for m, s in zip(bound[name], shifts, strict=False)) + (1 << r)
        assert total < 2**63, (name, pid_shift, total.bit_length())


@needs_numba
@settings(max_examples=400, deadline=None)
@given(params=st.lists(words, min_size=17, max_size=17),
       state=st.lists(words, min_size=4, max_size=4),
       mode=st.integers(0, 2), pid_shift=st.integers(0, PID_SHIFT_MAX),
       q=st.integers(-(1 << 31), (1 << 31) - 1), qd=words, tau_d=words,
       d=st.lists(words, min_size=3, max_size=3), tn=st.integers(0, (1 << 23) - 1))
def test_compiled_tick_equals_the_joint_reference(params, state, mode, pid_shift, q, qd, tau_d,
                                                  d, tn):
    """Part A (torque, PID integral), the integral alone and Part B of the compiled kernel
    equal :class:`JointModel`'s bit for bit, over any words."""
    p = JointParams(*params, pid_shift=pid_shift)
    ref = JointModel(p, *state)
    N = np.zeros(src.N_SIZE, dtype=np.int64)
    N[src.N_QDES:src.N_IHI + 1] = state
    P = mk.param_row(p)
    qd0, vd0, ad0 = d
    tau = ref.part_a(mode, q, qd, tau_d, ad0)[0]
    assert kern.part_a(N, P, mode, q, qd, tau_d, ad0) == tau
    ref.pid_integral(q - 7)
    kern.pid_integral(N, P, q - 7)
    ref.part_b(tn, qd0, vd0, ad0)
    kern.part_b(N, P, tn, qd0, vd0, ad0)
    assert N[src.N_QDES:src.N_IHI + 1].tolist() == [ref.q_des, ref.v_des, ref.i_lo, ref.i_hi]


@needs_numba
@pytest.mark.parametrize("seed, params", [
    (0, EncoderParams()),
    (1, EncoderParams(min_window=256, stop_cycles=5_000)),
    (2, EncoderParams(filter_cycles=1, min_window=64, stop_cycles=3_000)),
])
def test_compiled_encoder_equals_encoder_events(seed, params):
    """Same count changes, same strobes, deferred strobes and presets: the compiled encoder
    answers what :class:`EncoderEvents` answers, cycle for cycle."""
    rng = np.random.default_rng(seed)
    n = 40_000
    counts = _walk(rng, n)
    ref = EncoderEvents(params, int(counts[0]))
    fast = mk.KernelEncoder(kern, mk.KernelArrays(1), 0, params, int(counts[0]))
    pos = 0
    seen = set()
    for t in range(0, n, 50):
        if t >= pos:
            size = int(rng.integers(50, 700))
            ref.feed(pos, counts[pos:pos + size])
            fast.feed(pos, counts[pos:pos + size])
            pos = min(n, pos + size)
        kind = rng.integers(0, 10)
        if kind < 5:
            got = (ref.defer(t), fast.defer(t))
        elif kind < 8:
            got = (ref.sample(t), fast.sample(t))
            seen.add(got[0][1])
        elif kind < 9:
            got = (ref.count_at(t), fast.count_at(t))
        else:
            value = int(rng.integers(-1000, 1000))
            ref.preset(t, value)
            fast.preset(t, value)
            got = ((ref.count, ref.velocity, ref.errors), (fast.count, fast.velocity,
                                                           fast.errors))
        assert got[0] == got[1], f"cycle {t}"
    assert len(seen) > 20                       # velocities measured, bounded, stopped


def _wiggle(robot):
    """A 25 Hz swing from rest, a few mrad on every joint: thousands of counts."""
    amp = 2e-3 + 1e-3 * np.arange(robot.n) / max(1, robot.n - 1)
    w = 2 * np.pi * 25.0
    home = np.asarray(robot.home, dtype=float)

    def trajectory(t):
        return (home + amp * (1 - np.cos(w * t)), amp * w * np.sin(w * t),
                amp * w * w * np.cos(w * t))

    return trajectory


def _run(robot_name, controller, kernel, cycles, joints="rigid"):
    from mrm_cosim.cosim.closed_loop import ClosedLoop
    from mrm_cosim.cosim.model import ModelBackend
    from mrm_cosim.master.cycle import Master, MasterTiming
    from mrm_cosim.master.uploads import Gains, node_uploads, pid_gains, pid_shifts
    from mrm_cosim.models.plant import PlantConfig, make_plant
    from mrm_cosim.models.robot import load_robot

    robot = load_robot(robot_name)
    gains = Gains()
    master = Master(robot, controller, _wiggle(robot), robot.counts_per_rev, MasterTiming(),
                    lam=gains.lam, pid=pid_gains(robot, gains.pid_1khz_hz))
    payloads = []
    on_packet = master.on_packet

    def record(now, src_, ptype, payload):
        payloads.append((now, src_, ptype, bytes(payload)))
        on_packet(now, src_, ptype, payload)

    master.on_packet = record
    plant = make_plant(robot, PlantConfig(joints=joints), seed=1)
    plant.reset(robot.home)
    backend = ModelBackend(kernel=kernel, pid_shift=pid_shifts(robot))
    loop = ClosedLoop(robot, backend, master, plant, 50_000,
                      node_uploads(robot, controller, gains))
    result = loop.run(cycles)
    state = [(n._nt, n.torque, n.overruns, n._landing, n._deferred, n.joint.q_des,
              n.joint.v_des, n.joint.i_lo, n.joint.i_hi, n.tripped, n.prime, n.d_words,
              n.d_base, n.cd_words, n.cd_base, n.d_pending, n._commit_seen)
             for n in backend.nodes]
    enc = [(e.count, e.velocity, e.errors) for e in backend.encoders]
    # what the master saw of every period: the cycle of every event, reply and node strobe
    # (a strobe the fast path lost or moved shows here, not in the trace)
    seen = [(r.index, r.start, r.events, r.arrivals, r.node_events, r.complete)
            for r in master.records]
    return result, payloads, state, enc, backend, plant, seen


@needs_numba
@settings(max_examples=400, deadline=None)
@given(q0=st.floats(-3.0, 3.0), v0=st.one_of(st.floats(-6.0, 6.0), st.just(0.0)),
       v1=st.one_of(st.floats(-6.0, 6.0), st.just(0.0)),
       tiny=st.one_of(st.just(1.0), st.just(100.0), st.floats(1e-7, 1e-3)),
       cpr=st.sampled_from([800_000, 1_600_000, 4096]))
def test_compiled_count_changes_equal_the_reference(q0, v0, v1, tiny, cpr):
    """:func:`step_changes` gives the count changes of
    :func:`models.encoder.count_changes_lists` bit for bit: few changes (bisection), many
    (every cycle), turning points inside the step, at rest; and flags an overspeed where the
    reference raises."""
    from mrm_cosim.models.encoder import EncoderOverspeed, count_changes_lists, counts_per_rad

    dt, cycles = 1e-5, 500
    v0, v1 = v0 * tiny, v1 * tiny       # slow joints: one change or none; fast: overspeed
    acc = (v1 - v0) / dt
    q1 = q0 + 0.5 * dt * (v0 + v1)
    cols = [(q0, v0, acc, q1), (q1, v1, -acc, q0), (q0, 0.0, 0.0, q0)]
    M = np.array(cols, dtype=float).T.copy()
    k = counts_per_rad(np.full(3, cpr))
    chc = np.zeros((3, 1024), dtype=np.int64)
    chn = np.zeros((3, 1024), dtype=np.int64)
    nch = np.zeros(3, dtype=np.int64)
    flag = kern.step_changes(M, k, dt, cycles, chc, chn, nch)
    try:
        _, ref = count_changes_lists(*M.tolist(), dt, cycles, k.tolist())
    except EncoderOverspeed:
        assert flag
        return
    assert flag == 0
    for j in range(3):
        got = list(zip(chc[j, :nch[j]].tolist(), chn[j, :nch[j]].tolist(), strict=True))
        assert got == ref[j], (j, cols[j])


_FOLD = [0, 1, -1, (1 << 22) - 1, 1 << 22, (1 << 22) + 1, (1 << 23) - 1, 1 << 23,
         (1 << 23) + 1, 3 << 22, (3 << 22) - 1, (3 << 22) + 1, (1 << 24) - 1]


@needs_numba
@settings(max_examples=400, deadline=None)
@given(bam=st.one_of(st.integers(0, (1 << 24) - 1), st.sampled_from(_FOLD),
                     st.integers(-(1 << 40), 1 << 40)),
       count=st.one_of(st.integers(-(1 << 23), (1 << 23) - 1),
                       st.sampled_from([-(1 << 23), (1 << 23) - 1, 0, -1, 1 << 23, -(1 << 40)]),
                       st.integers(-(1 << 40), 1 << 40)),
       cpr=st.one_of(st.sampled_from([800_000, 1_600_000, 4096, 1 << 24, 2 ** 8 + 1]),
                     st.integers(2 ** 8 + 1, 1 << 26)))
def test_compiled_sin_cos_equals_the_reference(bam, count, cpr):
    """The boundary's CORDIC (:func:`sin_cos`, :func:`cordic`) against
    :mod:`hdl.node.trig_ref` bit for bit: every binary angle, the half-turn fold's edges,
    counts beyond 24 bits (wrapped) and every counts per revolution whose ``kb`` it takes
    (below :data:`SIN_COS_KB_MAX`: the widest product, a 24-bit count times ``kb``, then
    stays below 2^62)."""
    from mrm_cosim.hdl.node import trig_ref
    from mrm_cosim.protocol.cordic import bam_constant

    assert tuple(kern.cordic(bam)) == trig_ref.cordic(bam)
    kb = bam_constant(cpr)
    assert kb < src.SIN_COS_KB_MAX and (1 << 23) * kb + (1 << 21) < 1 << 62
    assert tuple(kern.sin_cos(count, kb)) == trig_ref.sin_cos(count, cpr)


@needs_numba
@pytest.mark.parametrize("robot", ["mrm3", "mrm6"])
def test_stick_slip_cache_gives_the_same_trace(robot):
    """``mrm bench``'s window, where joints rest stuck between moves: the fast path takes the
    bias and matrix of pinocchio's last ``nonLinearEffects`` and ``crba`` from its cache on
    steps with the same ``(q, v)`` bit for bit (``model_kernel_src.stick_cached``), and the
    trace and the master's replies are the pure-Python path's."""
    from mrm_cosim.cosim.bench import bench_master_and_plant
    from mrm_cosim.cosim.closed_loop import ClosedLoop
    from mrm_cosim.cosim.model import ModelBackend
    from mrm_cosim.master.uploads import Gains, node_uploads, pid_shifts
    from mrm_cosim.models.robot import load_robot

    out = {}
    for kernel in ("numba", "python"):
        robot_ = load_robot(robot)
        master, plant = bench_master_and_plant(robot_)
        backend = ModelBackend(kernel=kernel, pid_shift=pid_shifts(robot_))
        loop = ClosedLoop(robot_, backend, master, plant, 50_000,
                          node_uploads(robot_, "vdc", Gains()))
        result = loop.run(600_000)
        out[kernel] = (result.trace_sha256, result.violations,
                       [(r.index, r.events, r.arrivals, r.node_events) for r in master.records])
        if kernel == "numba":
            assert backend.stick_cached > 50, backend.stick_cached
    assert out["numba"] == out["python"]


@needs_numba
@pytest.mark.parametrize("robot", ["mrm3", "mrm6"])
@pytest.mark.parametrize("controller", ["vdc", "pid-fpga", "pid-1khz"])
def test_compiled_and_python_paths_give_the_same_trace(robot, controller):
    """8 ms of closed loop with every joint swinging: the compiled inner loop and the
    pure-Python references give the same trace hash, reply payloads, node and encoder
    state."""
    cycles = 400_000
    fast = _run(robot, controller, "numba", cycles)
    slow = _run(robot, controller, "python", cycles)
    assert type(fast[4].nodes[0]).__name__ == "KernelNode"
    assert type(slow[4].nodes[0]).__name__ == "FastNode"
    assert fast[0].violations == slow[0].violations == []
    assert fast[0].trace_sha256 == slow[0].trace_sha256
    # most plant steps took the fast path (GatewareSide.fast_path), the free step and the
    # stick-slip solve both
    steps = fast[4].fast_steps
    assert sum(steps.values()) > 0.8 * cycles / 500 and steps["free"] > 0, steps
    assert steps["stick-slip"] + steps["solve"] > 0, steps
    # and some of its runs ended with a step whose replies or strobes it handed to the master,
    # some with a step whose nodes had events (its plant in the kernel, ModelBackend._fast)
    assert fast[4].fast_handovers > 0
    assert fast[4].event_steps > 0
    # the nodes' boundaries, time-codes and packets ran with their tick state in the kernel's
    # row (KernelNode._boundary_in_row, timecode, packet), the commits inside fast steps
    # (KernelNode.arm_commit), and the row's references are the object's
    for event in ("boundary", "timecode", "packet"):
        assert sum(node.in_row[event] for node in fast[4].nodes) > 0, event
    assert sum(node.fast_commits for node in fast[4].nodes) > 0
    for node in fast[4].nodes:
        assert node._row[src.N_D0:src.N_D0 + 4].tolist() == node.d_words
        assert node._row[src.N_DBASE] == node.d_base
        assert node._row[src.N_COMMIT_C] == src.NEVER
    assert slow[4].fast_steps == {"free": 0, "stick-slip": 0, "solve": 0}
    assert fast[1] == slow[1] and len(fast[1]) > 0
    assert fast[2] == slow[2]
    assert fast[3] == slow[3]
    assert fast[6] == slow[6] and len(fast[6]) >= 7
    assert np.ptp(fast[0].q, axis=0).min() > 2e-5                 # every joint moved (counts)
    # the torques changed (torque-only nodes hold the master's torque for a period)
    assert max(len(np.unique(col)) for col in fast[0].tau.T) > \
        (5 if controller == "pid-1khz" else 15)


@needs_numba
@pytest.mark.parametrize("robot", ["mrm3", "mrm6"])
@pytest.mark.parametrize("controller", ["vdc", "pid-fpga", "pid-1khz"])
def test_compiled_and_python_paths_give_the_same_trace_on_the_compliant_plant(robot,
                                                                               controller):
    """The same on the compliant plant (two-inertia joints, gear curve with Dahl hysteresis,
    current-sensor noise, ripple; the encoder on the motor): its plain steps run
    :func:`fast_step_compliant` with the noise drawn between the kernel calls, and the trace,
    replies, node and encoder state are the pure-Python path's."""
    cycles = 400_000
    fast = _run(robot, controller, "numba", cycles, joints="compliant")
    slow = _run(robot, controller, "python", cycles, joints="compliant")
    assert type(fast[4].nodes[0]).__name__ == "KernelNode"
    assert fast[0].violations == slow[0].violations == []
    assert fast[0].trace_sha256 == slow[0].trace_sha256
    assert sum(node.fast_commits for node in fast[4].nodes) > 0
    steps = fast[4].fast_steps      # (a compliant step has no stick-slip solve through ABA)
    assert steps["free"] > 0.8 * cycles / 500 and steps["stick-slip"] == steps["solve"] == 0
    assert fast[4].fast_handovers > 0 and fast[4].event_steps > 0
    assert fast[1] == slow[1] and len(fast[1]) > 0
    assert fast[2] == slow[2]
    assert fast[3] == slow[3]
    assert fast[6] == slow[6] and len(fast[6]) >= 7
    # every link moved by counts of its motor-side encoder (≈ 1.3e5 counts/rad; mrm6's heavy
    # links follow their gears' 25 Hz swing by 1e-5 rad in 8 ms)
    assert np.ptp(fast[0].q, axis=0).min() > 5e-6
    # and the plant's own state (motor side, hysteresis, the noise stream) ended the same
    fp, sp = fast[5], slow[5]
    for name in ("theta", "theta_d", "gear_torques", "q", "qd"):
        np.testing.assert_array_equal(getattr(fp, name), getattr(sp, name), err_msg=name)
    assert fp._rng.bit_generator.state == sp._rng.bit_generator.state


def test_without_numba_the_python_path_runs_with_one_warning(monkeypatch):
    """numba missing (or failing): one warning line, then the pure-Python path."""
    from mrm_cosim.cosim.model import ModelBackend

    monkeypatch.setitem(sys.modules, "numba", None)          # import numba raises
    monkeypatch.setattr(mk, "_loaded", None)
    with pytest.warns(RuntimeWarning, match="pure-Python path") as record:
        backend = ModelBackend(kernel="numba")
        backend.power_on([0, 0, 0])
        ModelBackend(kernel="numba").power_on([0, 0])          # warned once only
    assert len(record) == 1 and "\n" not in str(record[0].message)
    assert type(backend.nodes[0]).__name__ == "FastNode"


def test_the_kernel_is_chosen_by_name_or_environment(monkeypatch):
    monkeypatch.setenv("MRM_MODEL_KERNEL", "python")
    assert mk.kernel_choice() == "python"
    assert mk.kernel_choice("numba") == "numba"
    monkeypatch.delenv("MRM_MODEL_KERNEL")
    assert mk.kernel_choice() == "numba"
    with pytest.raises(ValueError, match="'numba' or 'python', not 'c'"):
        mk.kernel_choice("c")


@needs_numba
def test_the_kernel_cache_is_keyed_on_every_source_it_reads(tmp_path):
    """numba freezes the globals a compiled function reads into its machine code and keys
    its own cache on the defining file only. The kernel's cache directory is named by a
    digest of every file it depends on: a change to a format, a table or a callee elsewhere
    (here models/gear.py's friction, called from the compliant plant) names a new one."""
    from pathlib import Path

    import importlib

    root = Path(mk.__file__).resolve().parents[1]
    files = mk.kernel_sources()
    # what the kernel's modules import, and units (protocol.encoder's CLOCK_HZ): transitive
    for name in ("cosim.model_kernel_src", "cosim.model_kernel", "protocol.fixed",
                 "protocol.cordic", "protocol.encoder", "hdl.node.encoder_ref",
                 "models.plant_kernel_src", "models.compliant_kernel_src", "models.gear",
                 "models.encoder", "units"):
        module = importlib.import_module(f"mrm_cosim.{name}")
        assert Path(module.__file__).resolve() in files, name
    assert not [f for f in files if not f.is_relative_to(root)]
    # the gateware is no dependency of the kernel (the references never import it)
    assert not [f for f in files if f.parent.name in ("node", "link") and
                not f.name.endswith("_ref.py")]
    copies = []
    for f in files:
        c = tmp_path / f.relative_to(root)
        c.parent.mkdir(parents=True, exist_ok=True)
        c.write_bytes(f.read_bytes())
        copies.append(c)
    before = mk.kernel_digest(copies)
    assert mk.kernel_digest(copies) == before
    gear = tmp_path / "models/gear.py"
    gear.write_text(gear.read_text() + "\n# a change\n")
    assert mk.kernel_digest(copies) != before


@needs_numba
def test_the_kernel_is_cached_under_its_digest():
    from pathlib import Path

    from mrm_cosim.cosim.compiled import cache_dir

    where = Path(src.plain_step._cache._cache_path)
    assert where.parent == cache_dir() / "numba" / mk.kernel_digest()


def test_no_vdc_sum_leaves_int64():
    """The compiled VDC link's widest sums, every word at its extreme (2^23): a regressor
    entry has at most three summands, a row or column at most 13 entries; the force row's
    rounding point (the widest) and the adaptation's stay below 2^63."""
    w = 2**23
    per_entry = np.bincount(src.VDC_TERMS[:, 0] * 13 + src.VDC_TERMS[:, 1]).max()
    assert per_entry <= 3
    y = per_entry * w                                   # |an entry of Y|
    row = 13 * y * w                                    # Σ_col Y θ (a group's sum, at most)
    pf = src.VDC_PT_F
    force = sum(row << int(s) for s in pf[:3]) + ((w * w) << int(pf[3])) + (1 << int(pf[4]))
    assert force < 2**62, force.bit_length()
    col = 6 * y * w                                     # Σ_row Y e
    assert (col << int(src.VDC_PT_SIG[0])) < 2**62
    assert ((w * w) << int(src.VDC_PT_DELTA[:, 0].max())) < 2**62
    cross = ((2 * w) << int(src.VDC_PT_A[0])) + ((2 * w * w) << int(src.VDC_PT_A[1]))
    assert cross < 2**62


@needs_numba
@settings(max_examples=300, deadline=None)
@given(link=st.integers(0, 1), th=st.lists(words, min_size=13, max_size=13),
       K=st.lists(words, min_size=6, max_size=6), rho=st.lists(words, min_size=13, max_size=13),
       bounds=st.lists(st.tuples(words, words), min_size=13, max_size=13),
       V=st.lists(words, min_size=6, max_size=6), Vr=st.lists(words, min_size=6, max_size=6),
       dV=st.lists(words, min_size=6, max_size=6), g=st.lists(words, min_size=3, max_size=3))
def test_compiled_vdc_link_equals_the_reference(link, th, K, rho, bounds, V, Vr, dV, g):
    """:class:`~cosim.model_kernel.KernelVdc`'s link (:func:`vdc_link`) gives
    :meth:`VdcModel._link <hdl.node.vdc_ref.VdcModel._link>`'s force words and adapted
    estimates bit for bit, saturated words included."""
    from mrm_cosim.hdl.node.vdc_ref import VdcModel
    from mrm_cosim.protocol.vdc_program import VdcParams

    lower = [min(a, b) for a, b in bounds]
    upper = [max(a, b) for a, b in bounds]
    other = [0] * 13

    def model():
        p = VdcParams(K=[K, K[::-1]][::1 - 2 * link], rho_T=[rho, other][::1 - 2 * link],
                      lower=[lower, other][::1 - 2 * link],
                      upper=[upper, other][::1 - 2 * link], inv_T=0)
        return VdcModel(p, [list(th), other][::1 - 2 * link])

    ref, fast = model(), model()
    mk.KernelVdc.adopt(fast)
    assert type(fast).__name__ == "KernelVdc"
    assert fast._link(link, V, Vr, dV, g) == ref._link(link, V, Vr, dV, g)


@needs_numba
def test_a_plant_with_its_own_step_gets_no_fast_path():
    """The fast path runs :class:`~models.plant.Plant`'s and
    :class:`~models.compliant.CompliantPlant`'s steps in pieces; a plant class that steps
    otherwise (a subclass overriding ``step``) keeps its own step: no fast path."""
    from mrm_cosim.cosim.model import ModelBackend
    from mrm_cosim.models.compliant import CompliantPlant
    from mrm_cosim.models.plant import Plant
    from mrm_cosim.models.robot import load_robot

    class OwnStep(Plant):
        def step(self, tau_cmd):
            Plant.step(self, tau_cmd)

    class OwnCompliantStep(CompliantPlant):
        def step(self, tau_cmd):
            CompliantPlant.step(self, tau_cmd)

    robot = load_robot("mrm3")
    rec = np.zeros((2, 4, robot.n))
    for cls, expect in ((Plant, True), (OwnStep, False), (CompliantPlant, True),
                        (OwnCompliantStep, False)):
        plant = cls(robot)
        backend = ModelBackend(kernel="numba")
        backend.power_on(plant.encoder_counts())
        backend.attach_plant(plant)
        assert (backend.fast_path(plant, rec) is not None) is expect, cls.__name__
    assert ModelBackend(kernel="python").fast_path(Plant(robot), rec) is None


@needs_numba
@settings(max_examples=200, deadline=None)
@given(vals=st.lists(st.integers(-(1 << 40), 1 << 40), min_size=20, max_size=20),
       torque_none=st.booleans(), land=st.sampled_from([None, "word", "dead"]),
       deferred=st.booleans(), prime_due=st.booleans(),
       flags=st.lists(st.booleans(), min_size=3, max_size=3))
def test_kernel_node_push_writes_each_field_where_the_kernel_reads_it(
        vals, torque_none, land, deferred, prime_due, flags):
    """:meth:`KernelNode.push` (one assignment of the whole row) puts every field of the
    object's tick state at its ``N_*`` index, a field marked absent as 0, and :meth:`pull`
    gives the object back unchanged."""
    from mrm_cosim.hdl.node.joint_ref import JointModel
    from mrm_cosim.protocol.regs import Config

    node = mk.KernelNode(joint=JointModel(JointParams.zero()))
    node.bind(mk.KernelArrays(2), 1, None)
    v = iter(vals)
    node._nt = next(v)
    node.torque = None if torque_none else next(v)
    c = next(v)
    node._landing = None if land is None else (c, next(v) if land == "word" else None)
    node._started, node._busy_until, node.overruns = next(v), next(v), next(v)
    node._deferred = (next(v), next(v), next(v), next(v)) if deferred else None
    j = node.joint
    j.q_des, j.v_des, j.i_lo, j.i_hi = next(v), next(v), next(v), next(v)
    node.armed, node.tripped, node.prime = flags
    node._prime_due = next(v) if prime_due else None
    node.last_packet, node.d_base = next(v), next(v)
    node.d_words = [11, -12, 13, -14]
    cfg = node.config
    cfg[Config.TICK], cfg[Config.MODE], cfg[Config.TIMEOUT] = 50, 2, 12345
    cfg[Config.TAU_MIN], cfg[Config.TAU_MAX], cfg[Config.RAMP] = -77, 88, 9
    before = dict(vars(node))
    before_joint = (j.q_des, j.v_des, j.i_lo, j.i_hi)
    node.push()
    N = node._row
    lnd = node._landing
    want = {src.N_NT: node._nt, src.N_TORQUE_NONE: int(torque_none),
            src.N_TORQUE: 0 if torque_none else node.torque,
            src.N_LAND: 0 if lnd is None else 2 if lnd[1] is None else 1,
            src.N_STARTED: node._started, src.N_BUSY: node._busy_until,
            src.N_OVERRUNS: node.overruns, src.N_DEF: int(deferred),
            src.N_QDES: j.q_des, src.N_VDES: j.v_des, src.N_ILO: j.i_lo, src.N_IHI: j.i_hi,
            src.N_ARMED: int(flags[0]), src.N_TRIPPED: int(flags[1]),
            src.N_PRIME: int(flags[2]), src.N_PRIME_SET: int(prime_due),
            src.N_LAST_PACKET: node.last_packet, src.N_DBASE: node.d_base,
            src.N_TICK: 50, src.N_MODE: 2, src.N_TIMEOUT: 12345, src.N_TAU_MIN: -77,
            src.N_TAU_MAX: 88, src.N_RAMP: 9}
    for k in range(4):
        want[src.N_D0 + k] = node.d_words[k]
    if lnd is not None:
        want[src.N_LAND_C] = lnd[0]
        if lnd[1] is not None:
            want[src.N_LAND_V] = lnd[1]
    if deferred:
        for k, f in enumerate((src.N_DEF_TN, src.N_DEF_Q, src.N_DEF_V, src.N_DEF_A)):
            want[f] = node._deferred[k]
    if prime_due:
        want[src.N_PRIME_DUE] = node._prime_due
    assert {k: int(N[k]) for k in want} == want and node.in_kernel
    node.pull()
    assert (j.q_des, j.v_des, j.i_lo, j.i_hi) == before_joint
    after = dict(vars(node))
    for name in ("_nt", "torque", "_landing", "_started", "_busy_until", "overruns",
                 "_deferred", "armed", "tripped", "prime", "_prime_due"):
        assert after[name] == before[name], name


@needs_numba
@settings(max_examples=200, deadline=None)
@given(th=st.lists(st.lists(words, min_size=13, max_size=13), min_size=2, max_size=2),
       K=st.lists(st.lists(words, min_size=6, max_size=6), min_size=2, max_size=2),
       rho=st.lists(st.lists(words, min_size=13, max_size=13), min_size=2, max_size=2),
       bounds=st.lists(st.lists(st.tuples(words, words), min_size=13, max_size=13),
                       min_size=2, max_size=2),
       inv_t=st.one_of(st.integers(0, WORD_MAX), st.just(WORD_MAX)),
       prev=st.one_of(st.none(), st.tuples(st.lists(words, min_size=6, max_size=6), words)),
       runs=st.lists(st.tuples(words, st.lists(words, min_size=6, max_size=6),
                               st.lists(words, min_size=6, max_size=6), words,
                               st.integers(-(1 << 22), 1 << 22),
                               st.integers(-(1 << 22), 1 << 22),
                               st.lists(words, min_size=3, max_size=3)),
                     min_size=1, max_size=3))
def test_compiled_vdc_step_equals_the_reference(th, K, rho, bounds, inv_t, prev, runs):
    """:class:`~cosim.model_kernel.KernelVdc`'s step (:func:`vdc_step`: the rotations into
    {A}, the backward differences, both links) gives :meth:`VdcModel.step
    <hdl.node.vdc_ref.VdcModel.step>`'s force words and leaves its state (estimates, previous
    {C} velocity and q̇_r, primed) bit for bit, over runs from unprimed and primed states,
    saturated words included."""
    import copy

    from mrm_cosim.hdl.node.vdc_ref import VdcInputs, VdcModel
    from mrm_cosim.protocol.vdc_program import VdcParams

    lower = [[min(a, b) for a, b in link] for link in bounds]
    upper = [[max(a, b) for a, b in link] for link in bounds]
    p = VdcParams(K=K, rho_T=rho, lower=lower, upper=upper, inv_T=inv_t)
    ref = VdcModel(copy.deepcopy(p), copy.deepcopy(th))
    fast = VdcModel(copy.deepcopy(p), copy.deepcopy(th))
    mk.KernelVdc.adopt(fast)
    if prev is not None:
        for m in (ref, fast):
            m.prev_C, m.prev_qd_r, m.primed = list(prev[0]), prev[1], True
    for qd_r, V_C, V_rC, qd, c, s, g in runs:
        x = VdcInputs(qd_r, V_C, V_rC, qd, c, s, g)
        assert fast.step(x) == ref.step(x)
        assert (fast.theta, fast.prev_C, fast.prev_qd_r, fast.primed) == \
            (ref.theta, ref.prev_C, ref.prev_qd_r, ref.primed)


@needs_numba
@settings(max_examples=300, deadline=None)
@given(rows=st.lists(st.tuples(st.booleans(), st.booleans(), st.integers(-10**6, 10**6),
                               st.integers(0, 10**6)), min_size=1, max_size=7),
       c=st.integers(-10**6, 3 * 10**6))
def test_any_trip_is_every_node_s_brake_test(rows, c):
    """:func:`any_trip` (ModelBackend.brake's shortcut) is the per-node test of a node the
    kernel holds: tripped, or armed with the watchdog's trip by ``c``."""
    N = np.zeros((len(rows), src.N_SIZE), dtype=np.int64)
    for k, (tripped, armed, last, timeout) in enumerate(rows):
        N[k, src.N_TRIPPED], N[k, src.N_ARMED] = tripped, armed
        N[k, src.N_LAST_PACKET], N[k, src.N_TIMEOUT] = last, timeout
    want = any(t or (a and c >= last + 2 + to) for t, a, last, to in rows)
    assert kern.any_trip(N, c) is want


@needs_numba
def test_borrowed_arrays_are_the_arrays_without_a_reference_count():
    """``borrow`` (cosim.model_kernel.borrowed): inside compiled code the same data, shape and
    strides, writes land in the caller's array, views of it work, and its meminfo is null (so
    numba's reference counting of it and of its views is a no-op, no atomic instruction); the
    Python object's own reference count is untouched. The entry points the backend calls
    from Python borrow their arrays."""
    import numba
    from numba.core import types
    from numba.extending import intrinsic

    assert kern.borrow is mk.borrowed()        # (the module jitted in place: src is kern)

    @intrinsic
    def meminfo_address(typingctx, a):
        def codegen(context, builder, sig, args):
            ary = context.make_array(sig.args[0])(context, builder, value=args[0])
            return builder.ptrtoint(ary.meminfo, context.get_value_type(types.intp))
        return types.intp(a), codegen

    borrow = mk.borrowed()

    @numba.njit
    def use(a):
        b = borrow(a)
        row = b[1]
        row[2] = 7
        return meminfo_address(a), meminfo_address(b), meminfo_address(row), b[1:, 1:].sum()

    a = np.arange(12, dtype=np.int64).reshape((3, 4))
    refs = sys.getrefcount(a)
    for _ in range(3):
        own, borrowed, view, total = use(a)
    assert own != 0 and borrowed == 0 and view == 0
    assert a[1, 2] == 7 and total == 5 + 7 + 7 + 9 + 10 + 11
    assert sys.getrefcount(a) == refs
    import inspect
    for name in ("fast_step", "fast_step_compliant", "plain_step", "node_plain", "vdc_step",
                 "step_changes"):
        assert "borrow(" in inspect.getsource(getattr(kern, name).py_func), name
