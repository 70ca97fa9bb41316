"""Model files: exact round trip, unit handling, pose forms, and one clear DataFormatError per bad input."""

import textwrap
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from kincal import robots
from kincal.errors import DataFormatError
from kincal.io import dump_robot, load_robot, parse_robot, save_robot
from kincal.kinematics import ArmModel, Robot, forward_kinematics
from kincal.lie.rotations import matrix_to_quat_wxyz, matrix_to_rpy, quat_wxyz_to_matrix, rpy_to_matrix
from kincal.testing import random_arm

GOOD = textwrap.dedent(
    """
    format: kincal-model
    version: 1
    name: demo
    units: {length: mm, angle: deg}
    arms:
      left:
        base: {xyz: [100, 0, 50], rpy: [0, 0, 90]}
        home: {xyz: [300, 0, 400], quaternion_wxyz: [0.7071067811865476, 0, 0.7071067811865476, 0]}
        tool: {rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]], xyz: [0, 0, 20]}
        controller_order: [j1, j3, j2]
        joints:
          - {name: j1, axis: [0, 0, 1], point: [0, 0, 0], limits: [-170, 170], gear_ratio: 100, offset: 1.5}
          - {name: j2, axis: [0, 1, 0], point: [0, 0, 250], limits: [null, 90]}
          - {name: j3, type: prismatic, axis: [1, 0, 0], limits: [0, 200], offset: 5}
    """
)


