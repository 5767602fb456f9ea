"""Robot description: Table 1, assemblies, URDF and pinocchio model, validation."""

import math
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest

from mrm_cosim.models.actuators import ACTUATORS
from mrm_cosim.models.modules import MODULE_TYPES, TABLE1, TABLE1_ERRATA
from mrm_cosim.models.robot import load_robot, matrix_to_rpy, robot_from_dict, rot_x, rpy_to_matrix
from mrm_cosim.models.spatial import theta_to_pinocchio, transform_theta
from mrm_cosim.errors import InputError

ROBOTS = ["mrm3", "mrm6"]


def test_table1_is_kept_as_printed():
    assert TABLE1["I"]["a"][0] == 1.8 and TABLE1["II"]["b"][0] == 1.64
    assert MODULE_TYPES["I"].link_a.printed == TABLE1["I"]["a"]
    # Module weights (Table 1: 2.6 kg and 4.9 kg) are within 0.4 kg of the two links' masses
    # (connectors and electronics are not in the link parameters).
    assert MODULE_TYPES["I"].mass == pytest.approx(2.3)
    assert MODULE_TYPES["II"].mass == pytest.approx(4.64)


def test_only_listed_table1_entries_disagree_with_m_r_squared():
    """θ₅..θ₇ must equal (m rᵢ)²/m to the printed precision, except the documented erratum."""
    found = set()
    for tname, links in TABLE1.items():
        for lname, t in links.items():
            for i in range(3):
                derived = t[1 + i] ** 2 / t[0]
                printed = t[4 + i]
                if not math.isclose(printed, derived, rel_tol=0.05, abs_tol=2e-6):
                    found.add((tname, lname, 4 + i))
    assert found == set(TABLE1_ERRATA)
    for (tname, lname, i), (printed, derived) in TABLE1_ERRATA.items():
        assert TABLE1[tname][lname][i] == printed
        link = getattr(MODULE_TYPES[tname], f"link_{lname}")
        assert link.theta()[i] == pytest.approx(derived)


@pytest.mark.parametrize("tname", sorted(MODULE_TYPES))
def test_table1_links_are_physical_bodies(tname):
    for link in (MODULE_TYPES[tname].link_a, MODULE_TYPES[tname].link_b):
        link.check_physical(tname)
        # Products of inertia printed as m rᵢrⱼ − Iᵢⱼ are reproduced by the derived body.
        t, p = link.theta(), link.printed
        np.testing.assert_allclose(t[[0, 1, 2, 3, 7, 8, 9, 10, 11, 12]],
                                   np.array(p)[[0, 1, 2, 3, 7, 8, 9, 10, 11, 12]], atol=1e-12)


def test_encoder_resolution_matches_paper():
    # 0.1571 rad ↔ 20,000 counts (paper §5.1; exactly 20,000 counts is 0.15708 rad).
    for t in MODULE_TYPES.values():
        assert t.counts_per_rev == 800_000
        assert 0.1571 * t.counts_per_rev / (2 * math.pi) == pytest.approx(20_000, rel=2e-4)


@pytest.mark.parametrize("name", ROBOTS)
def test_urdf_masses_are_table1_masses(name):
    robot = load_robot(name)
    root = ET.fromstring(robot.urdf())
    masses = {link.get("name"): float(link.find("inertial/mass").get("value"))
              for link in root.iter("link") if link.find("inertial") is not None}
    for k, mod in enumerate(robot.modules):
        assert masses[f"link{k + 1}a"] == TABLE1[mod.type.name]["a"][0]
        assert masses[f"link{k + 1}b"] == TABLE1[mod.type.name]["b"][0]
    joints = [j for j in root.iter("joint") if j.get("type") == "revolute"]
    assert [j.get("name") for j in joints] == robot.joint_names


@pytest.mark.parametrize("name", ROBOTS)
def test_pinocchio_bodies_carry_link_a_and_next_link_b(name):
    """Pinocchio merges the fixed mount into the moving body: body k = Link a of module k plus
    Link b of module k+1 (in {A_k}); Link b of module 1 sits on the base and moves nothing."""
    robot = load_robot(name)
    model = robot.pinocchio_model()
    assert model.nq == robot.n
    for k in range(robot.n):
        theta = robot.nominal_theta[k, 0].copy()
        if k + 1 < robot.n:
            M = robot.mount_transform(k + 1)
            theta += transform_theta(robot.nominal_theta[k + 1, 1], M[:3, :3], M[:3, 3])
        np.testing.assert_allclose(model.inertias[k + 1].toDynamicParameters(),
                                   theta_to_pinocchio(theta), atol=1e-12)


