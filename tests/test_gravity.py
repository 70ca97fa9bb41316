"""Joint compliance loaded by the arm's own weight (mass model and gravity, kincal.kinematics.gravity)."""

import numpy as np
import pytest
import yaml

from kincal.data import Dataset
from kincal.errors import DataFormatError, ModelError
from kincal.estimation import calibrate
from kincal.io.models import dump_robot, parse_robot
from kincal.kinematics import ArmModel, Robot, forward_kinematics, load_torques, loaded_chain, loaded_forward_kinematics
from kincal.kinematics.jacobians import torque_derivatives
from kincal.lie import se3, so3
from kincal.params import State, build_layout, retract
from kincal.robots import load
from kincal.simulate.generators import generate_markers
from kincal.simulate.noise import Noise
from kincal.simulate.perturb import perturb_robot
from kincal.testing import numerical_jacobian, random_pose
from test_piecewise_compliance import _noded
from test_residuals import _robot, check_residual

G = np.array([0.0, 0.0, -9.81])


def _planar(c=(0.0, 0.0), payload=0.0):
    """Two links in the x-y plane about z, l1 = 0.8, l2 = 0.5; centres of mass 0.3 and 0.2 along each link;
    gravity along -y (in the plane of motion)."""
    screws = np.array([[0, 0, 0, 0, 0, 1.0], [0, -0.8, 0, 0, 0, 1.0]])
    return ArmModel("planar", screws, se3.make(np.eye(3), [1.3, 0, 0]), compliance=c, link_masses=[4.0, 2.5],
                    link_coms=[[0.3, 0, 0], [1.0, 0, 0]], payload_mass=payload, gravity=[0, -9.81, 0])


def test_two_link_torques_equal_a_hand_computation_and_the_arm_sags():
    q = np.array([[0.3, -0.7], [0.0, 0.0], [-1.2, 2.0]])
    arm = _planar(payload=1.5)
    tau = load_torques(arm, q)
    g, c1, c12 = 9.81, np.cos(q[:, 0]), np.cos(q.sum(axis=1))
    tau2 = -g * (2.5 * 0.2 + 1.5 * 0.5) * c12
    tau1 = -g * (4.0 * 0.3 * c1 + 2.5 * (0.8 * c1 + 0.2 * c12) + 1.5 * (0.8 * c1 + 0.5 * c12))
    np.testing.assert_allclose(tau, np.stack([tau1, tau2], axis=1), atol=1e-12)
    soft = _planar(c=(1e-3, 2e-3), payload=1.5)  # theta = q + c tau: the rigid pose at the deflected angles
    np.testing.assert_allclose(loaded_forward_kinematics(soft, q), forward_kinematics(soft, q + [1e-3, 2e-3] * tau),
                               atol=1e-14)
    assert loaded_forward_kinematics(soft, [0.0, 0.0])[1, 3] < 0  # horizontal arm, gravity -y: the tool sags
    # no gravity vector or no mass: no load, the rigid pose
    for quiet in (soft.replace(gravity=None), soft.replace(link_masses=[0, 0], payload_mass=0.0)):
        assert not quiet.has_gravity_load
        np.testing.assert_array_equal(loaded_forward_kinematics(quiet, q), forward_kinematics(quiet, q))


def test_a_tool_wrench_adds_to_the_weights():
    rng = np.random.default_rng(0)
    arm = _planar(c=(1e-3, 2e-3), payload=1.5)
    q, w = rng.uniform(-2, 2, (4, 2)), rng.normal(size=(4, 6))
    both = load_torques(arm, q, w)
    np.testing.assert_allclose(both, load_torques(arm, q) + load_torques(arm.replace(gravity=None), q, w), atol=1e-12)


