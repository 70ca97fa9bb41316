"""Rounded published values in model files (0.866 for cos 30 deg, issue 14): refused unless the file asks for
``orthonormalize: true`` (per pose, or once at the top for every pose and joint axis); then projected onto the
nearest rotation (normalized) with a warning naming file, field and how far it moved, within a limit."""

import textwrap
import warnings

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from kincal import robots
from kincal.cli import main
from kincal.errors import DataFormatError, KincalWarning
from kincal.io import dump_robot, load_robot, parse_robot
from kincal.io.models import ORTHONORMALIZE_LIMIT

# DLR Agile Justin's right arm base (rokin's F_RIGHT_BASE), as published: a rotation about y by 150 deg, rounded
ROUNDED = [[-0.866, 0, 0.5], [0, 1, 0], [-0.5, 0, -0.866]]  # a rotation times 0.99997: only rescaled
# Frida's right base rotation (thesis Table A.1, 4 decimals): projecting it also turns its axes a little
FRIDA_TEXT = "[[0.5723, -0.1041, 0.8134], [0.6161, 0.7092, -0.3427], [-0.5412, 0.6973, 0.4700]]"
FRIDA = yaml.safe_load(FRIDA_TEXT)
TEXT = textwrap.dedent(
    """
    format: kincal-model
    version: 1
    name: rounded
    units: {length: m, angle: rad}
    arms:
      right:
        base:
          matrix: [[-0.866, 0, 0.5, 0.19], [0, 1, 0, 0.088], [-0.5, 0, -0.866, -0.256], [0, 0, 0, 1]]
        home: {xyz: [0.4, 0, 0], rotation: [[0.5723, -0.1041, 0.8134], [0.6161, 0.7092, -0.3427], [-0.5412, 0.6973, 0.4700]]}
        tool: {quaternion_wxyz: [0.7071, 0, 0.7071, 0]}
        joints:
          - {name: j1, axis: [0, 0, 1], point: [0, 0, 0]}
          - {name: j2, axis: [0, 0.5, 0.866], point: [0, 0, 0.2]}
    """
)


EXACT_AXIS = "[0, 0.6, 0.8]"


def _moved_deg(R) -> float:
    """The largest angle between a column of R and of its nearest rotation (scipy's, independent of kincal's)."""
    R = np.array(R, dtype=float)
    P = Rotation.from_matrix(R).as_matrix()
    sin = np.linalg.norm(np.cross(R.T, P.T), axis=-1) / np.linalg.norm(R, axis=0)
    return float(np.degrees(np.arcsin(sin)).max())


def _parse(text, file="m.yaml"):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        robot = parse_robot(text, file)
    return robot, [str(w.message) for w in caught if issubclass(w.category, KincalWarning)]


def test_rounded_rotation_is_refused_without_orthonormalize():
    with pytest.raises(DataFormatError, match=r"^m.yaml: arms.right.base.matrix: rotation is not orthonormal: "
                                              r"max \|R\^T R - I\| = .*set 'orthonormalize: true'") as info:
        parse_robot(TEXT.replace("[0, 0.5, 0.866]", EXACT_AXIS).replace(f"rotation: {FRIDA_TEXT}", "rpy: [0, 0, 0]"),
                    "m.yaml")
    assert "\n" not in str(info.value)


