"""Pose measurements with a full covariance (issue #13, item 1): the markers-to-pose fit and the covariance it
implies, whitening by a per-sample covariance, and honest standard deviations (Monte Carlo)."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.data import Dataset
from kincal.errors import DataFormatError, DegenerateExperimentError, KincalError, ShapeError
from kincal.experiments.pose_from_markers import fit_poses, markers_to_pose
from kincal.lie import se3, so3

LAYOUT = np.array([[0.30, 0.00, 0.20], [0.38, 0.05, 0.20], [0.32, -0.06, 0.26], [0.35, 0.02, 0.14]])


def _random_poses(n, rng):
    return se3.make(so3.exp(rng.normal(size=(n, 3))), rng.uniform(-1, 1, size=(n, 3)))


def _markers(T, x, noise, rng, **extra):
    y = se3.transform_points(T[:, None], x[None]) + noise * rng.normal(size=(len(T), len(x), 3))
    q = {"arm": np.zeros((len(T), 3))}
    return Dataset("markers", "klimchik3r", ("arm",), q, {"p_tracker_marker": y}, {"p_tool_marker": x}, **extra)


def _pose_error(T_fit, T):
    """(p_fit - p, log(R_fit R^T)): the error the pose covariance describes."""
    R = T_fit[:, :3, :3] @ np.swapaxes(T[:, :3, :3], -1, -2)
    return np.concatenate([T_fit[:, :3, 3] - T[:, :3, 3], so3.log(R)], axis=1)


def test_fit_recovers_noise_free_poses():
    rng = np.random.default_rng(0)
    T = _random_poses(50, rng)
    ds = markers_to_pose(_markers(T, LAYOUT, 0.0, rng), sigma=1e-5)
    assert ds.kind == "pose" and ds.measured["pose_cov"].shape == (50, 6, 6)
    np.testing.assert_allclose(ds.measured["T_tracker_tool"], T, atol=1e-12)
    np.testing.assert_allclose(fit_poses(LAYOUT, se3.transform_points(T[:, None], LAYOUT[None])), T, atol=1e-12)


def test_covariance_matches_monte_carlo_of_the_fit():
    """20000 noisy fits of one pose: the sample covariance, whitened by the predicted one, is the identity. Its
    entries' sampling std is sqrt(2/n) = 0.010 on the diagonal and 1/sqrt(n) = 0.007 off it; 0.05 is 5 of those.
    The first-order prediction's own error is of order (sigma / marker spread)^2 = 1e-6."""
    rng = np.random.default_rng(1)
    n, sigma = 20000, 1e-4
    T = np.repeat(_random_poses(1, rng), n, axis=0)
    ds = markers_to_pose(_markers(T, LAYOUT, sigma, rng), sigma=sigma)
    C = markers_to_pose(_markers(T[:1], LAYOUT, 0.0, rng), sigma=sigma).measured["pose_cov"][0]  # at the truth
    Li = np.linalg.inv(np.linalg.cholesky(C))
    # each row's covariance is evaluated at its fitted orientation: the same to first order, on average
    assert np.abs(Li @ ds.measured["pose_cov"].mean(axis=0) @ Li.T - np.eye(6)).max() < 0.01
    S = np.cov(_pose_error(ds.measured["T_tracker_tool"], T).T)
    assert np.abs(Li @ S @ Li.T - np.eye(6)).max() < 0.05
    # far from diagonal: the tool origin lies off the markers, so its position error follows the rotation's
    corr = C / np.sqrt(np.outer(np.diag(C), np.diag(C)))
    assert np.abs(corr[:3, 3:]).max() > 0.9


def test_conversion_keeps_readings_loads_tracker_and_noise():
    rng = np.random.default_rng(2)
    T = _random_poses(4, rng)
    W = se3.make(np.eye(3), [1.0, 2.0, 0.5])
    base = _markers(T, LAYOUT, 0.0, rng)
    ds = Dataset("markers", "klimchik3r", ("arm",), {"arm": rng.normal(size=(4, 3))},
                 {"p_tracker_marker": base.measured["p_tracker_marker"], "wrench_tool": rng.normal(size=(4, 6))},
                 {"T_world_tracker": W}, name="session", meta={"noise": {"position_m": 2e-5, "joint_rad": 1e-6}},
                 frames={"tracker": "lab", "markers": "tool_markers"})
    out = markers_to_pose(ds, LAYOUT)
    assert out.name == "session" and dict(out.frames) == {"tracker": "lab"}
    np.testing.assert_array_equal(out.q["arm"], ds.q["arm"])
    np.testing.assert_array_equal(out.measured["wrench_tool"], ds.measured["wrench_tool"])
    np.testing.assert_array_equal(out.known["T_world_tracker"], W)
    assert out.meta["noise"] == {"position_m": 2e-5, "joint_rad": 1e-6}
    # sigma from the stated position noise: the covariance scales with its square
    ratio = out.measured["pose_cov"] / markers_to_pose(ds, LAYOUT, sigma=1e-5).measured["pose_cov"]
    np.testing.assert_allclose(ratio[np.isfinite(ratio)], 4.0, rtol=1e-9)


@pytest.mark.parametrize("layout, y_bad, match", [
    (LAYOUT[:2], None, "at least 3 markers"),
    (np.array([[0.0, 0, 0], [0.1, 0, 0], [0.3, 0, 0]]), None, "collinear"),
    (LAYOUT, (2, 1), "sample 2"),
])
def test_bad_input_one_line_errors(layout, y_bad, match):
    rng = np.random.default_rng(3)
    ds = _markers(_random_poses(4, rng), layout, 0.0, rng)
    if y_bad is not None:
        y = np.array(ds.measured["p_tracker_marker"])
        y[y_bad] = np.nan
        ds = Dataset("markers", ds.robot, ds.arms, dict(ds.q), {"p_tracker_marker": y}, dict(ds.known))
    with pytest.raises((ShapeError, DegenerateExperimentError), match=match) as exc:
        markers_to_pose(ds, sigma=1e-5)
    assert "\n" not in str(exc.value)


def test_bad_input_without_layout_or_sigma_or_of_another_kind():
    rng = np.random.default_rng(4)
    ds = _markers(_random_poses(3, rng), LAYOUT, 0.0, rng)
    bare = Dataset("markers", ds.robot, ds.arms, dict(ds.q), dict(ds.measured))
    for call, match in ((lambda: markers_to_pose(bare), "p_tool_marker"),
                        (lambda: markers_to_pose(ds, sigma=0.0), "sigma > 0"),
                        (lambda: markers_to_pose(ds, LAYOUT[:3]), "layout p_tool_marker has 3"),
                        (lambda: markers_to_pose(markers_to_pose(ds, sigma=1e-5)), "expected kind 'markers'")):
        with pytest.raises(KincalError, match=match) as exc:
            call()
        assert "\n" not in str(exc.value)
