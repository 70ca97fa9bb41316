"""``kincal import`` / ``kincal export`` (issue #12, item 1): URDF patched from the URDF a model came from, a
clean URDF from a native model, DH / modified DH tables that reproduce the model (and refuse ill-conditioned
ones), controller offsets in channel order and motor units, JSON; each checked by forward kinematics at 200
configurations against kincal (and pinocchio where installed)."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from kincal import robots
from kincal.cli import main
from kincal.errors import ModelError
from kincal.io.export import controller_document, dh_document, import_urdf
from kincal.io.models import load_robot
from kincal.io.urdf_patch import patch_urdf
from kincal.kinematics import Robot, forward_kinematics
from kincal.kinematics.dh import to_dh
from kincal.lie import se3
from kincal.simulate import perturb_robot

yourdfpy = pytest.importorskip("yourdfpy")
from kincal.io.urdf import from_urdf  # noqa: E402

URDF = """<?xml version="1.0"?>
<!-- a test arm: comments, visuals and a joint outside the chain must survive export -->
<robot name="testarm">
  <material name="grey"><color rgba="0.5 0.5 0.5 1"/></material>
  <link name="world"/>
  <link name="base_link"><visual><geometry><cylinder radius="0.1" length="0.2"/></geometry></visual></link>
  <link name="l1"><inertial><mass value="3"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <link name="l2"><collision><geometry><box size="0.1 0.1 0.5"/></geometry></collision></link>
  <link name="l3"/><link name="l4"/><link name="flange"/><link name="tool0"/><link name="camera"/>
  <joint name="mount" type="fixed"><parent link="world"/><child link="base_link"/>
    <origin xyz="0.5 0 0" rpy="0 0 0.3"/></joint>
  <joint name="j1" type="revolute"><parent link="base_link"/><child link="l1"/>
    <origin xyz="0 0 0.3" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0.1 0.1" rpy="1.5707963267948966 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="elbow_bracket" type="fixed"><parent link="l2"/><child link="l3"/>
    <origin xyz="0.4 0 0" rpy="0 0 0.2"/></joint>
  <joint name="j3" type="revolute"><parent link="l3"/><child link="l4"/>
    <origin xyz="0.05 0 0" rpy="0 0.3 0"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="flange_joint" type="fixed"><parent link="l4"/><child link="flange"/>
    <origin xyz="0.3 0 0" rpy="0 1.5707963267948966 0"/></joint>
  <joint name="tool_joint" type="fixed"><parent link="flange"/><child link="tool0"/>
    <origin xyz="0 0 0.05" rpy="0 0 0"/></joint>
  <joint name="camera_joint" type="fixed"><parent link="l1"/><child link="camera"/>
    <origin xyz="0.1 0 0.2" rpy="0 0 0"/></joint>
</robot>
"""


def _calibrated(nominal, seed=3, base=True):
    cal = perturb_robot(Robot("r", {"arm": nominal}), "thesis", rng=seed)["arm"]
    if base:
        cal = cal.replace(base=se3.exp(np.array([0.01, 0.02, -0.01, 0.01, 0.02, 0.03])) @ cal.base,
                          tool=se3.exp(np.array([0.0, 0.01, 0.02, 0.0, 0.0, 0.1])) @ cal.tool)
    return cal


def _q(model, n=200, seed=0):
    return np.random.default_rng(seed).uniform(np.maximum(model.lower, -3), np.minimum(model.upper, 3), (n, model.dof))


def _fk_check(urdf_text, cal, base, tip):
    back = from_urdf(urdf_text, base, tip)
    q = _q(cal)
    assert np.abs(forward_kinematics(back, q) - forward_kinematics(cal, q)).max() < 1e-12


def _outside_chain(text):
    """Everything but the origins of the given joints' elements, for comparison."""
    root = ET.fromstring(text)
    for j in root.iter("joint"):
        o = j.find("origin")
        if o is not None:
            j.remove(o)
    return ET.tostring(root)


