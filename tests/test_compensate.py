"""Compensated targets (issue #12, item 3): joint programs written for the nominal model, compensated on the
calibrated one, reach the intended poses under the true robot to within the calibration's predicted error;
rows that cannot be compensated are named."""

from __future__ import annotations

import numpy as np
import pytest

from kincal import robots
from kincal.errors import ShapeError
from kincal.estimation import Noise, calibrate
from kincal.kinematics import forward_kinematics
from kincal.lie import se3
from kincal.simulate import generate_pose, perturb_robot, random_configurations
from kincal.workflow.compensate import BRANCH_RAD, compensate_joints, compensate_poses

NOISE = Noise(position=2e-5, orientation=2e-5)


def _calibrated(name, arm, seed):
    nominal = robots.load(name)
    true = perturb_robot(nominal, "fine", rng=seed)
    ds, _, _ = generate_pose(true, arm, n=150, rng=seed + 1, noise=NOISE, known_tracker=True)
    return nominal, true, calibrate(nominal, [ds], "kinematic", noise=NOISE)


@pytest.mark.parametrize("name,arm", [("ur10", "arm"), ("frida", "right")])
def test_compensated_program_reaches_the_intended_poses_under_the_true_robot(name, arm):
    for seed in (5, 6):
        nominal, true, res = _calibrated(name, arm, seed)
        q = random_configurations(nominal[arm], 400, np.random.default_rng(seed), 0.1)
        comp = compensate_joints(nominal, res.robot, {arm: q})
        ok = comp.status[arm] == "ok"
        assert ok.mean() > 0.9
        intended = forward_kinematics(nominal[arm], q)[:, :3, 3]
        before = np.linalg.norm(forward_kinematics(true[arm], q)[:, :3, 3] - intended, axis=1)[ok]
        after = np.linalg.norm(forward_kinematics(true[arm], comp.q[arm])[:, :3, 3] - intended, axis=1)[ok]
        predicted = res.predict(q[ok], arm, register=False).position_rms_predicted
        actual = np.sqrt(np.mean(after**2))
        assert 0.5 < actual / predicted < 2.0, (actual, predicted)
        assert np.sqrt(np.mean(before**2)) > 100 * actual
        assert comp.change[arm][ok].max() < BRANCH_RAD  # the program's branch kept
        assert np.all(comp.position_error[arm][ok] < 1e-6)


def test_dual_arm_program_and_failed_rows_are_named():
    nominal = robots.load("frida")
    true = perturb_robot(nominal, "fine", rng=2)
    rng = np.random.default_rng(0)
    program = {a: random_configurations(nominal[a], 50, rng, 0.1) for a in ("left", "right")}
    program["right"][3, 1] = nominal["right"].upper[1] + 0.2  # a row past a limit
    comp = compensate_joints(nominal, true, program)
    for a in ("left", "right"):
        ok = comp.status[a] == "ok"
        T = forward_kinematics(true[a], comp.q[a][ok])
        assert np.abs(T - forward_kinematics(nominal[a], program[a][ok])).max() < 1e-6
    assert ("right", 3, "outside limits") in comp.failed()


def test_cartesian_targets_and_unreachable_rows():
    nominal, true, res = _calibrated("ur10", "arm", 7)
    q = random_configurations(nominal["arm"], 20, np.random.default_rng(1), 0.1)
    T = forward_kinematics(nominal["arm"], q)
    T[5] = se3.make(T[5, :3, :3], T[5, :3, 3] * 3)  # far outside the reach
    comp = compensate_poses(res.robot, {"arm": T}, {"arm": q}, nominal=nominal)
    assert comp.status["arm"][5] == "unreachable" and comp.position_error["arm"][5] > 0.1
    assert (comp.status["arm"] == "ok").sum() >= 17
    with pytest.raises(ShapeError, match="20 poses but 3 seed"):
        compensate_poses(res.robot, {"arm": T}, {"arm": q[:3]})
    with pytest.raises(ShapeError, match="not finite"):
        compensate_joints(nominal, res.robot, {"arm": np.full((2, 6), np.nan)})
