"""A joint compliance that depends on the joint's own angle (seed 001 Sec. V: chi_21..chi_25 of a KR-270's
joint 2): interpolation, parameter names, the Jacobian against differences, model files and their errors."""

import numpy as np
import pytest
import yaml

from kincal.data import Dataset
from kincal.errors import DataFormatError, ModelError
from kincal.estimation import calibrate
from kincal.io.models import dump_robot, parse_robot
from kincal.kinematics import Robot, loaded_forward_kinematics
from kincal.kinematics.elastic import compliance_basis, joint_compliance
from kincal.noise import Noise
from kincal.params import State, build_layout
from kincal.robots import load
from test_residuals import LOADED, _case, _robot, check_residual

NODES = np.array([[-1.5, 0.02], [-0.3, 0.05], [0.4, 0.01], [1.6, 0.03]])  # (angle rad, rad/(N m))


def _noded(robot, joint="j2", table=NODES):
    a = robot["a"]
    c = np.array(a.compliance)
    c[a.joint_names.index(joint)] = 0.0
    return Robot(robot.name, {**robot.arms, "a": a.replace(compliance=c, compliance_nodes={joint: table})})


def test_compliance_interpolates_linearly_between_nodes_and_holds_beyond():
    x, k = NODES[:, 0], NODES[:, 1]
    q = np.array([-2.0, -1.5, -0.9, -0.3, 0.0, 0.4, 1.0, 1.6, 3.0])
    W, S = compliance_basis((x,), q[:, None])
    np.testing.assert_allclose(W.sum(axis=-1), 1.0)
    np.testing.assert_allclose((W @ k)[:, 0], np.interp(q, x, k), atol=1e-15)
    h = 1e-7  # S is dW/dq inside the nodes' span, zero beyond
    num = (compliance_basis((x,), q[:, None] + h)[0] - compliance_basis((x,), q[:, None] - h)[0]) / (2 * h)
    inside = (q > x[0]) & (q < x[-1]) & ~np.isin(q, x)
    np.testing.assert_allclose(S[inside], num[inside], atol=1e-6)
    assert not S[~((q > x[0]) & (q < x[-1]))].any()


@pytest.mark.parametrize("kind", LOADED)
@pytest.mark.parametrize("prismatic", [(), (2,)])
def test_jacobian_with_angle_dependent_compliance_matches_differences(rng, kind, prismatic):
    """The coefficients' block, the load torques' dependence on every block, and the joint readings (which
    move their own compliance along the table) against central differences."""
    robot = _noded(_robot(rng, prismatic, compliance=0.02), joint="j2")
    ds = _case(kind, rng, robot)
    check_residual(rng, robot, ds)


def test_parameter_names_and_a_model_without_nodes_unchanged(rng):
    plain = _robot(rng, compliance=0.02)
    names = build_layout(State.from_robot(plain), ["a.compliance"]).free_names
    assert names == [f"a.j{i}.compliance" for i in range(1, 7)]
    noded = _noded(plain, table=np.array([[-np.pi / 3, 1.0], [-0.0001, 2.0], [np.radians(25.24), 3.0]]))
    names = build_layout(State.from_robot(noded), ["a.compliance"]).free_names
    assert names == ["a.j1.compliance", "a.j2.compliance@-60deg", "a.j2.compliance@0deg", "a.j2.compliance@25deg",
                     *[f"a.j{i}.compliance" for i in range(3, 7)]]
    # a model state round-trips through the coefficients
    back = State.from_robot(noded).to_robot(noded)["a"]
    assert np.array_equal(back.compliance, noded["a"].compliance)
    assert back.compliance_nodes.keys() == {"j2"}
    assert np.array_equal(back.compliance_nodes["j2"], noded["a"].compliance_nodes["j2"])


def test_calibration_recovers_node_values_from_loaded_and_unloaded_markers(rng):
    """Each configuration measured without and with a load (same readings), as in the paper's experiment."""
    robot = _noded(_robot(rng, compliance=2e-3))
    a = robot["a"]
    q = rng.uniform(-2, 2, (40, 6))
    w = np.concatenate([rng.normal(scale=20, size=(40, 3)), rng.normal(scale=2, size=(40, 3))], axis=1)
    qq, ww = np.concatenate([q, q]), np.concatenate([np.zeros_like(w), w])
    x = rng.uniform(-0.1, 0.1, (3, 3))
    T = loaded_forward_kinematics(a, qq, ww)
    y = np.einsum("nij,mj->nmi", T[:, :3, :3], x) + T[:, None, :3, 3] + rng.normal(scale=1e-6, size=(80, 3, 3))
    ds = Dataset("markers", "r", ("a",), {"a": qq}, {"p_tracker_marker": y, "wrench_tool": ww}, {}, "loaded")
    start = Robot("r", {"a": a.replace(compliance_nodes={"j2": NODES * [1, 0] + [0, 0.03]},
                                       compliance=np.where(np.arange(6) == 1, 0, 0.01))})
    res = calibrate(start, [ds], free="elastic", noise=Noise(position=1e-6))
    for (angle, c) in NODES:
        e = res.estimate(f"a.j2.compliance@{np.degrees(angle):.0f}deg")
        assert abs(e.value - c) < 4 * e.std, (e.name, e.value, c, e.std)
    np.testing.assert_allclose(joint_compliance(res.robot["a"], q), joint_compliance(a, q), rtol=0.05)


