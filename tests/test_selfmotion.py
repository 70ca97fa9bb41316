"""Self-motion of clamped arms: closure, limits, spread over joints and branches, determinism, backlash."""

import numpy as np
import pytest

from kincal.kinematics import forward_kinematics
from kincal.robots import load
from kincal.simulate.generators import dataset_spread, generate_clamp
from kincal.simulate.ik import PoseConstraint
from kincal.simulate.noise import Noise, backlash_offsets
from kincal.simulate.perturb import perturb_robot
from kincal.simulate.selfmotion import explore, joint_spread
from kincal.testing import random_arm

FAST = {"n_seeds": 48, "n_steps": 80}


@pytest.fixture(scope="module")
def frida_clamp():
    true = perturb_robot(load("frida"), "thesis", rng=7)
    ds, truth, val = generate_clamp(true, "right", n=120, rng=11, explore_options=FAST)
    return true, ds, truth, val


def test_clamped_configurations_close_under_the_true_model(frida_clamp):
    true, ds, truth, _ = frida_clamp
    arm = true["right"]
    T = forward_kinematics(arm, truth.q["right"])
    T_fix = truth.values["T_world_fixture"]
    assert np.abs(T[:, :3, 3] - T_fix[:3, 3]).max() < 1e-10
    assert np.abs(T[:, :3, :3] - T_fix[:3, :3]).max() < 1e-10
    assert np.all(arm.within_limits(truth.q["right"]))
    assert ds.size == 120 and "T_world_fixture" not in ds.known  # unknown by default


def test_spread_report_covers_joints_and_branches(frida_clamp):
    true, ds, truth, _ = frida_clamp
    sp = dataset_spread(ds, true, truth)["right"]
    assert sp.names == true["right"].joint_names
    np.testing.assert_allclose(sp.range, np.ptp(ds.q["right"], axis=0))
    assert np.all(sp.fraction <= 1.0 + 1e-9)
    assert sp.n_branches is not None and sp.n_branches > 1
    assert np.count_nonzero(sp.range > 0.3) >= 5  # the self-motion really moves the arm
    text = "\n".join(sp.lines())
    assert "j1" in text and "branches visited" in text


def test_weak_joints_are_named():
    q = np.zeros((10, 3))
    q[:, 0] = np.linspace(0, 1, 10)
    q[:, 2] = np.linspace(0, 0.01, 10)
    sp = joint_spread(q, ("a", "b", "c"), [-1, -1, -1], [1, 1, 1], weak_rad=0.1)
    assert sp.weak == ("b", "c")
    assert "hardly excited: b, c" in "\n".join(sp.lines())


def test_identical_seeds_identical_data(frida_clamp):
    true, ds, truth, val = frida_clamp
    ds2, truth2, val2 = generate_clamp(true, "right", n=120, rng=11, explore_options=FAST)
    assert np.array_equal(ds.q["right"], ds2.q["right"])
    assert np.array_equal(truth.values["T_world_fixture"], truth2.values["T_world_fixture"])
    assert np.array_equal(val["right"].q["right"], val2["right"].q["right"])
    ds3, _, _ = generate_clamp(true, "right", n=120, rng=12, explore_options=FAST)
    assert not np.array_equal(ds.q["right"], ds3.q["right"])


def test_exploration_of_a_random_7dof_arm_reports_rejections(rng):
    arm = random_arm(rng, 7).replace(lower=np.full(7, -2.8), upper=np.full(7, 2.8))
    T = forward_kinematics(arm, rng.uniform(-1, 1, 7))
    ex = explore(PoseConstraint(arm, T), rng, n_seeds=32, n_steps=40)
    assert ex.dim == 1
    assert ex.n_seeds_tried == 32 and 0 <= ex.n_seeds_failed < 32
    assert np.abs(forward_kinematics(arm, ex.q) - T).max() < 1e-10
    assert np.all(arm.within_limits(ex.q))
    # no near-duplicates are returned
    d = np.abs(ex.q[:, None, :] - ex.q[None, :, :]).max(-1) + np.eye(len(ex.q))
    assert d.min() >= 1e-3


def test_backlash_follows_the_direction_of_motion(rng):
    path = np.array([[0.0], [1.0], [2.0], [2.0], [1.5], [1.5], [3.0]])
    off = backlash_offsets(path, 0.2, rng)[:, 0]
    np.testing.assert_allclose(off[1:], [0.1, 0.1, 0.1, -0.1, -0.1, 0.1])


def test_joint_noise_statistics(frida_clamp):
    true, _, truth, _ = frida_clamp
    ds, truth2, _ = generate_clamp(true, "right", n=120, rng=11, noise=Noise(joint=1e-3), explore_options=FAST)
    err = ds.q["right"] - truth2.q["right"]
    assert np.array_equal(truth2.q["right"], truth.q["right"])  # noise is drawn after the configurations
    assert 0.8e-3 < err.std() < 1.2e-3 and abs(err.mean()) < 3e-4