def _heavy(robot, rng, payload=True, arm="a"):
    a = robot[arm]
    a = a.replace(link_masses=rng.uniform(1, 10, a.dof), link_coms=rng.uniform(-0.5, 0.5, (a.dof, 3)),
                  payload_mass=3.0 if payload else 0.0, payload_com=rng.uniform(-0.1, 0.1, 3),
                  gravity=rng.normal(size=3) * 5)
    return Robot(robot.name, {**robot.arms, arm: a})


def _pose_case(rng, robot, wrench: bool, kind="pose"):
    q = rng.uniform(-2, 2, (5, robot["a"].dof))
    w = rng.normal(size=(5, 6)) if wrench else None
    T = loaded_forward_kinematics(robot["a"], q, w)
    W = random_pose(rng)
    if kind == "pose":
        measured = {"T_tracker_tool": se3.inverse(W) @ T}
        known = {"T_world_tracker": W}
    else:
        x = rng.uniform(-0.1, 0.1, (3, 3))
        measured = {"p_tracker_marker": se3.transform_points(se3.inverse(W), se3.transform_points(T[:, None], x))}
        known = {"T_world_tracker": W, "p_tool_marker": x}
    if wrench:
        measured["wrench_tool"] = w
    return Dataset(kind, "r", ("a",), {"a": q}, measured, known)


@pytest.mark.parametrize("kind, prismatic, payload, nodes, wrench", [
    ("pose", (), False, False, False), ("pose", (), True, False, False), ("markers", (2,), True, False, False),
    ("pose", (), True, True, False), ("markers", (2,), False, True, False), ("pose", (2,), True, False, True),
    ("markers", (), True, True, True), ("pose", (), False, True, True)])
def test_jacobians_with_weights_match_differences(rng, kind, prismatic, payload, nodes, wrench):
    """Every block (base included: it turns the arm relative to gravity) and the joint readings, with and
    without a payload, angle-dependent compliance and a tool load on top; large deflections (0.1 rad)."""
    robot = _robot(rng, prismatic, compliance=0.002)
    robot = _heavy(_noded(robot) if nodes else robot, rng, payload)
    check_residual(rng, robot, _pose_case(rng, robot, wrench, kind))


@pytest.mark.parametrize("payload", [False, True])
def test_torque_derivatives_match_differences(rng, payload):
    """d tau / d p per part of the unloaded chain, directly (offsets, twists, home, base, tool)."""
    robot = _heavy(_robot(rng, (3,), compliance=0.002), rng, payload)
    state = State.from_robot(robot)
    parts = ("offsets", "twists", "home", "base", "tool")
    layout = build_layout(state, [f"a.{p}" for p in parts])
    q, w = rng.uniform(-2, 2, (4, 6)), rng.normal(size=(4, 6))

    def tau(d):
        a = retract(state, layout, d).arms["a"]
        return loaded_chain(a.screws, q + a.offsets, a.base, a.home, a.tool, 0.0, w, a.weights).tau

    a = state.arms["a"]
    kin = loaded_chain(a.screws, q + a.offsets, a.base, a.home, a.tool, 0.0, w, a.weights)
    D = torque_derivatives(kin, a.generators, parts)
    num = numerical_jacobian(tau, np.zeros(layout.size))
    for b in layout.blocks:
        if b.arm == "a" and b.part in parts:
            np.testing.assert_allclose(D[b.part], num[:, :, b.start: b.stop], atol=1e-7, rtol=1e-6, err_msg=b.name)
    assert np.abs(D["base"]).max() > 1.0  # the base turns the arm relative to gravity


UR10_MASSES = [7.1, 12.7, 4.27, 2.0, 2.0, 0.365]
TILT = se3.make(so3.exp(np.array([0.5, 0.0, 0.0])), [0.0, 0.0, 0.3])  # a pedestal tilted by 0.5 rad


