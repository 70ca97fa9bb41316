"""``kincal export --to ur-ros`` (issue #12): the kinematics file of the Universal Robots ROS driver.

The nominal UR10 gives the driver's own default file; a calibrated UR10, composed as the ur_description xacro
composes the file, reproduces kincal's forward kinematics; other arms are refused in one line."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from kincal import robots
from kincal.cli import main
from kincal.errors import ModelError
from kincal.io.ur_ros import UR_LINKS, ur_ros_document, ur_ros_text
from kincal.kinematics import Robot, forward_kinematics
from kincal.lie import se3
from kincal.lie.rotations import rpy_to_matrix
from kincal.simulate import perturb_robot

# ros-industrial/universal_robot, ur_description/config/ur10/default_kinematics.yaml (the UR10 defaults the
# driver's description loads when no kinematics_params_file is given): x, y, z, roll, pitch, yaw per link.
UR10_DEFAULT = {
    "shoulder": (0, 0, 0.1273, 0, 0, 0),
    "upper_arm": (0, 0, 0, 1.570796327, 0, 0),
    "forearm": (-0.612, 0, 0, 0, 0, 0),
    "wrist_1": (-0.5723, 0, 0.163941, 0, 0, 0),
    "wrist_2": (0, -0.1157, -2.373046667922381e-11, 1.570796327, 0, 0),
    "wrist_3": (0, 0.0922, -1.891053610911353e-11, 1.570796326589793, 3.141592653589793, 3.141592653589793),
}
FIELDS = ("x", "y", "z", "roll", "pitch", "yaw")


def _origin(k) -> np.ndarray:
    """A joint origin as URDF reads it: Trans(x, y, z) Rz(yaw) Ry(pitch) Rx(roll), written out here."""
    r, p, y = k["roll"], k["pitch"], k["yaw"]
    c, s = np.cos, np.sin
    Rx = np.array([[1, 0, 0], [0, c(r), -s(r)], [0, s(r), c(r)]])
    Ry = np.array([[c(p), 0, s(p)], [0, 1, 0], [-s(p), 0, c(p)]])
    Rz = np.array([[c(y), -s(y), 0], [s(y), c(y), 0], [0, 0, 1]])
    return se3.make(Rz @ Ry @ Rx, np.array([k["x"], k["y"], k["z"]]))


def _xacro_fk(doc, q) -> np.ndarray:
    """world -> base_link (kincal block) -> base_link_inertia (Rz(pi)) -> six joints (origin, then rotation
    about z) -> tool0 -> tool (kincal block), as ur_description/urdf/inc/ur_macro.xacro chains them."""
    pose = lambda d: se3.make(rpy_to_matrix(d["rpy"]), np.array(d["xyz"]))  # noqa: E731
    out = []
    for row in q:
        T = pose(doc["kincal"]["world_to_base_link"]) @ se3.make(rpy_to_matrix([0, 0, np.pi]), np.zeros(3))
        for link, qi in zip(UR_LINKS, row):
            T = T @ _origin(doc["kinematics"][link]) @ se3.make(rpy_to_matrix([0, 0, qi]), np.zeros(3))
        out.append(T @ pose(doc["kincal"]["tool0_to_tool"]))
    return np.array(out)


def _calibrated_ur10(seed=3):
    arm = perturb_robot(Robot("r", {"arm": robots.load("ur10")["arm"]}), "thesis", rng=seed)["arm"]
    return arm.replace(base=se3.exp(np.array([0.01, 0.02, -0.01, 0.01, 0.02, 0.03])) @ arm.base,
                       tool=se3.exp(np.array([0.0, 0.01, 0.02, 0.0, 0.0, 0.1])) @ arm.tool)


def test_nominal_ur10_gives_the_drivers_default_file(tmp_path, capsys):
    out = tmp_path / "ur10_kinematics.yaml"
    assert main(["export", "ur10", "--to", "ur-ros", "--ur-hash", "calib_17227329492635474227", "-o", str(out)]) == 0
    doc = yaml.safe_load(out.read_text())
    assert list(doc["kinematics"]) == list(UR_LINKS) + ["hash"]
    assert doc["kinematics"]["hash"] == "calib_17227329492635474227"
    for link, values in UR10_DEFAULT.items():
        got = doc["kinematics"][link]
        assert list(got) == list(FIELDS)
        assert np.allclose([got[f] for f in FIELDS], values, rtol=0, atol=1e-9), link
    assert doc["kincal"]["tool0_to_tool"] == {"xyz": [0.0, 0.0, 0.0], "rpy": [0.0, 0.0, 0.0]}
    assert "note" not in capsys.readouterr().out  # nothing to warn about with the robot's own hash


def test_calibrated_ur10_round_trips_through_the_xacro_chain():
    for seed in (3, 4):
        cal = _calibrated_ur10(seed)
        doc = ur_ros_document(cal)
        q = np.random.default_rng(seed).uniform(-np.pi, np.pi, (200, 6))
        assert np.abs(_xacro_fk(doc, q) - forward_kinematics(cal, q)).max() < 1e-9
        assert doc["kincal"]["check"]["max_position_difference_m"] < 1e-12
        off = doc["kincal"]["flange_off_joint6_axis"]
        assert off["position_mm"] > 0.01 and off["rotation_deg"] > 0.01  # the thesis errors move the flange
        # the link frames stay near the nominal ones (meshes in place): lengths within 0.1 m of the defaults
        for link, values in UR10_DEFAULT.items():
            got = doc["kinematics"][link]
            assert np.abs(np.array([got[f] for f in "xyz"]) - np.array(values[:3])).max() < 0.1, link


def test_flange_on_joint6_axis_needs_no_tool_remainder():
    arm = robots.load("ur10")["arm"]
    cal = arm.replace(offsets=np.array([0.01, -0.02, 0.03, 0.0, 0.01, -0.01]))  # the flange stays on joint 6's axis
    doc = ur_ros_document(cal)
    assert doc["kincal"]["flange_off_joint6_axis"] == {"position_mm": 0.0, "rotation_deg": 0.0}
    q = np.random.default_rng(1).uniform(-np.pi, np.pi, (200, 6))
    assert np.abs(_xacro_fk(doc, q) - forward_kinematics(cal, q)).max() < 1e-9


def test_calibrated_export_states_the_flange_remainder(tmp_path):
    text, notes = ur_ros_text(_calibrated_ur10(), "model.yaml")
    assert any("off joint 6's axis" in n and "mm" in n and "deg" in n for n in notes)
    assert any("--ur-hash" in n for n in notes)
    assert yaml.safe_load(text)["kinematics"]["hash"].startswith("kincal_")


@pytest.mark.parametrize("name", ["panda", "frida", "klimchik3r"])
def test_non_ur_arms_are_refused_in_one_line(name, tmp_path, capsys):
    robot = robots.load(name)
    arm = next(iter(robot.arms))
    with pytest.raises(ModelError, match="needs 6 revolute joints"):
        ur_ros_document(robot[arm])
    code = main(["export", name, "--arm", arm, "--to", "ur-ros", "-o", str(tmp_path / "k.yaml")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "6 revolute joints" in err
    assert not (tmp_path / "k.yaml").exists()


# The joint layout of ur_description's ur_macro.xacro (base_link -> base_link_inertia turned by pi, six joints
# whose origins come from the kinematics file, wrist_3_link -> flange -> tool0), written here for the test.
XACRO = """<?xml version="1.0"?>
<robot name="ur" xmlns:xacro="http://wiki.ros.org/xacro">
  <xacro:property name="kin" value="${{xacro.load_yaml('{file}')['kinematics']}}"/>
  <link name="base_link"/><link name="base_link_inertia"/><link name="flange"/><link name="tool0"/>
  <joint name="base_link-base_link_inertia" type="fixed"><parent link="base_link"/>
    <child link="base_link_inertia"/><origin xyz="0 0 0" rpy="0 0 ${{pi}}"/></joint>
  <xacro:macro name="arm_joint" params="name parent child key">
    <link name="${{child}}"/>
    <joint name="${{name}}" type="revolute"><parent link="${{parent}}"/><child link="${{child}}"/>
      <origin xyz="${{kin[key]['x']}} ${{kin[key]['y']}} ${{kin[key]['z']}}"
              rpy="${{kin[key]['roll']}} ${{kin[key]['pitch']}} ${{kin[key]['yaw']}}"/>
      <axis xyz="0 0 1"/><limit lower="-6.3" upper="6.3" effort="1" velocity="1"/></joint>
  </xacro:macro>
  <xacro:arm_joint name="shoulder_pan_joint" parent="base_link_inertia" child="shoulder_link" key="shoulder"/>
  <xacro:arm_joint name="shoulder_lift_joint" parent="shoulder_link" child="upper_arm_link" key="upper_arm"/>
  <xacro:arm_joint name="elbow_joint" parent="upper_arm_link" child="forearm_link" key="forearm"/>
  <xacro:arm_joint name="wrist_1_joint" parent="forearm_link" child="wrist_1_link" key="wrist_1"/>
  <xacro:arm_joint name="wrist_2_joint" parent="wrist_1_link" child="wrist_2_link" key="wrist_2"/>
  <xacro:arm_joint name="wrist_3_joint" parent="wrist_2_link" child="wrist_3_link" key="wrist_3"/>
  <joint name="wrist_3-flange" type="fixed"><parent link="wrist_3_link"/><child link="flange"/>
    <origin xyz="0 0 0" rpy="0 ${{-pi/2.0}} ${{-pi/2.0}}"/></joint>
  <joint name="flange-tool0" type="fixed"><parent link="flange"/><child link="tool0"/>
    <origin xyz="0 0 0" rpy="${{pi/2.0}} 0 ${{pi/2.0}}"/></joint>
