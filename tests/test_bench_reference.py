"""The minimal reference solver of bench/ (issue 15's floor): its model is the UR10's, its analytic Jacobian
matches finite differences, its parameter set is identifiable, and it reaches kincal's estimate on the same data."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import reference_solver as rs  # noqa: E402
from kincal.estimation import Noise as StatedNoise  # noqa: E402
from kincal.estimation import calibrate  # noqa: E402
from kincal.kinematics import forward_kinematics  # noqa: E402
from kincal.lie import se3  # noqa: E402
from kincal.robots import load  # noqa: E402
from kincal.simulate import Noise, generate_markers, perturb_robot, random_configurations  # noqa: E402
from kincal.simulate.generators import random_markers, random_tracker_pose  # noqa: E402
from kincal.testing import numerical_jacobian  # noqa: E402

SIGMA = 5e-5


def _moved(rng) -> rs.Model:
    """The nominal UR10 with every estimated parameter moved (tracker pose and marker away from identity)."""
    model = rs.ur10()
    return rs.retract(model, np.r_[0.5, -1.0, 2.0, 0.3, -0.2, 0.5, rng.normal(0, 0.01, model.size - 9),
                                   0.05, 0.02, 0.1])


def test_nominal_model_is_kincals_ur10(rng):
    q = rng.uniform(-np.pi, np.pi, (20, 6))
    flange = rs.frames(rs.ur10(), q)[1]
    np.testing.assert_allclose(flange, forward_kinematics(load("ur10")["arm"], q), atol=1e-12)


def test_jacobian_matches_finite_differences(rng):
    model, q = _moved(rng), rng.uniform(-np.pi, np.pi, (15, 6))
    y, J = rs.jacobian(model, q)
    np.testing.assert_allclose(y, rs.predict(model, q), atol=1e-14)
    numeric = numerical_jacobian(lambda d: rs.predict(rs.retract(model, d), q), np.zeros(model.size))
    assert J.shape == (15, 3, 27)
    np.testing.assert_allclose(J, numeric, atol=1e-8)


def test_parameters_are_a_minimal_identifiable_set(rng):
    model, q = _moved(rng), rng.uniform(-np.pi, np.pi, (50, 6))
    S = np.linalg.svd(rs.jacobian(model, q)[1].reshape(-1, model.size), compute_uv=False)
    assert model.size == 27  # the rank kincal finds for this problem: 4 x 6 + 3
    assert S[-1] > 1e-6 * S[0]


@pytest.fixture(scope="module")
def tracker_problem():
    rng = np.random.default_rng(0)
    nominal = load("ur10")
    true = perturb_robot(nominal, "fine", rng=rng)
    T_world_tracker = random_tracker_pose(true, "arm", rng)
    marker = random_markers(1, rng)
    ds = generate_markers(true, "arm", n=200, rng=rng, noise=Noise(position=SIGMA), markers=marker,
                          T_world_tracker=T_world_tracker, n_validation=1)[0]
    q_val = random_configurations(true["arm"], 300, rng, margin=0.05)
    T = se3.inverse(T_world_tracker) @ forward_kinematics(true["arm"], q_val)
    return nominal, ds, q_val, se3.transform_points(T, np.asarray(marker).reshape(3))


def test_reaches_kincals_estimate(tracker_problem):
    nominal, ds, q_val, y_val = tracker_problem
    y = ds.measured["p_tracker_marker"][:, 0]
    fit = rs.solve(rs.ur10(), ds.q["arm"], y)
    res = calibrate(nominal, [ds], "kinematic", noise=StatedNoise(position=SIGMA, joint=0.0))
    assert fit.converged and res.status == "converged" and res.identifiability.rank == fit.model.size
    T = se3.inverse(res.extras["tracker"]) @ forward_kinematics(res.robot["arm"], q_val)
    theirs = se3.transform_points(T, np.asarray(res.extras["markers"]).reshape(3))
    ours = rs.predict(fit.model, q_val)
    assert np.max(np.linalg.norm(ours - theirs, axis=1)) < 0.01 * SIGMA  # the same fit, well below the noise
    rms = [np.sqrt(np.mean(np.sum((p - y_val) ** 2, axis=1))) for p in (ours, theirs)]
    assert rms[0] == pytest.approx(rms[1], rel=1e-2)
    assert rms[0] < SIGMA  # calibrated: well below the nominal model's millimetres
    fit_rms = np.sqrt(fit.cost2 / len(y))
    assert fit_rms == pytest.approx(res.after[0].position_rms, rel=1e-6)
