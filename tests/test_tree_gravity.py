"""Gravity on tree-structured robots: the torso carries both arms' weights, each arm its own; exact Jacobians
w.r.t. every segment's blocks, the other branch's included, and every arm's readings."""

import numpy as np
import pytest

from kincal import experiments
from kincal.data import Dataset
from kincal.errors import DataFormatError, ModelError
from kincal.io.datasets import load_dataset, write_dataset
from kincal.kinematics import ArmModel, Robot
from kincal.kinematics.branches import tree_loaded_kinematics
from kincal.kinematics.couplings import derive_readings
from kincal.lie import se3
from kincal.params import State, build_layout, retract
from kincal.testing import numerical_jacobian, random_arm, random_pose
from test_tree import _assemble

G = np.array([0.3, -0.5, -9.8])


def _heavy(rng, arm: ArmModel, payload: bool, gravity=None) -> ArmModel:
    return arm.replace(link_masses=rng.uniform(1, 10, arm.dof), link_coms=rng.uniform(-0.5, 0.5, (arm.dof, 3)),
                       payload_mass=2.0 if payload else 0.0, payload_com=rng.uniform(-0.1, 0.1, 3), gravity=gravity)


def gravity_tree(rng, compliance=0.003, coupled=False):
    """A 3-joint torso (j3 = -j1 - j2 when ``coupled``) carrying arms ``a`` (6 joints) and ``b`` (7, one
    prismatic), all with masses and compliances; gravity stated on the torso only (the tree's)."""
    torso = random_arm(rng, 3, name="torso")
    if coupled:
        torso = torso.replace(couplings={"j3": {"j1": -1.0, "j2": -1.0}})
    arms = {"torso": _heavy(rng, torso, False, G), "a": _heavy(rng, random_arm(rng, 6, name="a"), True),
            "b": _heavy(rng, random_arm(rng, 7, prismatic=(3,), name="b"), True)}
    arms = {k: m.replace(compliance=rng.uniform(0.2, 1.0, m.dof) * compliance) for k, m in arms.items()}
    return Robot("tree", arms, mounts={"a": "torso", "b": "torso"})


def _readings(rng, robot, n):
    return {a: derive_readings(m.couplings, m.joint_names, rng.uniform(-2, 2, (n, m.dof)))
            for a, m in robot.arms.items()}


def _case(kind, rng, robot, n=5, arm="b"):
    q = _readings(rng, robot, n)
    T = tree_loaded_kinematics(robot, arm, q).tool
    W = random_pose(rng)
    if kind == "pose":
        return Dataset("pose", "tree", (arm,), q, {"T_tracker_tool": se3.inverse(W) @ T}, {"T_world_tracker": W})
    x = rng.uniform(-0.1, 0.1, (3, 3))
    y = se3.transform_points(se3.inverse(W), se3.transform_points(T[:, None], x))
    return Dataset("markers", "tree", (arm,), q, {"p_tracker_marker": y}, {"T_world_tracker": W, "p_tool_marker": x})


def check_gravity_tree(rng, robot, ds):
    """Zero at the truth; away from it, every block of the torso, of both arms (the other arm's through the
    torso's deflection) and the frames, and every arm's readings, equal central differences."""
    state = State.from_robot(robot)
    exps, extras, unknown = experiments.build([ds], state)
    state = State(state.arms, extras, experiments.frame_kinds(exps), robot.mounts)
    exp = exps[0]
    np.testing.assert_allclose(exp.residual(state).r, 0.0, atol=1e-10)
    arms = ["torso", "a", "b"]
    layout = build_layout(state, [f"{a}.*" for a in arms] + list(extras), arms=arms)
    state = retract(state, layout, rng.normal(scale=0.05, size=layout.size))
    n = 3
    q = _readings(rng, robot, n)
    measured = {k: np.repeat(v[:1], n, axis=0) for k, v in ds.measured.items()}
    make = lambda qq: type(exp)(Dataset(ds.kind, "tree", ds.arms, qq, measured, dict(ds.known)), exp.frames)  # noqa
    res = make(q).residual(state)
    num = numerical_jacobian(lambda d: make(q).residual(retract(state, layout, d)).r, np.zeros(layout.size), order=4)
    J = _assemble(res, layout, n)
    np.testing.assert_allclose(J, num, atol=1e-7, rtol=1e-6)
    a_cols = [i for b in layout.blocks if b.name.startswith("a.") for i in range(b.start, b.stop)]
    assert np.abs(num[..., a_cols]).max() > 1e-5  # the other arm's geometry matters (through the torso)
    assert set(res.jq) == set(arms)
    for arm in arms:
        m = robot[arm]

        def f(x, arm=arm, m=m):
            return make({**q, arm: derive_readings(m.couplings, m.joint_names, x.reshape(q[arm].shape))}).residual(
                state).r
        num_q = numerical_jacobian(f, q[arm].ravel(), order=4).reshape(res.r.shape + q[arm].shape)
        num_q = np.stack([num_q[i, :, i, :] for i in range(n)])
        np.testing.assert_allclose(res.jq[arm], num_q, atol=1e-7, rtol=1e-6)