@pytest.mark.parametrize("name", ROBOTS)
def test_joint_torque_regressor_with_our_parameters_reproduces_rnea(name):
    robot = load_robot(name)
    model = robot.pinocchio_model()
    data = model.createData()
    rng = np.random.default_rng(3)
    pis = []
    for k in range(robot.n):
        theta = robot.nominal_theta[k, 0].copy()
        if k + 1 < robot.n:
            M = robot.mount_transform(k + 1)
            theta += transform_theta(robot.nominal_theta[k + 1, 1], M[:3, :3], M[:3, 3])
        pis.append(theta_to_pinocchio(theta))
    pi = np.concatenate(pis)
    for _ in range(5):
        q, v, a = (rng.uniform(-2, 2, robot.n) for _ in range(3))
        Y = pin.computeJointTorqueRegressor(model, data, q, v, a)
        np.testing.assert_allclose(Y @ pi, pin.rnea(model, data, q, v, a), atol=1e-10)


@pytest.mark.parametrize("name", ROBOTS)
def test_frames_match_pinocchio_and_interfaces_mate(name):
    robot = load_robot(name)
    model = robot.pinocchio_model()
    data = model.createData()
    rng = np.random.default_rng(5)
    for _ in range(5):
        q = rng.uniform(-robot.joint_limits, robot.joint_limits)
        pin.framesForwardKinematics(model, data, q)
        np.testing.assert_allclose(data.oMf[model.getFrameId("tool")].homogeneous,
                                   robot.tip_pose(q), atol=1e-12)
        for k, (T_C, T_A) in enumerate(robot.link_frames(q)):
            np.testing.assert_allclose(data.oMf[model.getFrameId(f"link{k + 1}a")].homogeneous,
                                       T_A, atol=1e-12)
            np.testing.assert_allclose(data.oMf[model.getFrameId(f"link{k + 1}b")].homogeneous,
                                       T_C, atol=1e-12)
            if k:  # {B_k} is {T_k-1} turned by the twist about their common x axis
                T_prev = data.oMf[model.getFrameId(f"T{k}")].homogeneous
                B = data.oMf[model.getFrameId(f"B{k + 1}")].homogeneous
                np.testing.assert_allclose(B[:3, 3], T_prev[:3, 3], atol=1e-12)
                np.testing.assert_allclose(B[:3, :3], T_prev[:3, :3] @ rot_x(
                    robot.modules[k].twist), atol=1e-12)


