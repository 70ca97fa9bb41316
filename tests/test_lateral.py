"""Lateral compliance (kincal.kinematics.lateral): kinematics, model file, Jacobians against finite differences."""

import numpy as np
import pytest
import yaml

from kincal.kinematics import Robot, loaded_forward_kinematics
from kincal.kinematics.lateral import lateral_axes
from kincal.params import LATERAL, State, build_layout, retract
from kincal.kinematics.branches import tree_loaded_kinematics
from kincal.kinematics.tree import tip_model
from kincal.errors import DataFormatError, ModelError
from kincal.estimation import calibrate
from kincal.io.models import dump_robot, parse_robot
from kincal.simulate.generators import generate_markers
from kincal.simulate.noise import Noise
from test_gravity import TILT, UR10_MASSES, _heavy, _pose_case, _ur10_with_weights
from test_tree_gravity import _case as _tree_case
from test_tree_gravity import check_gravity_tree, gravity_tree
from test_piecewise_compliance import _noded
from test_residuals import _robot, check_residual


def _lateral(robot, rng, arm="a", scale=0.002):
    a = robot[arm]
    return Robot(robot.name, {**robot.arms, arm: a.replace(lateral=rng.uniform(0, scale, (a.dof, 2)))},
                 dict(robot.meta), dict(robot.mounts))


def test_lateral_axes_are_normal_to_the_joint_through_its_axis():
    screws = np.array([[0, 0, 0, 0, 0, 1], [0, 0, 0.3, 0, 1, 0], [-0.2, 0.5, 0, 1, 0, 0]], float)
    screws[1, :3] = -np.cross([0, 1, 0], [0.1, 0, 0.4])
    eta = lateral_axes(screws)
    for xi, (ex, ey) in zip(screws, eta):
        w, p = xi[3:], np.cross(xi[3:], xi[:3])
        x, y = ex[3:], ey[3:]
        np.testing.assert_allclose([x @ w, y @ w, x @ y], 0, atol=1e-15)
        np.testing.assert_allclose(np.cross(x, y), w, atol=1e-15)
        np.testing.assert_allclose([ex[:3], ey[:3]], [np.cross(p, x), np.cross(p, y)], atol=1e-15)
    np.testing.assert_allclose(eta[0, :, 3:], [[1, 0, 0], [0, 1, 0]])  # a z joint bends about base x and y


def test_lateral_compliance_bends_the_arm_and_zero_changes_nothing(rng):
    robot = _heavy(_robot(rng, compliance=0.002), rng)
    q = rng.uniform(-2, 2, (4, 6))
    T = loaded_forward_kinematics(robot["a"], q)
    zero = robot["a"].replace(lateral=np.zeros((6, 2)))
    np.testing.assert_allclose(loaded_forward_kinematics(zero, q), T, atol=1e-14)
    bent = _lateral(robot, rng)["a"]
    assert np.abs(loaded_forward_kinematics(bent, q)[:, :3, 3] - T[:, :3, 3]).max() > 1e-3


def test_the_parameter_kind_names_two_per_joint_and_only_on_arms_that_declare_it(rng):
    robot = _lateral(_heavy(_robot(rng, compliance=0.002), rng), rng)
    layout = build_layout(State.from_robot(robot), ["kinematic", "elastic", "lateral"])
    names = [layout.names[i] for i in np.flatnonzero(layout.free) if "lateral" in layout.names[i]]
    assert names == [f"a.j{j}.lateral_{c}" for j in range(1, 7) for c in "xy"]
    assert [b.name for b in layout.blocks if b.kind is LATERAL] == ["a.lateral"]
    plain = build_layout(State.from_robot(robot), ["kinematic", "elastic"])
    assert not any("lateral" in n for n in plain.free_names)


@pytest.mark.parametrize("kind, payload, nodes, wrench", [
    ("pose", False, False, False), ("markers", True, False, False), ("pose", True, True, False),
    ("markers", True, True, True), ("pose", False, False, True)])
def test_jacobians_with_lateral_compliance_match_differences(rng, kind, payload, nodes, wrench):
    """Every block (lateral included, twists moving the lateral axes along) and the readings."""
    robot = _robot(rng, compliance=0.002)
    robot = _lateral(_heavy(_noded(robot) if nodes else robot, rng, payload), rng)
    check_residual(rng, robot, _pose_case(rng, robot, wrench, kind))


