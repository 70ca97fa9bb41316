"""The issue's table on Frida, noise-free: thesis-size errors (twists +-0.01 m / +-2.4 deg, offsets <= 0.07 rad)."""

import numpy as np
import pytest

from kincal.data import Dataset
from kincal.estimation import calibrate, evaluate
from kincal.kinematics import Robot, forward_kinematics
from kincal.lie import se3
from kincal.params import displacement
from kincal.robots import load
from kincal.simulate.generators import generate_clamp, generate_dual, generate_plate
from kincal.simulate.perturb import perturb_robot

EXACT = 1e-9


@pytest.fixture(scope="module")
def frida():
    return load("frida")


@pytest.fixture(scope="module")
def true_full(frida):
    return perturb_robot(frida, "thesis", 7)


@pytest.fixture(scope="module")
def true_offsets(frida, true_full):
    """Nominal geometry, thesis-size joint offsets."""
    return Robot(frida.name, {k: frida[k].replace(offsets=true_full[k].offsets) for k in frida.arms})


def _offset_errors(res, truth, arm):
    return np.array([res.estimate(f"{arm}.j{i + 1}.offset").value - truth[arm].offsets[i] for i in range(7)])


def _reported(res, name):
    return any(d.pivot == name for d in res.identifiability.directions)


def test_one_clamp_known_pose(frida, true_offsets):
    ds, _, _ = generate_clamp(true_offsets, "right", n=30, rng=1, known_fixture=True)
    res = calibrate(frida, [ds], "offsets")
    assert res.status == "converged" and res.identifiability.deficiency == 0
    assert np.max(np.abs(_offset_errors(res, true_offsets, "right"))) < EXACT


def test_one_clamp_unknown_pose(frida, true_offsets):
    ds, truth, _ = generate_clamp(true_offsets, "right", n=30, rng=1, known_fixture=False)
    res = calibrate(frida, [ds], "offsets")
    err = _offset_errors(res, true_offsets, "right")
    assert np.max(np.abs(err[1:6])) < EXACT
    assert res.identifiability.deficiency == 2
    assert _reported(res, "right.j1.offset") and _reported(res, "right.j7.offset")
    words = " ".join(res.messages)
    assert "right.j1.offset cannot be identified" in words
    assert "a rotation of the fixture about the axis of right.j1" in words
    assert "a rotation of the fixture about the axis of right.j7" in words
    assert not res.estimate("right.j1.offset").identifiable and np.isnan(res.estimate("right.j1.offset").std)
    assert res.estimate("right.j3.offset").identifiable
    assert not res.identifiability.scale_unidentifiable


def test_plate_with_four_fixtures(frida, true_offsets):
    ds, _, _ = generate_plate(true_offsets, "right", n=40, rng=2, known_plate=False)
    res = calibrate(frida, [ds], "offsets")
    err = _offset_errors(res, true_offsets, "right")
    assert np.max(np.abs(err[1:])) < EXACT
    assert [d.pivot for d in res.identifiability.directions] == ["right.j1.offset"]
    assert "a rotation of the plate about the axis of right.j1" in res.identifiability.directions[0].words


def test_dual_known_clamp(frida, true_offsets):
    ds, _, _ = generate_dual(true_offsets, n=40, rng=3, known_clamp=True)
    res = calibrate(frida, [ds], "offsets")
    assert res.identifiability.deficiency == 0
    for arm in ("left", "right"):
        assert np.max(np.abs(_offset_errors(res, true_offsets, arm))) < EXACT