def test_mrm3_quintic_tip_speed_is_the_papers():
    """Table 2: 0.5226 m/s for q_i = i·q_d (quintic 0 → 0.1571 rad in 1 s)."""
    robot = load_robot("mrm3")
    model = robot.pinocchio_model()
    data = model.createData()
    fid = model.getFrameId("tool")
    D = 0.1571
    best = 0.0
    for s in np.linspace(0.3, 0.7, 801):
        qd = D * (10 * s**3 - 15 * s**4 + 6 * s**5) * np.array([1.0, 2.0, 3.0])
        vd = D * (30 * s**2 - 60 * s**3 + 30 * s**4) * np.array([1.0, 2.0, 3.0])
        pin.forwardKinematics(model, data, qd, vd)
        pin.updateFramePlacements(model, data)
        v = pin.getFrameVelocity(model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear
        best = max(best, float(np.linalg.norm(v)))
    assert round(best, 4) == 0.5226


def test_mrm3_spring_counterbalances_shoulder_gravity_at_rest():
    robot = load_robot("mrm3")
    model = robot.pinocchio_model()
    g = pin.computeGeneralizedGravity(model, model.createData(), robot.home)
    residual = g - robot.spring_torque(robot.home)
    assert abs(g[1]) > 7.0 and abs(residual[1]) < 0.5
    assert np.all(np.abs(residual) < robot.continuous_torques)


def test_mrm6_rests_within_continuous_torques():
    robot = load_robot("mrm6")
    model = robot.pinocchio_model()
    g = pin.computeGeneralizedGravity(model, model.createData(), robot.home)
    assert np.all(np.abs(g - robot.spring_torque(robot.home)) < robot.continuous_torques)


@pytest.mark.parametrize("seed", range(5))
def test_rpy_round_trip(seed):
    rpy = np.random.default_rng(seed).uniform(-3, 3, 3) * [1, 0.5, 1]
    R = rpy_to_matrix(rpy)
    np.testing.assert_allclose(R, pin.rpy.rpyToMatrix(*rpy), atol=1e-14)
    np.testing.assert_allclose(rpy_to_matrix(matrix_to_rpy(R)), R, atol=1e-12)


def _doc(**over):
    doc = {"name": "t", "modules": [{"type": "I"}, {"type": "II", "twist_deg": 90.0}]}
    doc.update(over)
    return doc


@pytest.mark.parametrize("doc, field", [
    (_doc(modules=[]), "modules"),
    (_doc(modules=[{"type": "IV"}]), "modules[0].type"),
    (_doc(modules=[{"type": "I", "twist": float("nan")}]), "modules[0].twist"),
    (_doc(modules=[{"type": "I", "twist": 0.1, "twist_deg": 3}]), "modules[0].twist"),
    (_doc(modules=[{"type": "I", "colour": "red"}]), "modules[0].colour"),
    (_doc(modules=[{"type": "I", "spring": {"torque": 1.0}}]), "modules[0].spring"),
    (_doc(modules=[{"type": "II", "spring": {"torque": 12.0}}]), "modules[0].spring.torque"),
    (_doc(base={"xyz": [0, 0]}), "base.xyz"),
    (_doc(base={"xyz": [0, 0, "up"]}), "base.xyz[2]"),
    (_doc(home_deg=[0.0, 200.0]), "home_deg[1]"),
    (_doc(home=[0.0]), "home"),
    (_doc(gravity=[0, 0, -9.81]), "gravity"),
    (_doc(module_types={"III": {"like": "V"}}), "module_types.III.like"),
    (_doc(module_types={"III": {"actuator": "X"}}), "module_types.III.continuous_torque"),
    (_doc(module_types={"III": {"like": "I", "length_a": -0.1}}), "module_types.III.length_a"),
    (_doc(module_types={"III": {"like": "I", "gear_ratio": 1.5}}), "module_types.III.gear_ratio"),
    (_doc(module_types={"III": {"like": "I", "continuous_torque": 20.0}}),
     "module_types.III.continuous_torque"),
    (_doc(module_types={"III": {"like": "I", "link_a": [1.0] + [0.0] * 9 + [1e-3, 1e-3, 5e-3]}}),
     "module_types.III.link_a"),
    (_doc(module_types={"I": {"like": "II"}}), "module_types.I"),
])
def test_rejects_bad_assembly_naming_the_field(doc, field):
    with pytest.raises(InputError) as info:
        robot_from_dict(doc)
    assert info.value.field == field


@pytest.mark.parametrize("doc, field", [
    (_doc(modules=[{"type": ["I"]}]), "modules[0].type"),
    (_doc(modules=[{"type": {"name": "I"}}]), "modules[0].type"),
    (_doc(modules=[{"twist_deg": 90.0}]), "modules[0].type"),
    (_doc(module_types={"III": {"like": ["I"]}}), "module_types.III.like"),
    (_doc(module_types={"III": {"like": {"name": "I"}}}), "module_types.III.like"),
])
def test_a_type_name_that_is_no_string_is_named(doc, field):
    """``type = ["I"]`` or a table (and the same for ``like``) used to end in
    ``TypeError: unhashable type`` from the lookup; it is refused naming the field."""
    with pytest.raises(InputError) as info:
        robot_from_dict(doc)
    assert info.value.field == field


@pytest.mark.parametrize("doc, field", [
    (_doc(name="arm\x1b[31m"), "name"),
    (_doc(name="two\nlines"), "name"),
    (_doc(name="nul\x00"), "name"),
    (_doc(name="c1\x9b"), "name"),
    (_doc(module_types={"III\n": {"like": "I"}}), "module_types.'III\\n'"),
])
def test_control_characters_in_names_are_refused(doc, field):
    """A name with an escape sequence or a newline was accepted, then printed raw by
    ``mrm robot show`` (repainting the terminal, splitting lines) and written into the URDF;
    it is refused naming the field."""
    with pytest.raises(InputError) as info:
        robot_from_dict(doc)
    assert info.value.field == field and "control characters" in info.value.message


def test_names_may_be_any_printable_text():
    assert robot_from_dict(_doc(name="Bras-é 3 (v2)")).name == "Bras-é 3 (v2)"


@pytest.mark.parametrize("fields, field", [
    ({"encoder_lines": 10**22}, "module_types.III.encoder_lines"),
    ({"gear_ratio": 2**63 - 1}, "module_types.III.gear_ratio"),
    ({"encoder_lines": 3_000_000_000}, "module_types.III.encoder_lines"),
    ({"encoder_lines": 10_737_419, "gear_ratio": 100}, "module_types.III.encoder_lines"),
])
def test_counts_per_rev_beyond_the_joint_count_is_refused_at_load(fields, field):
    """Huge encoder_lines or gear_ratio were accepted, then ``mrm run preview`` and ``mrm bench``
    ended in an OverflowError traceback (counts per revolution beyond int64); anything beyond
    the node's 32-bit signed joint count is refused when the robot is loaded."""
    with pytest.raises(InputError) as info:
        robot_from_dict(_doc(module_types={"III": {"like": "I", **fields}},
                             modules=[{"type": "III"}]))
    assert info.value.field == field and "32-bit" in info.value.message


def test_the_largest_counts_per_rev_loads_and_runs():
    from mrm_cosim.cosim.preview import run_preview
    from mrm_cosim.models.robot import MAX_COUNTS_PER_REV

    robot = robot_from_dict(_doc(module_types={"III": {"like": "I", "encoder_lines": 10_737_418}},
                                 modules=[{"type": "III"}]))
    assert robot.counts_per_rev[0] == 4 * 10_737_418 * 100 <= MAX_COUNTS_PER_REV
    assert np.isfinite(run_preview(robot, duration=0.005).summary["rho_s"])


def test_unknown_actuator_is_named_where_it_is_written():
    """An unknown actuator in [module_types.III] was accepted by ``mrm robot show``, then
    refused by the plant as ``modules[1].actuator`` (no such field: the module only says
    ``type = "III"``); it is refused at load as module_types.III.actuator."""
    with pytest.raises(InputError) as info:
        robot_from_dict(_doc(module_types={"III": {"like": "I", "actuator": "FHA-99"}},
                             modules=[{"type": "I"}, {"type": "III"}]))
    assert info.value.field == "module_types.III.actuator"
    assert "FHA-11C-100" in info.value.message


@pytest.mark.parametrize("doc, field", [
    (_doc(modules=[{"type": "I", "twist_deg": "90"}]), "modules[0].twist_deg"),
    (_doc(modules=[{"type": "I", "twist": "0.1"}]), "modules[0].twist"),
    (_doc(modules=[{"type": "II", "spring": {"torque": "8"}}]), "modules[0].spring.torque"),
    (_doc(base={"xyz": [0, 0, "0.3"]}), "base.xyz[2]"),
    (_doc(tool={"rpy_deg": ["0", 0, 0]}), "tool.rpy_deg[0]"),
    (_doc(home_deg=["10", 0.0]), "home_deg[0]"),
    (_doc(module_types={"III": {"like": "I", "length_a": "0.3"}}), "module_types.III.length_a"),
    (_doc(module_types={"III": {"like": "I", "spring_max": "1"}}), "module_types.III.spring_max"),
    (_doc(module_types={"III": {"like": "I", "joint_limit_deg": "90"}}),
     "module_types.III.joint_limit_deg"),
])
def test_numbers_written_as_strings_are_refused(doc, field):
    """``twist_deg = "90"`` (a quoted number) was silently read as 90 (float() takes the
    string); it is refused naming the field, so a quoting mistake is seen."""
    with pytest.raises(InputError) as info:
        robot_from_dict(doc)
    assert info.value.field == field and "string" in info.value.message


def test_user_module_type_like_builtin():
    robot = robot_from_dict(_doc(
        module_types={"Ilong": {"like": "I", "length_a": 0.3, "joint_limit_deg": 90}},
        modules=[{"type": "Ilong"}, {"type": "I", "twist_deg": 90}]))
    assert robot.modules[0].type.length_a == 0.3
    assert robot.modules[0].type.link_a == MODULE_TYPES["I"].link_a
    assert robot.joint_limits[0] == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(robot.tip_pose([0.0, 0.0])[:3, 3], [0.3 + 0.1 + 0.2 + 0.1, 0, 0])
    pin.buildModelFromXML(robot.urdf())


def test_unknown_robot_and_unreadable_file(tmp_path):
    with pytest.raises(InputError, match="unknown robot"):
        load_robot("mrm99")
    with pytest.raises(InputError, match="does not exist"):
        load_robot(str(tmp_path / "missing.toml"))
    bad = tmp_path / "bad.toml"
    bad.write_text("name = [")
    with pytest.raises(InputError, match="not valid TOML"):
        load_robot(str(bad))


def test_docs_example_assembly_loads():
    """The assembly shown in docs/robot.md is valid as printed."""
    import re
    import tomllib
    from pathlib import Path

    text = (Path(__file__).parents[1] / "docs" / "robot.md").read_text()
    block = re.search(r"```toml\n(.*?)```", text, re.S).group(1)
    robot = robot_from_dict(tomllib.loads(block))
    assert robot.n == 2 and robot.modules[1].type.length_a == 0.30
    pin.buildModelFromXML(robot.urdf())


@pytest.mark.parametrize("fields, field, words", [
    ({"like": "I", "gear_ratio": 80}, "module_types.III.gear_ratio", "gear of actuator"),
    ({"like": "I", "actuator": "FHA-14C-100", "gear_ratio": 160},
     "module_types.III.gear_ratio", r"FHA-14C-100 \(100\)"),
    ({"like": "I", "peak_torque": 12.0}, "module_types.III.peak_torque", "11.0 N·m"),
])
def test_a_module_type_cannot_claim_more_of_its_drive_than_the_plant_has(fields, field, words):
    """The plant takes the drive's inertia, friction and saturation from the actuator: a type
    with another gear (its counts went to the master and nodes, the plant kept the actuator's
    encoder and dynamics; the arm stopped 20 % short at gear 80) or a peak torque above the
    actuator's (commands the plant would silently clip) is refused at load, naming the field."""
    with pytest.raises(InputError, match=words) as info:
        robot_from_dict(_doc(module_types={"III": fields}, modules=[{"type": "III"}]))
    assert info.value.field == field


def test_a_new_type_takes_its_actuators_gear_and_encoder_unless_it_gives_its_own():
    base = asdict_type("I")
    robot = robot_from_dict(_doc(module_types={"N": base, "M": {**base, "encoder_lines": 1900}},
                                 modules=[{"type": "N"}, {"type": "M"}]))
    assert robot.modules[0].type.gear_ratio == ACTUATORS["FHA-11C-100"].gear_ratio
    assert list(robot.counts_per_rev) == [800_000, 760_000]


def asdict_type(name: str) -> dict:
    """A built-in type as a ``[module_types.X]`` table without ``like`` (no gear, no encoder)."""
    t = MODULE_TYPES[name]
    return {"actuator": t.actuator, "peak_torque": t.peak_torque,
            "continuous_torque": t.continuous_torque, "max_speed": t.max_speed,
            "length_a": t.length_a, "length_b": t.length_b,
            "link_a": list(t.link_a.theta()), "link_b": list(t.link_b.theta())}


def test_mount_transform_memo_follows_the_base_and_hands_out_copies():
    """``Robot.mount_transform`` is memoised for the master: a changed base (in place or
    replaced) gives the new transform, and writing into a result does not reach the memo."""
    fresh = load_robot("mrm3")
    robot = load_robot("mrm3")
    first = [robot.mount_transform(k) for k in range(robot.n)]
    assert all(np.array_equal(first[k], fresh.mount_transform(k)) for k in range(robot.n))
    first[0][:] = 0.0
    assert np.array_equal(robot.mount_transform(0), fresh.mount_transform(0))
    robot.base[0, 3] += 0.25                      # in place
    moved = robot.mount_transform(0)
    assert moved[0, 3] == pytest.approx(fresh.mount_transform(0)[0, 3] + 0.25)
    assert np.array_equal(robot.mount_transform(1), fresh.mount_transform(1))
    robot.base = np.eye(4)                        # replaced
    assert np.array_equal(robot.mount_transform(0)[:3, :3], fresh.mount_transform(0)[:3, :3]
                          @ np.linalg.inv(fresh.base[:3, :3]))