def _ur10_with_weights(base=np.eye(4)):
    """UR10 with its published link masses; centres of mass on the links at q = 0 (arm base frame; rough); a
    5 kg payload off the j6 axis."""
    ur = load("ur10")["arm"]
    coms = [[0, 0, 0.128], [-0.306, 0, 0.175], [-0.886, 0, 0.05], [-1.18, -0.16, 0.06], [-1.18, -0.17, 0.0],
            [-1.18, -0.25, 0.0]]
    return ur.replace(link_masses=UR10_MASSES, link_coms=coms, payload_mass=5.0, payload_com=[0.1, 0, 0.05],
                      gravity=G, base=base)


@pytest.fixture(scope="module")
def sagging():
    """On a tilted pedestal every joint's weight torque varies with the configuration (a vertical first axis
    carries none: docs/calibration.md)."""
    nominal = Robot("ur10", {"arm": _ur10_with_weights(TILT)})
    true = perturb_robot(nominal, "fine", 5)
    c = np.array([3e-6, 2e-6, 4e-6, 8e-6, 1e-5, 1.5e-5])
    return nominal, Robot("ur10", {"arm": true["arm"].replace(compliance=c)})


@pytest.mark.parametrize("seed", [1, pytest.param(2, marks=pytest.mark.slow), pytest.param(3, marks=pytest.mark.slow)])
def test_a_sagging_arm_calibrates_its_compliances_from_its_own_weight(sagging, seed):
    """No tool load: the weights alone deflect the joints. 3 known markers, a tracker whose pose in the world
    (where gravity is stated) is known, 0.02 mm noise, nominal model without compliance: every compliance comes
    back within 3 reported std, and fresh configurations are predicted better than by a rigid calibration.
    (With the tracker's pose unknown too, the arm's tilt relative to gravity is seen only through the sag:
    docs/calibration.md.)"""
    nominal, true = sagging
    ds, _, val = generate_markers(true, n=60, rng=seed, markers=3, noise=Noise(position=2e-5), n_validation=50,
                                  known_tracker=True, known_markers=True)
    assert "wrench_tool" not in ds.measured
    res = calibrate(nominal, [ds], ["kinematic", "elastic"], validation=list(val.values()))
    rigid = calibrate(nominal, [ds], ["kinematic"], validation=list(val.values()))
    assert res.status == "converged"
    truth = true["arm"].compliance
    for j, name in enumerate(nominal["arm"].joint_names):
        e = res.estimate(f"arm.{name}.compliance")
        assert e.identifiable and abs(e.value - truth[j]) < 3 * e.std, (name, e.value, truth[j], e.std)
        if j < 3:  # the wrists' weight torques are a few N m: their compliances are seen, less sharply
            assert e.std < 0.1 * truth[j]
    after, before = res.validation[0].after, rigid.validation[0].after
    assert after.position_rms < 0.3 * before.position_rms
    assert after.position_rms < 5e-5


