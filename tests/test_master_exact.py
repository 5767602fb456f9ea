"""The master's hot paths give the floats of their plain formulation bit for bit.

The master's kinematics run every period in a cheaper form than the textbook one (the chains
without their checks, the joint rotations built at once, BLAS's products through
``ndarray.dot``, Python floats where the arithmetic is elementwise). Their floats reach the
nodes through quantised words and the trace through the plant, so the cheaper form must give
the same IEEE results, not results within a tolerance: each is compared here, ``==`` on every
element, with the formulation the master had before (26 Nov, ``@`` on freshly built matrices,
one ``Robot.link_frames``), over random states of three robots — the built-in ones and an odd
one (a tilted base, twists that are no multiple of 90°).
"""

import math

import numpy as np
import pytest

from mrm_cosim.cosim.bench import bench_master_and_plant
from mrm_cosim.master.vdc import (
    _mount_U_of, force_chain, joint_rotations, mounts, propagate_forces, propagate_velocities,
    velocity_chain,
)
from mrm_cosim.models.robot import load_robot, robot_from_dict
from tests.test_vdc_master import ODD


def _robot(name):
    return robot_from_dict(ODD) if name == "odd" else load_robot(name)


def _rot_z(q):
    c, s = np.cos(q), np.sin(q)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def plain_velocities(robot, q, qd, qd_r, qdd_r):
    """propagate_velocities as it was: rows (V_C, Vr_C, dVr_C), (V_A, Vr_A, dVr_A)."""
    S = np.zeros((3, 6))
    S[2] = [0.0, 0.0, 9.81, 0.0, 0.0, 0.0]
    out = []
    for k in range(robot.n):
        C = S @ _mount_U_of(robot, k)
        A = (C.reshape(6, 3) @ _rot_z(q[k])).reshape(3, 6)
        qd_k = qd[k]
        a0, a1, a3, a4 = A[1, 0], A[1, 1], A[1, 3], A[1, 4]
        A[0, 5] += qd_k
        A[1, 5] += qd_r[k]
        A[2, 0] -= qd_k * -a1
        A[2, 1] -= qd_k * a0
        A[2, 3] -= qd_k * -a4
        A[2, 4] -= qd_k * a3
        A[2, 5] += qdd_r[k]
        out.append((C, A))
        S = A
    return out


def plain_forces(robot, q, F_a, F_b):
    """propagate_forces' F_A as it was."""
    F_A = np.zeros((robot.n, 6))
    F_C_next = np.zeros(6)
    for k in reversed(range(robot.n)):
        F = F_a[k].copy()
        if k + 1 < robot.n:
            F += _mount_U_of(robot, k + 1) @ F_C_next
        F_A[k] = F
        F_C_next = F_b[k] + (F.reshape(2, 3) @ _rot_z(q[k]).T).ravel()
    return F_A


def _states(robot, seed, count=300):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        scale = 10.0 ** rng.uniform(-4.0, 1.0)
        yield tuple(rng.uniform(-3.0, 3.0, robot.n) * scale for _ in range(4)), \
            rng.standard_normal((2, robot.n, 6)) * 30.0 * scale


@pytest.mark.parametrize("name", ["mrm3", "mrm6", "odd"])
def test_chains_equal_the_plain_formulation(name):
    robot = _robot(name)
    for (q, qd, qd_r, qdd_r), (F_a, F_b) in _states(robot, seed=len(name)):
        plain = plain_velocities(robot, q, qd, qd_r, qdd_r)
        fast = velocity_chain(robot, q, qd.tolist(), qd_r.tolist(), qdd_r.tolist())
        kin = propagate_velocities(robot, q, qd, qd_r, qdd_r)
        for (C0, A0), (C1, A1), m in zip(plain, fast, kin, strict=True):
            assert np.array_equal(C0, C1) and np.array_equal(A0, A1)
            assert np.array_equal(np.array([m.V_C, m.Vr_C, m.dVr_C]), C0)
            assert np.array_equal(np.array([m.V_A, m.Vr_A, m.dVr_A]), A0)
        F_A = plain_forces(robot, q, F_a, F_b)
        assert np.array_equal(force_chain(robot, joint_rotations(q), F_a, F_b), F_A)
        assert np.array_equal(propagate_forces(robot, q, F_a, F_b)[1], F_A[:, 5])


@pytest.mark.parametrize("name", ["mrm3", "mrm6", "odd"])
def test_gravity_equals_link_frames(name):
    robot = _robot(name)
    master, _ = bench_master_and_plant(robot)
    for (q, *_), _ in _states(robot, seed=7):
        plain = np.array([T_C[2, :3] * 9.81 for T_C, _ in robot.link_frames(q)])
        assert np.array_equal(master.gravity_in_C(q), plain)


def test_joint_rotations_are_rot_z():
    q = np.random.default_rng(3).uniform(-math.pi, math.pi, 1000)
    R = joint_rotations(q)
    assert all(np.array_equal(R[k], _rot_z(q[k])) for k in range(q.size))