def _write(tmp_path, text, name="model.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_good_file_converts_units_and_pose_forms(tmp_path):
    robot = load_robot(_write(tmp_path, GOOD))
    arm = robot["left"]
    np.testing.assert_allclose(arm.base[:3, 3], [0.1, 0, 0.05])
    np.testing.assert_allclose(arm.base[:3, :3], Rotation.from_euler("z", 90, degrees=True).as_matrix(), atol=1e-15)
    np.testing.assert_allclose(arm.home[:3, :3], Rotation.from_euler("y", 90, degrees=True).as_matrix(), atol=1e-15)
    np.testing.assert_allclose(arm.home[:3, 3], [0.3, 0, 0.4])
    np.testing.assert_allclose(arm.tool[:3, 3], [0, 0, 0.02])
    np.testing.assert_allclose(arm.screws[1], [-0.25, 0, 0, 0, 1, 0])  # v = -w x p with p in m
    np.testing.assert_allclose(arm.screws[2], [1, 0, 0, 0, 0, 0])  # prismatic direction is unitless
    np.testing.assert_allclose(arm.offsets, [np.radians(1.5), 0, 0.005])
    np.testing.assert_allclose(arm.lower, [np.radians(-170), -np.inf, 0.0])
    np.testing.assert_allclose(arm.upper, [np.radians(170), np.radians(90), 0.2])
    np.testing.assert_array_equal(arm.gear_ratios, [100, 1, 1])
    assert arm.controller_order == (0, 2, 1)
    assert arm.joint_types == ("revolute", "revolute", "prismatic")


@pytest.mark.parametrize("name", robots.names())
def test_builtin_round_trip_is_exact(tmp_path, name):
    robot = robots.load(name)
    back = load_robot(save_robot(robot, tmp_path / f"{name}.yaml"))
    assert back == robot
    for key, arm in robot.arms.items():  # == compares arrays exactly; check the rest too
        assert dict(back[key].meta) == dict(arm.meta)
        assert back[key].controller_order == arm.controller_order
    assert dict(back.meta) == dict(robot.meta)


def test_random_robot_round_trip_is_exact(tmp_path, rng):
    arms = {}
    for k, (n, prismatic) in enumerate([(6, ()), (7, (2,)), (3, (0, 1))]):
        arm = random_arm(rng, n, prismatic, name=f"a{k}")
        arms[f"a{k}"] = arm.replace(
            lower=rng.uniform(-3, -1, n), upper=np.r_[rng.uniform(1, 3, n - 1), np.inf],
            gear_ratios=rng.uniform(-120, 120, n), controller_order=tuple(rng.permutation(n)),
        )
    robot = Robot("random", arms, {"note": "round trip"})
    back = parse_robot(dump_robot(robot))
    assert back == robot
    q = rng.uniform(-1, 1, (5, 7))
    np.testing.assert_array_equal(forward_kinematics(back["a1"], q), forward_kinematics(robot["a1"], q))


def test_save_refuses_to_overwrite(tmp_path):
    robot = robots.load("klimchik3r")
    path = save_robot(robot, tmp_path / "k.yaml")
    before = path.read_text()
    with pytest.raises(DataFormatError, match="exists; not overwritten"):
        save_robot(robots.load("ur10"), path)
    assert path.read_text() == before
    save_robot(robots.load("ur10"), path, overwrite=True)
    assert load_robot(path).name == "ur10"


def test_saved_file_is_versioned_si_and_safe_yaml(tmp_path):
    data = yaml.safe_load(dump_robot(robots.load("frida")))
    assert data["format"] == "kincal-model" and data["version"] == 1
    assert data["units"] == {"length": "m", "angle": "rad"}
    assert data["arms"]["right"]["controller_order"] == ["j1", "j2", "j4", "j5", "j6", "j7", "j3"]


def test_orthonormalize_is_explicit(tmp_path):
    rounded = GOOD.replace("base: {xyz: [100, 0, 50], rpy: [0, 0, 90]}",
                           "base: {rotation: [[0.5723, -0.1041, 0.8134], [0.6161, 0.7092, -0.3427], "
                           "[-0.5412, 0.6973, 0.4700]]}")
    msg = r"arms\.left\.base\.rotation: rotation is not orthonormal.*orthonormalize"
    with pytest.raises(DataFormatError, match=msg):
        load_robot(_write(tmp_path, rounded))
    fixed = rounded.replace("0.4700]]}", "0.4700]], orthonormalize: true}")
    R = load_robot(_write(tmp_path, fixed, "fixed.yaml"))["left"].base[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)


BAD_CASES = [
    # (replace this, with that, expected field path, expected words)
    ("axis: [0, 1, 0], point: [0, 0, 250]", "axis: [0, 1.2, 0], point: [0, 0, 250]",
     r"arms\.left\.joints\[1\]\.axis", "unit vector.*norm 1.2"),
    ("point: [0, 0, 250]", "point: [0, 250]", r"arms\.left\.joints\[1\]\.point", "list of 3 numbers.*length 2"),
    ("rpy: [0, 0, 90]", "rotation: [[1, 0, 0], [0, 1, 0], [0, 0.1, 1]]", r"arms\.left\.base\.rotation",
     "not orthonormal"),
    ("home: {xyz", "# home: {xyz",
     r"arms\.left", "missing key 'home'"),
    ("units: {length: mm, angle: deg}", "units: {length: inch, angle: deg}", r"units\.length",
     "unknown length unit 'inch'"),
    ("gear_ratio: 100,", "gear_ration: 100,", r"arms\.left\.joints\[0\]\.gear_ration", "unknown key 'gear_ration'"),
    ("version: 1", "version: 2", "version", "expected 1"),
    ("format: kincal-model", "format: urdf", "format", "expected 'kincal-model'"),
    ("controller_order: [j1, j3, j2]", "controller_order: [j1, j3, j9]", r"arms\.left\.controller_order\[2\]",
     "unknown joint 'j9'"),
    ("limits: [-170, 170]", "limits: [170, -170]", r"arms\.left\.joints\[0\]\.limits", "lower < upper"),
    ("quaternion_wxyz: [0.7071067811865476, 0, 0.7071067811865476, 0]", "quaternion_wxyz: [1, 0, 1, 0]",
     r"arms\.left\.home\.quaternion_wxyz", "unit quaternion"),
    ("axis: [0, 0, 1], point: [0, 0, 0]", "twist: [0, 0, 0.1, 0, 0, 1]", r"arms\.left\.joints\[0\]\.twist",
     "zero pitch"),
    ("{name: j1, axis: [0, 0, 1], point: [0, 0, 0],", "{name: j1,", r"arms\.left\.joints\[0\]", "either as 'axis'"),
    ("name: j2,", "name: j1,", r"arms\.left\.joints\[1\]\.name", "duplicate joint name"),
    ("offset: 5}", "offset: five}", r"arms\.left\.joints\[2\]\.offset", "expected a number"),
]


@pytest.mark.parametrize("old,new,field,words", BAD_CASES, ids=[c[2].replace("\\", "") for c in BAD_CASES])
def test_bad_input_names_file_and_field(tmp_path, old, new, field, words):
    assert old in GOOD
    path = _write(tmp_path, GOOD.replace(old, new))
    with pytest.raises(DataFormatError, match=rf"^{str(path)}: {field}: .*{words}"):
        load_robot(path)


def test_yaml_syntax_error_names_line(tmp_path):
    path = _write(tmp_path, GOOD.replace("name: demo", "name: [demo"))
    with pytest.raises(DataFormatError, match=rf"^{path}: not valid YAML \(line \d+"):
        load_robot(path)


def test_safe_load_refuses_python_tags(tmp_path):
    path = _write(tmp_path, GOOD.replace("name: demo", "name: !!python/object/apply:os.getcwd []"))
    with pytest.raises(DataFormatError, match="not valid YAML"):
        load_robot(path)


def test_unknown_source_lists_builtins(tmp_path):
    with pytest.raises(DataFormatError, match="no such model file and no built-in robot"):
        load_robot(tmp_path / "missing.yaml")


def test_model_from_file_equals_model_built_in_code():
    arm = robots.load("klimchik3r")["arm"]
    ref = ArmModel("arm", np.array([[0, 0, 0, 0, 0, 1.0], [1.0, 0, 0, 0, -1, 0], [1.0, 0, -0.8, 0, -1, 0]]),
                   np.array([[1, 0, 0, 1.4], [0, 1, 0, 0], [0, 0, 1, 1.0], [0, 0, 0, 1]]))
    np.testing.assert_allclose(arm.screws, ref.screws, atol=1e-15)
    np.testing.assert_array_equal(arm.home, ref.home)


def test_docs_example_parses():
    doc = Path(__file__).resolve().parents[1] / "docs" / "model-format.md"
    text = doc.read_text()
    example = text.split("```yaml\n", 1)[1].split("```", 1)[0]
    arm = parse_robot(example, "docs example")["left"]
    assert arm.joint_names == ("j1", "j2", "j3", "j4") and arm.controller_order == (0, 1, 3, 2)
    np.testing.assert_allclose(arm.home[:3, 3], [0.3375, 0, 0.4105])
    np.testing.assert_allclose(arm.base[:3, :3].T @ arm.base[:3, :3], np.eye(3), atol=1e-15)


def test_rotation_helpers_match_scipy_including_gimbal_lock_and_pi():
    R = Rotation.random(500, random_state=7)
    M = R.as_matrix()
    special = Rotation.from_euler("xyz", [[0.3, np.pi / 2, 0.5], [0.3, -np.pi / 2, 0.5], [np.pi, 0, 0],
                                          [0, np.pi, 0], [np.pi - 1e-7, 0.2, 0]]).as_matrix()
    M = np.concatenate([M, special])
    np.testing.assert_allclose(rpy_to_matrix(matrix_to_rpy(M)), M, atol=1e-14)
    rpy = R.as_euler("xyz")  # scipy extrinsic xyz = Rz(y) Ry(p) Rx(r)
    np.testing.assert_allclose(rpy_to_matrix(rpy), R.as_matrix(), atol=1e-14)
    q = matrix_to_quat_wxyz(M)
    assert np.all(q[:, 0] >= 0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1, atol=1e-15)
    np.testing.assert_allclose(quat_wxyz_to_matrix(q), M, atol=1e-14)
    xyzw = Rotation.from_matrix(M).as_quat()
    ref = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=-1) * np.where(xyzw[:, 3:] < 0, -1, 1)
    np.testing.assert_allclose(np.abs(np.sum(q * ref, axis=-1)), 1, atol=1e-14)