@pytest.mark.parametrize("kind, coupled", [("pose", False), ("markers", False), ("pose", True), ("markers", True)])
def test_jacobians_of_a_sagging_tree_match_differences(rng, kind, coupled):
    robot = gravity_tree(rng, coupled=coupled)
    check_gravity_tree(rng, robot, _case(kind, rng, robot))


def test_jacobians_of_the_torso_carrying_both_arms_match_differences(rng):
    """Markers on the torso itself: both arms hang on its tool (their weights move with its home and tool)."""
    robot = gravity_tree(rng)
    check_gravity_tree(rng, robot, _case("markers", rng, robot, arm="torso"))


def _line_arm(name, x_com, mass, base=np.eye(4), payload=0.0, gravity=None):
    """One revolute joint about y through the origin; its link's centre of mass at (x_com, 0, 0)."""
    return ArmModel(name, np.array([[0, 0, 0, 0, 1.0, 0]]), np.eye(4), base=base, link_masses=[mass],
                    link_coms=[[x_com, 0, 0]], payload_mass=payload, payload_com=np.zeros(3), gravity=gravity)


def test_the_torso_carries_both_arms_each_arm_its_own():
    """At q = 0 with gravity -z, a y-axis joint's torque is g * sum(m x) of everything it carries."""
    g = 9.81
    shift = lambda x: se3.make(np.eye(3), [x, 0, 0])  # noqa: E731
    robot = Robot("hand", {"torso": _line_arm("torso", 0.1, 20.0, gravity=[0, 0, -g]),
                           "left": _line_arm("left", 0.3, 4.0, shift(0.2), payload=1.0),
                           "right": _line_arm("right", -0.4, 5.0, shift(-0.2), payload=2.0)},
                  mounts={"left": "torso", "right": "torso"})
    q = {a: np.zeros((1, 1)) for a in robot.arms}
    torso = g * (20 * 0.1 + 4 * 0.5 + 1 * 0.2 + 5 * -0.6 + 2 * -0.2)
    for arm, own in (("left", g * (4 * 0.3 + 1 * 0.0)), ("right", g * (5 * -0.4 + 2 * 0.0))):
        tau = tree_loaded_kinematics(robot, arm, q).tau[0]
        np.testing.assert_allclose(tau, [torso, own], atol=1e-12)


def test_a_mounted_data_set_without_the_other_arm_readings_is_refused(rng):
    robot = gravity_tree(rng)
    ds = _case("pose", rng, robot)
    ds = Dataset("pose", "tree", ("b",), {a: ds.q[a] for a in ("torso", "b")}, dict(ds.measured), dict(ds.known),
                 "right-hand")
    with pytest.raises(DataFormatError, match=r"data set 'right-hand': field q\[a\]: no readings of arm 'a', whose "
                                              r"weight loads"):
        experiments.build([ds], State.from_robot(robot))


def test_arms_of_one_tree_state_one_gravity(rng):
    robot = gravity_tree(rng)
    assert np.array_equal(robot["a"].gravity, G)  # the tree's gravity, stated on the torso
    with pytest.raises(ModelError, match="arm 'b': gravity .* disagrees with arm 'torso'"):
        Robot("tree", {**robot.arms, "b": robot["b"].replace(gravity=-G)}, mounts=dict(robot.mounts))


# ------------------------------------------------------------------ end to end: two arms on a sagging torso

import dataclasses  # noqa: E402

from kincal.estimation import calibrate  # noqa: E402
from kincal.io.models import load_builtin  # noqa: E402
from kincal.lie import so3  # noqa: E402
from kincal.noise import Noise  # noqa: E402
from kincal.simulate.generators import generate_markers  # noqa: E402
from kincal.simulate.perturb import perturb_robot  # noqa: E402