def test_mounts_follow_the_robot():
    """The master's memo of the mounts follows a base moved in place and a module replaced."""
    import dataclasses

    robot = load_robot("mrm3")
    before = mounts(robot)[0][0].copy()
    robot.base[0, 3] += 0.25
    robot.modules = [dataclasses.replace(robot.modules[0], twist=0.3)] + robot.modules[1:]
    Ts, Us = mounts(robot)
    assert not np.array_equal(Ts[0], before)
    for k in range(robot.n):
        assert np.array_equal(Ts[k], robot.mount_transform(k))
        assert np.array_equal(Us[k], _mount_U_of(robot, k))


def _plain_comm_b(qd_r, V_C, V_rC, prime):
    """pack_comm_b as it was: every word by its format's encode."""
    from mrm_cosim.protocol.fixed import VEL
    from mrm_cosim.protocol.regs import pack_words

    enc = VEL.encode
    return pack_words([enc(qd_r), *map(enc, V_C), *map(enc, V_rC)]) + (b"\1" if prime else b"\0")


def _plain_comm_d(tau, g_C, q_d0, qd_d0, qdd_d0, cpr):
    """pack_comm_d as it was."""
    from mrm_cosim.protocol.fixed import ACC, FORCE, POS, VEL
    from mrm_cosim.protocol.regs import PAYLOAD, pack_words

    counts = q_d0 * cpr / (2 * math.pi)
    words = [FORCE.encode(tau)] + [ACC.encode(x) for x in g_C] + \
        [POS.encode(counts), VEL.encode(qd_d0), ACC.encode(qdd_d0)]
    out = pack_words(words)
    return out + bytes(PAYLOAD - len(out))


@pytest.mark.parametrize("seed", range(4))
def test_comm_b_and_d_packing_equals_the_formats_encode(seed):
    """The packers' inline encoding gives the bytes of every format's own ``encode``, over
    random values at every scale, ties at half an LSB, and beyond the words' range (saturated)."""
    from mrm_cosim.protocol.regs import pack_comm_b, pack_comm_d

    rng = np.random.default_rng(seed)
    for _ in range(300):
        scale = 10.0 ** rng.uniform(-8, 4)
        x = (rng.standard_normal(14) * scale).tolist()
        x[rng.integers(14)] = rng.integers(-2**26, 2**26) * 2.0**-20    # a tie, at some LSB
        x[rng.integers(14)] = float(rng.choice([1e9, -1e9, 0.0, -0.0]))
        prime = bool(rng.integers(2))
        assert pack_comm_b(x[0], x[1:7], x[7:13], prime) == \
            _plain_comm_b(x[0], x[1:7], x[7:13], prime)
        cpr = int(rng.choice([800_000, 4096, 1 << 24]))
        assert pack_comm_d(x[0], x[1:4], x[4] * 1e-3, x[5], x[6], cpr) == \
            _plain_comm_d(x[0], x[1:4], x[4] * 1e-3, x[5], x[6], cpr)


def _plain_comm_a(data):
    """parse_comm_a as it was: a from_bytes a field."""
    from mrm_cosim.protocol.regs import LINK_HEALTH, Status, unpack_words

    qd, tau = unpack_words(data, 2, 4)
    return {"count": int.from_bytes(data[0:4], "little", signed=True), "qd": qd, "torque": tau,
            "status": Status(int.from_bytes(data[10:12], "little")),
            "errors": int.from_bytes(data[12:14], "little"), "period": data[14],
            "overruns": int.from_bytes(data[15:17], "little"),
            "sync_errors": int.from_bytes(data[17:19], "little"),
            "late_d": int.from_bytes(data[19:21], "little"),
            "upload_crc": int.from_bytes(data[21:23], "little"),
            "upload_count": int.from_bytes(data[23:25], "little"),
            **{k: int.from_bytes(data[25 + 2 * i:27 + 2 * i], "little")
               for i, k in enumerate(LINK_HEALTH)},
            "dmp_overruns": int.from_bytes(data[33:35], "little")}


def test_comm_a_and_c_parsing_equals_the_plain_one():
    """parse_comm_a's one struct call gives every field (and its order, and Status) of the
    field-by-field parse; parse_comm_c's status is the enum's, over random payloads."""
    from mrm_cosim.protocol.regs import PAYLOAD, Status, parse_comm_a, parse_comm_c

    rng = np.random.default_rng(7)
    for _ in range(500):
        data = rng.integers(0, 256, PAYLOAD, dtype=np.uint8).tobytes()
        got, want = parse_comm_a(data), _plain_comm_a(data)
        assert got == want and list(got) == list(want)
        assert type(got["status"]) is Status
        status = parse_comm_c(data)[2]
        assert type(status) is Status and status == Status(int.from_bytes(data[36:38], "little"))