def test_patched_urdf_keeps_everything_but_the_chain_origins_and_reproduces_the_calibration():
    nominal = from_urdf(URDF, "base_link", "tool0")
    cal = _calibrated(nominal)
    out = patch_urdf(URDF, "base_link", "tool0", nominal, cal)
    _fk_check(out, cal, "base_link", "tool0")
    assert _outside_chain(out) == _outside_chain(URDF)  # names, visuals, inertials, limits, camera joint
    assert "a test arm" in out  # the comment before the root
    before = {j.get("name"): j.find("origin").attrib for j in ET.fromstring(URDF).iter("joint")}
    after = {j.get("name"): j.find("origin").attrib for j in ET.fromstring(out).iter("joint")}
    assert before["mount"] == after["mount"] and before["camera_joint"] == after["camera_joint"]
    assert before["tool_joint"] == after["tool_joint"]  # the flange joint takes the remainder
    assert before["j1"] != after["j1"]


def test_patch_refuses_a_model_of_another_urdf():
    nominal = from_urdf(URDF, "base_link", "tool0")
    other = nominal.replace(joint_names=("a", "b", "c"))
    with pytest.raises(ModelError, match="imported from"):
        patch_urdf(URDF, "base_link", "tool0", nominal, other)


def test_real_urdf_patch_in_pinocchio(tmp_path):
    path = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "figaroh-geometric" / "ur10" / "ur10_robot.urdf"
    if not path.is_file():
        pytest.skip("../shared/datasets/figaroh-geometric absent")
    nominal = from_urdf(path, "base_link", "tool0")
    cal = _calibrated(nominal)
    out = patch_urdf(path, "base_link", "tool0", nominal, cal)
    _fk_check(out, cal, "base_link", "tool0")
    src = path.read_text()
    assert out.count("<!--") == src.count("<!--") and out.count("<visual") == src.count("<visual")
    pin = pytest.importorskip("pinocchio")
    model = pin.buildModelFromXML(out)
    data = model.createData()
    q = _q(cal, 50)
    fb, ft = model.getFrameId("base_link"), model.getFrameId("tool0")
    for k in range(len(q)):
        qq = pin.neutral(model)
        for i, name in enumerate(cal.joint_names):
            qq[model.joints[model.getJointId(name)].idx_q] = q[k, i]
        pin.framesForwardKinematics(model, data, qq)
        T = np.linalg.inv(data.oMf[fb].homogeneous) @ data.oMf[ft].homogeneous
        assert np.abs(T - forward_kinematics(cal, q[k:k + 1])[0]).max() < 1e-12


@pytest.mark.parametrize("name", ["ur10", "frida", "panda"])
@pytest.mark.parametrize("modified", [False, True])
def test_dh_tables_reproduce_nominal_models(name, modified):
    robot = robots.load(name)
    for arm in robot.arms.values():
        doc = dh_document(arm, modified)
        assert doc["check"]["max_position_difference_m"] < 1e-12
        back = to_dh(arm, modified=modified).to_model()
        q = _q(arm)
        assert np.abs(forward_kinematics(back, q) - forward_kinematics(arm, q)).max() < 1e-12


def test_dh_of_calibrated_arms():
    """Calibrated Frida and Panda (no parallel axes) convert exactly; a calibrated UR10 (shoulder and elbow
    axes 0.1 deg from parallel) is refused with the joints and the distance of the common normal."""
    for name in ("frida", "panda"):
        cal = perturb_robot(robots.load(name), "fine", rng=1)
        for arm in cal.arms.values():
            q = _q(arm)
            assert np.abs(forward_kinematics(to_dh(arm).to_model(), q) - forward_kinematics(arm, q)).max() < 1e-12
    ur = perturb_robot(robots.load("ur10"), "fine", rng=1)["arm"]
    with pytest.raises(ModelError, match=r"shoulder_lift and elbow are .* deg from parallel.* m away"):
        to_dh(ur)