TILT = se3.make(so3.exp(np.array([0.5, 0.0, 0.0])), [0.0, 0.0, 0.3])  # a tilted pedestal: the pan axis loaded too
COMPLIANCE = {"torso": [2e-6, 3e-6], "left": [4e-6, 5e-6, 6e-6, 8e-6, 1e-5, 1.5e-5, 2e-5],
              "right": [5e-6, 4e-6, 7e-6, 9e-6, 1.2e-5, 1.5e-5, 2e-5]}


def _sagging_torso(level):
    """dual7_torso with masses (torso links 20 and 15 kg, arms 4 .. 0.5 kg and a 2 kg hand each), gravity
    stated on the torso, its true robot perturbed (offsets only for level ``offsets``) and compliant."""
    nom = load_builtin("dual7_torso")
    rng = np.random.default_rng(0)
    arms = {"torso": nom["torso"].replace(base=TILT @ nom["torso"].base, link_masses=[20.0, 15.0],
                                          link_coms=[[0, 0, 0.2], [0.05, 0, 0.5]], gravity=[0, 0, -9.81])}
    for a in ("left", "right"):
        arms[a] = nom[a].replace(link_masses=np.linspace(4, 0.5, 7), link_coms=rng.uniform(-0.3, 0.3, (7, 3)),
                                 payload_mass=2.0, payload_com=[0.0, 0.0, 0.05])
    nominal = Robot(nom.name, arms, mounts=nom.mounts)
    perturbed = perturb_robot(nominal, "fine", 5)
    true = {a: (nominal[a].replace(offsets=perturbed[a].offsets) if level == "offsets" else perturbed[a])
            for a in arms}
    true = Robot(nom.name, {a: m.replace(compliance=COMPLIANCE[a]) for a, m in true.items()}, mounts=nom.mounts)
    return nominal, true


@pytest.mark.parametrize("level", ["offsets", pytest.param("kinematic", marks=pytest.mark.slow)])
def test_two_arms_on_a_sagging_torso_calibrate_their_compliances(level):
    """Markers on both hands, one tracker of known pose, 0.02 mm noise: the torso carries both arms, each arm
    its hand; every compliance (torso and arms) comes back within 3 reported std, and fresh configurations
    are predicted far better than by a rigid calibration. (``kinematic`` takes minutes: the solver crawls.)"""
    nominal, true = _sagging_torso(level)
    W = random_pose(np.random.default_rng(9))
    data, val = [], []
    for seed, arm in ((1, "left"), (2, "right")):
        ds, _, v = generate_markers(true, arm, n=80, rng=seed, markers=3, noise=Noise(position=2e-5),
                                    n_validation=50, known_tracker=True, known_markers=True, T_world_tracker=W)
        assert set(ds.q) == {"torso", "left", "right"}  # the other arm's readings: its weight loads the torso
        data.append(dataclasses.replace(ds, name=f"{arm}-hand"))
        val.append(v[arm])
    res = calibrate(nominal, data, [level, "elastic"], validation=val)
    rigid = calibrate(nominal, data, [level], validation=val)
    assert res.status == "converged"
    for arm, c in COMPLIANCE.items():
        for j, name in enumerate(nominal[arm].joint_names):
            e = res.estimate(f"{arm}.{name}.compliance")
            assert e.identifiable and abs(e.value - c[j]) < 3 * e.std, (arm, name, e.value, c[j], e.std)
    for after, before in zip(res.validation, rigid.validation):
        assert after.after.position_rms < 0.2 * before.after.position_rms
        assert after.after.position_rms < 2e-5


def test_the_other_arms_readings_round_trip_through_files(rng, tmp_path):
    """CSV columns ``a.j1 ..`` carry the other arm's readings; a file without them is refused when used."""
    robot = gravity_tree(rng)
    ds = _case("markers", rng, robot)
    path = write_dataset(ds, tmp_path / "hand.yaml", robot)
    back = load_dataset(path, robot)
    assert set(back.q) == {"torso", "a", "b"}
    np.testing.assert_allclose(back.q["a"], ds.q["a"], atol=1e-15)
    without = Dataset(ds.kind, "tree", ds.arms, {a: ds.q[a] for a in ("torso", "b")}, dict(ds.measured),
                      dict(ds.known), "hand")
    back = load_dataset(write_dataset(without, tmp_path / "bare.yaml", robot), robot)
    with pytest.raises(DataFormatError, match=r"data set 'hand': field q\[a\]: no readings of arm 'a'"):
        experiments.build([back], State.from_robot(robot))
