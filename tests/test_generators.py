"""True-robot perturbation and the experiment generators (pose, markers, plate, dual, socket)."""

import numpy as np
import pytest

from kincal.errors import ModelError
from kincal.kinematics import forward_kinematics
from kincal.lie import se3
from kincal.robots import load
from kincal.simulate.generators import (
    BRACKET_90,
    generate_dual,
    generate_markers,
    generate_plate,
    generate_pose,
    generate_socket,
    plate_layout,
)
from kincal.simulate.ik import closure_error
from kincal.simulate.noise import Noise
from kincal.simulate.perturb import LEVELS, perturb_robot, perturbation

FAST = {"n_seeds": 48, "n_steps": 60}


@pytest.fixture(scope="module")
def frida():
    return load("frida")


@pytest.fixture(scope="module")
def true_frida(frida):
    return perturb_robot(frida, "thesis", rng=3)


def test_thesis_perturbation_magnitudes(frida):
    true = perturb_robot(frida, "thesis", rng=1)
    p = LEVELS["thesis"]
    for a in frida.arms:
        nom, tr = frida[a], true[a]
        assert np.all(np.abs(tr.offsets - nom.offsets) <= 0.07) and np.abs(tr.offsets).max() > 0.02
        w_nom, w_tr = se3.split(nom.screws)[1], se3.split(tr.screws)[1]
        np.testing.assert_allclose(np.linalg.norm(w_tr, axis=1), 1.0)  # re-conformed
        assert np.abs(np.einsum("ij,ij->i", w_tr, se3.split(tr.screws)[0])).max() < 1e-12  # zero pitch
        angle = np.arccos(np.clip(np.einsum("ij,ij->i", w_nom, w_tr), -1, 1))
        assert angle.max() < np.sqrt(3) * p.twist_rad + 1e-9 and angle.max() > 0.1 * p.twist_rad
        assert not np.array_equal(tr.home, nom.home)
        assert np.array_equal(tr.base, nom.base) and np.array_equal(tr.tool, nom.tool)


def test_fine_level_and_overrides(frida):
    true = perturb_robot(frida, "fine", rng=1, base_m=0.002, arms=("left",))
    assert np.abs(true["left"].offsets).max() <= 0.01
    assert np.linalg.norm(true["left"].base[:3, 3] - frida["left"].base[:3, 3]) <= 0.002 * np.sqrt(3) + 1e-12
    assert true["right"] == frida["right"]  # not perturbed
    assert perturb_robot(frida, "thesis", rng=5) == perturb_robot(frida, "thesis", rng=5)
    assert perturb_robot(frida, "thesis", rng=5) != perturb_robot(frida, "thesis", rng=6)
    with pytest.raises(ModelError, match="expected one of"):
        perturbation("huge")
    with pytest.raises(ModelError, match="finite magnitude"):
        perturbation("fine", twist_m=-1.0)


def test_pose_experiment_is_consistent_with_truth():
    ur10 = perturb_robot(load("ur10"), "fine", rng=2)
    ds, truth, val = generate_pose(ur10, n=30, rng=4)
    T_wt = truth.values["T_world_tracker"]
    arm = ur10["arm"]
    expected = se3.inverse(T_wt) @ forward_kinematics(arm, ds.q["arm"])
    np.testing.assert_allclose(ds.measured["T_tracker_tool"], expected, atol=1e-12)
    assert "T_world_tracker" not in ds.known
    assert np.all(arm.within_limits(ds.q["arm"]))
    v = val["arm"]
    assert v.kind == "pose" and v.size == 100
    np.testing.assert_allclose(v.measured["T_tracker_tool"], forward_kinematics(arm, v.q["arm"]), atol=1e-12)


def test_markers_experiment_with_noise():
    ur10 = perturb_robot(load("ur10"), "fine", rng=2)
    noise = Noise(joint=0.0, position=1e-4)
    ds, truth, _ = generate_markers(ur10, n=400, rng=4, markers=3, noise=noise, known_markers=True)
    p_tm = truth.values["p_tool_marker"]
    assert p_tm.shape == (3, 3) and np.allclose(np.linalg.norm(p_tm, axis=1), 0.1)
    np.testing.assert_array_equal(ds.known["p_tool_marker"], p_tm)
    T = se3.inverse(truth.values["T_world_tracker"]) @ forward_kinematics(ur10["arm"], truth.q["arm"])
    err = ds.measured["p_tracker_marker"] - se3.transform_points(T[:, None], p_tm[None])
    assert 0.9e-4 < err.std() < 1.1e-4