def test_file_level_orthonormalize_projects_every_pose_and_axis_and_says_how_far():
    robot, said = _parse("orthonormalize: true\n" + TEXT)
    arm = robot["right"]
    for T in (arm.base, arm.home, arm.tool):
        np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-15)
    np.testing.assert_allclose(arm.base[:3, :3], Rotation.from_matrix(ROUNDED).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(arm.base[:3, 3], [0.19, 0.088, -0.256])  # the translation is kept
    np.testing.assert_allclose(np.linalg.norm(arm.screws[1, 3:]), 1.0, atol=1e-15)
    assert len(said) == 4  # base, home, tool quaternion, joint 2 axis
    base = next(w for w in said if "arms.right.base.matrix" in w)
    assert base.startswith("m.yaml: arms.right.base.matrix: rotation projected onto the nearest rotation (max |R^T R")
    assert base.endswith("its axes turned by up to 0 deg")  # 0.866 for cos 30 deg: the columns only shrank
    home = next(w for w in said if "arms.right.home.rotation" in w)
    assert home.endswith(f"its axes turned by up to {_moved_deg(FRIDA):.3g} deg")
    assert 1e-4 < _moved_deg(FRIDA) < 1e-2
    assert any(w.startswith("m.yaml: arms.right.tool.quaternion_wxyz: normalized to a unit quaternion: found norm "
                            "0.99999") for w in said)
    assert any(w.startswith("m.yaml: arms.right.joints[1].axis: normalized to a unit vector: found norm 0.99997")
               for w in said)
    assert all("\n" not in w for w in said)


def test_per_pose_orthonormalize_and_a_pose_may_refuse_the_file_default():
    text = TEXT.replace("[0, 0.5, 0.866]", EXACT_AXIS).replace("-0.256], [0, 0, 0, 1]]", "-0.256], [0, 0, 0, 1]]\n      orthonormalize: true")
    with pytest.raises(DataFormatError, match=r"arms.right.home.rotation: rotation is not orthonormal"):
        parse_robot(text, "m.yaml")  # only the base asked for it
    text = text.replace("0.4700]]}", "0.4700]], orthonormalize: false}")
    with pytest.raises(DataFormatError, match=r"arms.right.home.rotation: rotation is not orthonormal"):
        parse_robot("orthonormalize: true\n" + text, "m.yaml")
    with pytest.raises(DataFormatError, match=r"m.yaml: orthonormalize: expected true or false, found 'yes please'"):
        parse_robot("orthonormalize: yes please\n" + TEXT, "m.yaml")


def test_axis_rounding_is_refused_with_a_hint_for_the_file_level_option():
    text = TEXT.replace("-0.256], [0, 0, 0, 1]]", "-0.256], [0, 0, 0, 1]]\n      orthonormalize: true")
    text = text.replace("0.4700]]}", "0.4700]], orthonormalize: true}")
    text = text.replace("0.7071, 0]}", "0.7071, 0], orthonormalize: true}")
    with pytest.raises(DataFormatError, match=r"m.yaml: arms.right.joints\[1\].axis: expected a unit vector \(norm 1 "
                                              r"within 1e-06\), found norm 0.99997.*'orthonormalize: true' at the "
                                              r"top of the file"):
        parse_robot(text, "m.yaml")


@pytest.mark.parametrize("old, new, field, words", [
    ("[[-0.866, 0, 0.5, 0.19]", "[[-0.8, 0, 0.5, 0.19]", r"arms.right.base.matrix",
     r"rotation is too far from orthonormal to be a rounded one: max \|R\^T R - I\| = 0.11"),
    ("[[-0.866, 0, 0.5, 0.19]", "[[0.866, 0, 0.5, 0.19]", r"arms.right.base.matrix",
     r"cannot orthonormalize: determinant -0.49\d+ is not positive"),
    ("[0.7071, 0, 0.7071, 0]", "[1, 0, 1, 0]", r"arms.right.tool.quaternion_wxyz",
     "expected a unit quaternion: norm 1.41421356 is too far from 1"),
    ("axis: [0, 0.5, 0.866]", "axis: [0, 0.5, 0.9]", r"arms.right.joints\[1\].axis",
     "expected a unit vector: norm 1.02956301 is too far from 1"),
])
@pytest.mark.filterwarnings("ignore::kincal.errors.KincalWarning")  # on the other, rounded, poses
def test_beyond_the_limit_is_still_refused(old, new, field, words):
    assert ORTHONORMALIZE_LIMIT == 1e-2
    with pytest.raises(DataFormatError, match=f"^m.yaml: {field}: {words}") as info:
        parse_robot("orthonormalize: true\n" + TEXT.replace(old, new), "m.yaml")
    assert "\n" not in str(info.value)


def test_projected_model_saves_exact_and_loads_back_silently():
    robot, _ = _parse("orthonormalize: true\n" + TEXT)
    back, said = _parse(dump_robot(robot), "saved.yaml")
    assert back == robot and said == []


def test_built_in_robots_load_without_warnings():
    """Frida's base matrices are projected (documented in docs/model-format.md): no warning on every load."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", KincalWarning)
        for name in robots.names():
            robots.load(name)


def test_cli_prints_the_warning_as_one_line(tmp_path, capsys):
    (tmp_path / "m.yaml").write_text("orthonormalize: true\n" + TEXT)
    assert main(["model", "show", str(tmp_path / "m.yaml")]) == 0
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if "arms.right.base.matrix" in x]
    assert len(lines) == 1 and lines[0].startswith(f"kincal: warning: {tmp_path / 'm.yaml'}: arms.right.base.matrix: "
                                                   "rotation projected onto the nearest rotation")
    assert "Traceback" not in err and "warnings.warn" not in err
    with pytest.warns(KincalWarning, match="arms.right.base.matrix: rotation projected"):
        assert load_robot(tmp_path / "m.yaml").name == "rounded"