</robot>
"""


def test_exported_file_through_xacro_and_a_urdf_parser(tmp_path):
    """The file read by xacro's own YAML loader into the macro's joint layout, the URDF parsed by yourdfpy:
    base mount @ URDF(base_link -> tool0) @ tool remainder = kincal's forward kinematics."""
    xacro = pytest.importorskip("xacro")
    pytest.importorskip("yourdfpy")
    from kincal.io.urdf import from_urdf

    cal = _calibrated_ur10()
    kin = tmp_path / "my_robot_calibration.yaml"
    kin.write_text(ur_ros_text(cal, "model.yaml")[0])
    (tmp_path / "ur.xacro").write_text(XACRO.format(file=kin))
    urdf = tmp_path / "ur.urdf"
    urdf.write_text(xacro.process_file(str(tmp_path / "ur.xacro")).toxml())
    arm = from_urdf(urdf, "base_link", "tool0")
    doc = yaml.safe_load(kin.read_text())["kincal"]
    pose = lambda d: se3.make(rpy_to_matrix(d["rpy"]), np.array(d["xyz"]))  # noqa: E731
    q = np.random.default_rng(7).uniform(-np.pi, np.pi, (200, 6))
    got = pose(doc["world_to_base_link"]) @ forward_kinematics(arm, q) @ pose(doc["tool0_to_tool"])
    assert np.abs(got - forward_kinematics(cal, q)).max() < 1e-9