def test_twist_steps_carry_the_lateral_axes_rigidly(rng):
    """After a twist step the lateral axes stay normal to their joint's axis and meet it (reciprocal product 0)."""
    robot = _lateral(_heavy(_robot(rng, compliance=0.002), rng), rng)
    state = State.from_robot(robot)
    layout = build_layout(state, ["a.twists"])
    a = retract(state, layout, rng.normal(scale=0.1, size=layout.size)).arms["a"]
    assert np.abs(a.screws - robot["a"].screws).max() > 1e-2
    for xi, eta in zip(a.screws, a.lateral_axes):
        w = xi[3:]
        np.testing.assert_allclose([eta[0, 3:] @ w, eta[1, 3:] @ w, eta[0, 3:] @ eta[1, 3:]], 0, atol=1e-12)
        np.testing.assert_allclose(eta[:, 3:] @ xi[:3] + eta[:, :3] @ w, 0, atol=1e-12)


@pytest.mark.parametrize("kind, arm, coupled", [("pose", "b", False), ("markers", "b", True),
                                                 ("markers", "torso", False)])
def test_jacobians_of_a_tree_with_lateral_compliance_match_differences(rng, kind, arm, coupled):
    """Torso and both arms bend laterally: the composite chain carries the torso's lateral axes (mapped like its
    screws), the other arm's weight loads them; every block and every arm's readings against differences."""
    robot = gravity_tree(rng, compliance=0.001, coupled=coupled)  # differences of deflections of 0.1 rad lose digits
    for a in robot.arms:
        robot = _lateral(robot, rng, a, 0.001)
    check_gravity_tree(rng, robot, _tree_case(kind, rng, robot, arm=arm))


def test_a_tree_and_its_serial_tip_model_bend_alike(rng):
    """The tip's composite with lateral compliance equals the same robot written as one serial chain."""
    robot = gravity_tree(rng)
    robot = Robot(robot.name, {k: robot[k] for k in ("torso", "b")}, mounts={"b": "torso"})
    for a in robot.arms:
        robot = _lateral(robot, rng, a, 0.003)
    q = {a: rng.uniform(-2, 2, (4, m.dof)) for a, m in robot.arms.items()}
    T = tree_loaded_kinematics(robot, "b", q).tool
    tip = tip_model(robot, "b")
    np.testing.assert_allclose(tip.lateral, np.concatenate([robot["torso"].lateral, robot["b"].lateral]))
    np.testing.assert_allclose(loaded_forward_kinematics(tip, np.concatenate([q["torso"], q["b"]], axis=1)), T,
                               atol=1e-12)


@pytest.fixture(scope="module")
def bending():
    """UR10 on a tilted pedestal with its link masses, no payload and a massless last link (nothing loads joint
    6: its compliances cannot be seen); true joint and lateral compliances."""
    arm = _ur10_with_weights(TILT).replace(payload_mass=0.0, link_masses=[*UR10_MASSES[:5], 0.0])
    nominal = Robot("ur10", {"arm": arm.replace(lateral=np.zeros((6, 2)))})
    rng = np.random.default_rng(7)
    c = np.array([3e-6, 2e-6, 4e-6, 8e-6, 1e-5, 1.5e-5])
    true = nominal["arm"].replace(offsets=rng.uniform(-2e-3, 2e-3, 6), compliance=c,
                                  lateral=rng.uniform(2e-6, 6e-6, (6, 2)))
    return nominal, Robot("ur10", {"arm": true})


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_sagging_arm_calibrates_its_lateral_compliances_from_its_own_weight(bending, seed):
    """No tool load; 3 known markers, a tracker of known pose, 0.02 mm noise: at offsets + elastic + lateral
    every loaded joint and lateral compliance comes back within 3 reported std, fresh configurations are predicted
    at the noise level (a joint-compliance model cannot: the lateral bending is not in it), and joint 6's
    compliances, which nothing loads, are named unidentifiable, not invented."""
    nominal, true = bending
    ds, _, val = generate_markers(true, n=80, rng=seed, markers=3, noise=Noise(position=2e-5), n_validation=50,
                                  known_tracker=True, known_markers=True)
    res = calibrate(nominal, [ds], ["offsets", "elastic", "lateral"], validation=list(val.values()))
    joint = calibrate(nominal, [ds], ["offsets", "elastic"], validation=list(val.values()))
    assert res.status == "converged"
    a = true["arm"]
    truth = {**{f"arm.{j}.compliance": a.compliance[i] for i, j in enumerate(a.joint_names)},
             **{f"arm.{j}.lateral_{c}": a.lateral[i, k] for i, j in enumerate(a.joint_names)
                for k, c in enumerate("xy")}}
    for name, value in truth.items():
        e = res.estimate(name)
        if name.startswith(f"arm.{a.joint_names[5]}."):
            assert not e.identifiable, name
            continue
        assert e.identifiable and abs(e.value - value) < 3 * e.std, (name, e.value, value, e.std)
    after = res.validation[0].after
    assert after.position_rms < 5e-5
    assert after.position_rms < 0.5 * joint.validation[0].after.position_rms
    model = res.robot["arm"]  # the returned model is the solver's: it predicts what the fit saw
    np.testing.assert_allclose(model.lateral.ravel()[:10], [res.estimate(n).value for n in list(truth)[6:16]])