def test_readings_are_true_value_minus_offset(true_frida):
    """The controller reports theta - offset: FK of the true model (which adds the offsets) closes the chain,
    while reading + offset would not."""
    ds, truth, _ = generate_dual(true_frida, n=50, rng=8, explore_options=FAST)
    l, r = true_frida["left"], true_frida["right"]
    pos, rot = closure_error(l, r, BRACKET_90, ds.q["left"], ds.q["right"])
    assert pos.max() < 1e-10 and rot.max() < 1e-10
    pos2, _ = closure_error(l, r, BRACKET_90, ds.q["left"] + l.offsets, ds.q["right"] + r.offsets)
    assert pos2.max() > 1e-3


def test_dual_arm_frida_closure_limits_spread_and_seed(true_frida):
    ds, truth, val = generate_dual(true_frida, n=200, rng=9, explore_options=FAST)
    assert ds.kind == "dual" and ds.arms == ("left", "right") and ds.size == 200
    np.testing.assert_array_equal(ds.known["T_toolA_toolB"], BRACKET_90)
    pos, rot = closure_error(true_frida["left"], true_frida["right"], BRACKET_90, truth.q["left"], truth.q["right"])
    assert pos.max() < 1e-10 and rot.max() < 1e-10
    for a in ds.arms:
        assert np.all(true_frida[a].within_limits(truth.q[a]))
        assert np.ptp(truth.q[a], axis=0).min() > 0.3
    ds2, _, _ = generate_dual(true_frida, n=200, rng=9, explore_options=FAST)
    assert np.array_equal(ds.q["left"], ds2.q["left"]) and np.array_equal(ds.q["right"], ds2.q["right"])


def test_dual_arm_workspace_and_unknown_clamp(true_frida):
    box = (np.array([0.25, -0.3, 0.05]), np.array([0.65, 0.3, 0.6]))
    ds, truth, _ = generate_dual(true_frida, n=40, rng=2, known_clamp=False, workspace=box, explore_options=FAST)
    assert "T_toolA_toolB" not in ds.known and "T_toolA_toolB" in truth.values
    p = forward_kinematics(true_frida["left"], truth.q["left"])[:, :3, 3]
    assert np.all((p >= box[0]) & (p <= box[1]))


def test_plate_fixtures_are_all_reached(true_frida):
    ds, truth, _ = generate_plate(true_frida, "right", n=40, rng=3, explore_options=FAST, candidates=10)
    arm = true_frida["right"]
    fixture = ds.measured["fixture"]
    assert sorted(np.unique(fixture)) == [0, 1, 2, 3] and np.bincount(fixture).min() == 10
    T_target = truth.values["T_world_plate"] @ truth.values["T_plate_fixture"][fixture]
    np.testing.assert_allclose(forward_kinematics(arm, truth.q["right"]), T_target, atol=1e-10)
    np.testing.assert_array_equal(ds.known["T_plate_fixture"], plate_layout())
    assert "T_world_plate" not in ds.known
    assert np.all(arm.within_limits(truth.q["right"]))


def test_socket_keeps_the_tool_point_fixed(true_frida):
    ds, truth, _ = generate_socket(true_frida, "left", n=30, rng=5, known_socket=True, explore_options=FAST)
    p = forward_kinematics(true_frida["left"], truth.q["left"])[:, :3, 3]
    assert np.abs(p - truth.values["p_world_socket"]).max() < 1e-10
    np.testing.assert_array_equal(ds.known["p_world_socket"], truth.values["p_world_socket"])


def test_every_generator_declares_its_scenario_options():
    """Each option names a keyword argument of its generator, with the generator's default; every keyword a
    scenario can set (besides rng, noise, n_validation, progress and tuning knobs) is an option."""
    import inspect

    from kincal.simulate.generators import GENERATORS, OPTIONS

    assert {"pose", "markers", "clamp", "plate", "dual", "socket"} <= set(GENERATORS) == set(OPTIONS)
    for kind, fn in GENERATORS.items():
        params = inspect.signature(fn).parameters
        for o in OPTIONS[kind]:
            assert o.argument in params, (kind, o.name)
            default = params[o.argument].default
            if o.default is not None:  # (p_tool_marker declares none: the count 'markers' declares the default)
                assert np.array_equal(np.asarray(o.default, dtype=object), np.asarray(default, dtype=object)), \
                    (kind, o.name, o.default, default)
            else:
                assert default is None or any(p.argument == o.argument and p.default is not None
                                              for p in OPTIONS[kind]), (kind, o.name, default)
        declared = {o.argument for o in OPTIONS[kind]}
        internal = {"robot", "rng", "noise", "n_validation", "progress", "margin", "candidates"}
        assert set(params) - internal <= declared, (kind, set(params) - internal - declared)