def test_controller_offsets_in_channel_order_and_motor_units():
    frida = robots.load("frida")
    right = frida["right"].replace(offsets=np.arange(1, 8) * 0.01)
    doc = controller_document(right)
    assert [c["joint"] for c in doc["channels"]] == [right.joint_names[j] for j in right.controller_order]
    assert [c["joint"] for c in doc["channels"]][2] == "j4"  # Frida: channels 1, 2, 7, 3, 4, 5, 6 from the base
    for c in doc["channels"]:
        j = right.joint_names.index(c["joint"])
        assert c["offset_joint"] == pytest.approx(right.offsets[j])
        assert c["offset_motor"] == pytest.approx(right.offsets[j] * right.gear_ratios[j])
    assert "theta = q + o" in doc["sign_convention"]


def test_cli_import_calibrate_export_round_trip(tmp_path, capsys):
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(URDF)
    model = tmp_path / "models" / "arm.yaml"
    assert main(["import", str(urdf), "--base-link", "base_link", "--tip-link", "tool0", "-o", str(model)]) == 0
    robot = load_robot(model)
    assert robot["arm"].meta["urdf"]["file"] == str(urdf.resolve())  # absolute: carried into calibrations
    cal = Robot(robot.name, {"arm": _calibrated(robot["arm"]).replace(meta=robot["arm"].meta)})
    cal_file = tmp_path / "models" / "cal.yaml"
    from kincal.io.models import save_robot
    save_robot(cal, cal_file)
    out = tmp_path / "out" / "cal.urdf"
    assert main(["export", str(cal_file), "--to", "urdf", "-o", str(out)]) == 0
    _fk_check(out.read_text(), cal["arm"], "base_link", "tool0")
    assert main(["export", str(cal_file), "--to", "urdf", "-o", str(out)]) == 2  # no overwrite
    assert "refusing to overwrite" in capsys.readouterr().err
    assert main(["export", str(cal_file), "--to", "urdf", "-o", str(out), "--overwrite"]) == 0
    for fmt in ("mdh", "controller", "json"):
        assert main(["export", str(cal_file), "--to", fmt, "-o", str(tmp_path / f"x.{fmt}")]) == 0
    doc = yaml.safe_load((tmp_path / "x.mdh").read_text())
    assert doc["check"]["max_position_difference_m"] < 1e-12 and len(doc["joints"]) == 3
    assert json.loads((tmp_path / "x.json").read_text())["arms"]["arm"]["meta"]["urdf"]["tip_link"] == "tool0"
    assert not list(tmp_path.rglob(".*kincal-tmp*"))


def test_native_model_exports_a_clean_urdf_with_joint_named_links(tmp_path):
    assert main(["export", "panda", "--to", "urdf", "-o", str(tmp_path / "panda.urdf")]) == 0
    text = (tmp_path / "panda.urdf").read_text()
    arm = robots.load("panda")["arm"]
    assert f'<link name="{arm.joint_names[0]}_link"/>' in text
    _fk_check(text, arm, "world", "tool")


def test_cli_bad_input_is_one_line(tmp_path, capsys):
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(URDF)
    cases = ((["import", str(urdf), "--base-link", "base_link", "--tip-link", "nowhere", "-o", str(tmp_path / "m.yaml")],
              "nowhere"),
             (["export", "frida", "--to", "dh", "-o", str(tmp_path / "f.yaml")], "several arms"),
             (["export", "ur10", "--arm", "left", "--to", "dh", "-o", str(tmp_path / "g.yaml")], "left"),
             (["export", "ur10", "--to", "urdf", "-o", str(tmp_path)], "is a directory"))
    for args, words in cases:
        assert main(args) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1, err
    moved = tmp_path / "moved.yaml"
    robot = import_urdf(urdf, "base_link", "tool0")
    from kincal.io.models import save_robot
    save_robot(robot, moved)
    urdf.unlink()
    assert main(["export", str(moved), "--to", "urdf", "-o", str(tmp_path / "o.urdf")]) == 2
    assert "not there any more" in capsys.readouterr().err