def test_model_file_declares_lateral_compliance_and_round_trips(bending):
    """``lateral: [x, y]`` per joint (angle unit/(N m)); ``save_robot`` writes the axes too (calibrated twists carry
    them), so a calibrated model loads back as it was; bad values get one line naming file and field."""
    _, true = bending
    text = dump_robot(true)
    assert parse_robot(text, "m.yaml") == true
    data = yaml.safe_load(text)
    data["units"]["angle"] = "deg"
    for j in data["arms"]["arm"]["joints"]:
        j.pop("lateral_axes")
        j["lateral"] = [float(np.degrees(x)) for x in j["lateral"]]
        j.pop("offset", None)
        j.pop("limits", None)
        j["compliance"] = float(np.degrees(j["compliance"]))
    data["arms"]["arm"]["joints"][2].pop("lateral")  # a joint without: zero lateral compliance
    arm = parse_robot(yaml.safe_dump(data), "m.yaml")["arm"]
    np.testing.assert_allclose(arm.lateral[[0, 1, 3, 4, 5]], true["arm"].lateral[[0, 1, 3, 4, 5]], rtol=1e-12)
    np.testing.assert_allclose(arm.lateral[2], 0.0)
    np.testing.assert_allclose(arm.lateral_axes, lateral_axes(arm.screws))
    assert "lateral" not in yaml.safe_load(dump_robot(Robot("r", {"arm": true["arm"].replace(
        lateral=None, lateral_axes=None)})))["arms"]["arm"]["joints"][0]

    def bad(edit, message):
        d = yaml.safe_load(text)
        edit(d["arms"]["arm"]["joints"])
        with pytest.raises(DataFormatError, match=message):
            parse_robot(yaml.safe_dump(d), "m.yaml")

    bad(lambda js: js[1].update(lateral=[-1e-6, 0.0]),
        r"^m.yaml: arms.arm.joints\[1\].lateral: expected two lateral compliances >= 0")
    bad(lambda js: js[1].update(lateral=[1e-6]), r"arms.arm.joints\[1\].lateral: expected a list of 2 numbers")
    bad(lambda js: js[1].pop("lateral"), r"arms.arm.joints\[1\].lateral_axes: 'lateral_axes' goes with 'lateral'")
    bad(lambda js: js[1].update(lateral_axes=[[0, 0, 0, 1, 0, 0]]), r"joints\[1\].lateral_axes: expected two twists")
    with pytest.raises(ModelError, match="lateral must be finite with shape"):
        true["arm"].replace(lateral=np.zeros(6))


def test_a_negative_lateral_compliance_is_reported_and_kept(bending):
    """An estimate below 0 stays in the returned model (which then equals the solver's fit) and is reported."""
    nominal, true = bending
    lat = true["arm"].lateral.copy()
    lat[1, 0] = -2e-5
    true = Robot("ur10", {"arm": true["arm"].replace(lateral=lat, allow_negative_compliance=True)})
    ds, _, _ = generate_markers(true, n=80, rng=4, markers=3, noise=Noise(position=2e-5), known_tracker=True,
                                known_markers=True)
    res = calibrate(nominal, [ds], ["offsets", "elastic", "lateral"])
    name = f"arm.{nominal['arm'].joint_names[1]}.lateral_x"
    assert [c.name for c in res.negative_compliances if c.significant] == [name]
    arm = res.robot["arm"]
    assert arm.allow_negative_compliance and arm.lateral[1, 0] == res.estimate(name).value < 0
    q = ds.q["arm"]
    T = loaded_forward_kinematics(arm, q)
    np.testing.assert_allclose(T[:, :3, 3], loaded_forward_kinematics(true["arm"], q)[:, :3, 3], atol=2e-4)