def _text(table=None, joint=1, unit="deg"):
    data = yaml.safe_load(dump_robot(load("ur10")))
    data["units"]["angle"] = unit
    for i, j in enumerate(data["arms"]["arm"]["joints"]):
        j["limits"] = [-180, 180] if unit == "deg" else [-3, 3]
        j["name"] = f"j{i + 1}"
    if table is not None:
        data["arms"]["arm"]["joints"][joint]["compliance"] = table
    return yaml.safe_dump(data)


def test_model_file_round_trip_in_degrees():
    text = _text({"nodes": [-140, -99.85, -56.9, -25.24, -0.01], "values": [0.1, 0.2, 0.3, 0.4, 0.5]})
    robot = parse_robot(text, "kr.yaml")
    t = robot["arm"].compliance_nodes["j2"]
    np.testing.assert_allclose(t[:, 0], np.radians([-140, -99.85, -56.9, -25.24, -0.01]))
    np.testing.assert_allclose(t[:, 1], np.radians([0.1, 0.2, 0.3, 0.4, 0.5]))
    assert robot["arm"].compliance[1] == 0
    back = parse_robot(dump_robot(robot), "again.yaml")
    assert back == robot
    assert back != parse_robot(_text(0.0), "rigid.yaml")


@pytest.mark.parametrize("table, joint, message", [
    ({"nodes": [-10, -20, 0], "values": [1, 2, 3]}, 1,
     r"kr.yaml: arms.arm.joints\[1\].compliance.nodes\[1\]: expected node angles increasing strictly, found -20 after -10"),
    ({"nodes": [-10, 200], "values": [1, 2]}, 1,
     r"kr.yaml: arms.arm.joints\[1\].compliance.nodes\[1\]: expected a node within the joint limits \[-180, 180\], found 200"),
    ({"nodes": [-10, 20], "values": [1]}, 1,
     r"kr.yaml: arms.arm.joints\[1\].compliance.values: expected 2 compliances \(one per node\), found \[1\]"),
    ({"nodes": [-10, 20], "values": [1, -2]}, 1,
     r"kr.yaml: arms.arm.joints\[1\].compliance.values\[1\]: expected a compliance >= 0"),
    ({"nodes": [5], "values": [1]}, 1, r"kr.yaml: arms.arm.joints\[1\].compliance.nodes: expected a list of at least 2"),
    ({"nodes": [5, 6], "value": [1, 2]}, 1, r"kr.yaml: arms.arm.joints\[1\].compliance.value: unknown key 'value'"),
    ({"nodes": [5, 5.2], "values": [1, 2]}, 1, r"kr.yaml: arms.arm: .*keep them at least 1 deg apart"),
])
def test_bad_compliance_nodes_are_one_line_errors(table, joint, message):
    with pytest.raises(DataFormatError, match=message) as info:
        parse_robot(_text(table, joint), "kr.yaml")
    assert "\n" not in str(info.value)


def test_compliance_nodes_on_a_joint_that_cannot_have_them():
    data = yaml.safe_load(_text(None))
    j = data["arms"]["arm"]["joints"][2]
    j.pop("twist")
    j.update(type="prismatic", axis=[0, 0, 1], limits=[0, 1], compliance={"nodes": [0, 0.5], "values": [1, 2]})
    with pytest.raises(DataFormatError, match=r"kr.yaml: arms.arm.joints\[2\].compliance: compliance nodes .* need a "
                                              r"revolute joint"):
        parse_robot(yaml.safe_dump(data), "kr.yaml")
    arm = load("ur10")["arm"]
    with pytest.raises(ModelError, match="joint j9: compliance nodes: no such joint"):
        arm.replace(compliance_nodes={"j9": NODES})
    with pytest.raises(ModelError, match="joint elbow: compliance nodes: the joint also has a constant compliance"):
        arm.replace(compliance=[0, 0, 1e-6, 0, 0, 0], compliance_nodes={"elbow": NODES})