def test_model_file_round_trip_and_bad_mass_values():
    robot = Robot("ur10", {"arm": _ur10_with_weights()})
    text = dump_robot(robot)
    back = parse_robot(text, "m.yaml")
    assert back == robot and back["arm"].has_gravity_load
    assert back != Robot("ur10", {"arm": robot["arm"].replace(gravity=None)})
    data = yaml.safe_load(text)
    data["units"]["length"] = "mm"  # centres of mass in the file's length unit; masses kg, gravity m/s^2
    for j in data["arms"]["arm"]["joints"]:
        j["com"] = [1000 * x for x in j["com"]]
        j["twist"] = j["twist"][:3] + j["twist"][3:]
        j["twist"][:3] = [1000 * x for x in j["twist"][:3]]
    for key in ("base", "home", "tool"):
        for r in data["arms"]["arm"][key]["matrix"][:3]:
            r[3] *= 1000
    data["arms"]["arm"]["payload"]["com"] = [0, 0, 50.0]
    mm = parse_robot(yaml.safe_dump(data), "m.yaml")["arm"]
    np.testing.assert_allclose(mm.link_coms, robot["arm"].link_coms, atol=1e-12)
    np.testing.assert_allclose(mm.payload_com, [0, 0, 0.05], atol=1e-15)

    def bad(edit, message):
        d = yaml.safe_load(text)
        edit(d["arms"]["arm"])
        with pytest.raises(DataFormatError, match=message):
            parse_robot(yaml.safe_dump(d), "m.yaml")

    bad(lambda a: a["joints"][1].update(mass=-1.0), r"m.yaml: arms.arm.joints\[1\].mass: expected a mass >= 0 kg")
    bad(lambda a: a["joints"][1].pop("com"), r"arms.arm.joints\[1\]: give a link's 'mass' \(kg\) and 'com'")
    bad(lambda a: a.update(gravity=[0, -9.81]), r"arms.arm.gravity: expected a list of 3 numbers")
    bad(lambda a: a.update(payload={"mass": 1.0}), r"arms.arm.payload: missing key 'com'")
    with pytest.raises(ModelError, match="masses must be >= 0 kg"):
        robot["arm"].replace(payload_mass=-1.0)
    with pytest.raises(ModelError, match=r"link_coms must be finite with shape \(6, 3\)"):
        robot["arm"].replace(link_coms=np.zeros((5, 3)))


URDF = """<robot name="two">
  <link name="base_link"><inertial><mass value="50"/><origin xyz="0 0 0"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <link name="l1"><inertial><mass value="2"/><origin xyz="0 0 0.2"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <link name="l1b"><inertial><mass value="1"/><origin xyz="0.1 0 0"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <link name="l2"><inertial><mass value="3"/><origin xyz="0.1 0 0"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <link name="tip"><inertial><mass value="0.5"/><origin xyz="0 0 0.05"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="base_link"/><child link="l1"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="0" velocity="0"/></joint>
  <joint name="f1" type="fixed"><parent link="l1"/><child link="l1b"/><origin xyz="0 0 0.4"/></joint>
  <joint name="j2" type="revolute"><parent link="l1b"/><child link="l2"/><origin xyz="0.3 0 0" rpy="0 0 1.5707963267948966"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="0" velocity="0"/></joint>
  <joint name="f2" type="fixed"><parent link="l2"/><child link="tip"/><origin xyz="0 0.2 0"/></joint>
</robot>"""


def test_urdf_inertials_are_lumped_per_joint_in_the_arm_base_frame():
    pytest.importorskip("yourdfpy")
    from kincal.io.urdf import from_urdf

    arm = from_urdf(URDF, "base_link", "tip", gravity=G)
    # j1 carries l1 (2 kg at z 0.3) and l1b fixed to it (1 kg at (0.1, 0, 0.5)); j2 carries l2 (3 kg; its
    # frame at (0.3, 0, 0.5) turned 90 deg about z: x -> y, y -> -x) and tip (0.5 kg at (0.1, 0, 0.55))
    np.testing.assert_allclose(arm.link_masses, [3.0, 3.5])
    c1 = (2 * np.array([0, 0, 0.3]) + np.array([0.1, 0, 0.5])) / 3
    c2 = (3 * np.array([0.3, 0.1, 0.5]) + 0.5 * np.array([0.1, 0, 0.55])) / 3.5
    np.testing.assert_allclose(arm.link_coms, [c1, c2], atol=1e-12)
    assert arm.has_gravity_load and arm.payload_mass == 0.0  # base_link's own mass does not load the joints
    assert not from_urdf(URDF, "base_link", "tip", inertials=False).link_masses.any()
    assert not from_urdf(URDF, "base_link", "tip").has_gravity_load  # URDF has no gravity vector
    with pytest.raises(DataFormatError, match=r"<urdf string>: link 'l2': inertial mass must be >= 0 kg, found -3"):
        from_urdf(URDF.replace('<mass value="3"/>', '<mass value="-3"/>'), "base_link", "tip")