def test_dual_clamp_off_by_table_4_14(frida, true_offsets):
    ds, truth, _ = generate_dual(true_offsets, n=40, rng=3, known_clamp=True)
    off = se3.exp(np.array([0.01, 0.01, -0.01, -0.1, 0.1, 0.1]))  # 1 cm / 0.1 rad, thesis Table 4.14
    wrong = Dataset(ds.kind, ds.robot, ds.arms, ds.q, ds.measured,
                    {"T_toolA_toolB": truth.values["T_toolA_toolB"] @ off}, ds.name)
    res = calibrate(frida, [wrong], ["offsets", "clamp"])
    for arm in ("left", "right"):
        assert np.max(np.abs(_offset_errors(res, true_offsets, arm)[:6])) < EXACT
    assert sorted(d.pivot for d in res.identifiability.directions) == ["left.j7.offset", "right.j7.offset"]
    assert all("a rotation of the clamp about the axis of" in d.words for d in res.identifiability.directions)


def _fresh_dual(true, clamp, rng):
    ds, _, _ = generate_dual(true, n=20, rng=rng, known_clamp=True, clamp=clamp)
    return ds


def test_dual_one_arm_known_calibrates_the_other(frida, true_full):
    nominal = Robot(frida.name, {"left": true_full["left"], "right": frida["right"]})
    ds, truth, val = generate_dual(true_full, n=50, rng=4, known_clamp=True)
    res = calibrate(nominal, [ds], ["right.*.offset", "right.twists", "right.home"])
    assert res.status == "converged"
    # offsets are redundant with twists and home in a full POE model: 7 directions, all named
    assert res.identifiability.deficiency == 7
    assert all("full POE" in d.words for d in res.identifiability.directions)
    q = val["right"].q["right"]
    err = forward_kinematics(res.robot["right"], q) - forward_kinematics(true_full["right"], q)
    assert np.max(np.abs(err[:, :3, 3])) < EXACT and np.max(np.abs(err[:, :3, :3])) < EXACT


def test_dual_both_arms_unknown(frida, true_full):
    ds, truth, _ = generate_dual(true_full, n=50, rng=5, known_clamp=False)
    res = calibrate(frida, [ds], "kinematic")
    ana = res.identifiability
    assert res.status == "converged"
    assert ana.scale_unidentifiable
    # estimate minus truth lies in the reported unidentifiable subspace (first order)
    true_state = type(res.state)({a: type(res.state.arms[a]).from_model(true_full[a]) for a in ("left", "right")},
                                 {"clamp": truth.values["T_toolA_toolB"]}, res.state.kinds)
    d, _ = displacement(true_state, res.state, res.layout)
    d = d[res.layout.free]
    outside = d - ana.null_space @ (ana.null_space.T @ d)
    assert np.linalg.norm(outside) < 0.05 * np.linalg.norm(d)
    # closure of fresh configurations of the true robot
    fresh = _fresh_dual(true_full, truth.values["T_toolA_toolB"], 6)
    fresh = Dataset("dual", fresh.robot, fresh.arms, fresh.q, {}, {"T_toolA_toolB": res.extras["clamp"]}, "fresh")
    stats = evaluate(res.robot, [fresh])[0]
    assert stats.position_max < EXACT and stats.orientation_max < EXACT


@pytest.mark.parametrize("markers,rank", [(1, 27), (3, 33)])
def test_tracker_markers_unknown_tracker_and_markers(markers, rank):
    """UR10 seen by a tracker (partial pose, seed 001): all geometric parameters + unknown tracker and markers.

    The gauge (whole arm moved rigidly with the tracker; with one marker, the tool frame's rotation about it)
    is exact in the tracker-frame residual: an exact rank, no 'weakly identifiable' noise directions.
    """
    from kincal.simulate.generators import generate_markers

    ur = load("ur10")
    true = perturb_robot(ur, "fine", 3)
    ds, _, val = generate_markers(true, n=200, rng=4, markers=markers)
    res = calibrate(ur, [ds], "kinematic", validation=list(val.values()))
    assert res.status == "converged"
    assert res.identifiability.rank == rank
    assert not any("weakly identifiable" in m for m in res.messages)
    v = res.validation[0]
    assert v.before.position_rms > 1e-3 and v.after.position_max < EXACT
    # the Python API reports, next to the validation error, what the model predicts about its accuracy there
    ((name, pred),) = res.predictions
    assert name == v.experiment and pred.trusted and pred.null_moving == 0
