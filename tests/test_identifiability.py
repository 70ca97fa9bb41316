"""Rank, named null directions, the user's gauge priority, scale detection and covariance."""

import numpy as np

from kincal.analysis import analyse, correlated_pairs, covariance, select_columns
from kincal.data import Dataset
from kincal.estimation import calibrate
from kincal.kinematics import Robot, forward_kinematics
from kincal.lie import se3
from kincal.testing import random_arm


def test_rank_and_reduced_directions(rng):
    A = rng.normal(size=(30, 3))
    J = np.column_stack([A, A[:, 0] - 2 * A[:, 1], np.zeros(30)])  # col 3 = col0 - 2 col1, col 4 inert
    ana = analyse(J, ["a", "b", "c", "d", "e"], priority=[3, 4, 0, 1, 2])
    assert ana.rank == 3 and ana.deficiency == 2
    assert list(ana.identifiable) == [False, False, True, False, False]
    piv = {d.pivot: d for d in ana.directions}
    assert set(piv) == {"d", "e"}
    assert dict(piv["d"].partners) == {"a": -1.0, "b": 2.0} or np.allclose(
        [dict(piv["d"].partners)[k] for k in "ab"], [-1.0, 2.0])
    assert "does not affect any residual" in piv["e"].words
    np.testing.assert_allclose(J @ ana.null_space, 0.0, atol=1e-12)
    assert select_columns(J, [3, 0, 1, 2, 4], ana.rank) == [0, 2, 3]


def test_a_column_zero_up_to_round_off_is_zero(rng):
    """Issue 9, finding 2: a column at round-off (a tool point on its last joint's axis) used to be rescaled to
    unit length and looked identifiable; below 1e-10 of the largest column norm it is zero."""
    A = rng.normal(size=(30, 3))
    J = np.column_stack([A, 1e-17 * rng.normal(size=30)])
    ana = analyse(J, ["a", "b", "c", "d"])
    assert ana.rank == 3 and list(ana.identifiable) == [True, True, True, False]
    assert "does not affect any residual" in ana.directions[0].words
    assert select_columns(J, [3, 0, 1, 2], ana.rank) == [0, 1, 2]
    J[:, 3] = 1e-9 * rng.normal(size=30)  # small but real: identifiable
    assert analyse(J, ["a", "b", "c", "d"]).rank == 4


def test_covariance_is_inverse_normal_matrix_on_the_range(rng):
    J = rng.normal(size=(40, 4))
    cov = covariance(J, np.eye(4), 2.0)
    np.testing.assert_allclose(cov, 2.0 * np.linalg.inv(J.T @ J), rtol=1e-10)
    C = np.array([[1.0, 0.99], [0.99, 1.0]])
    assert correlated_pairs(C, ["x", "y"], 0.9) == [("x", "y", 0.99)]


def test_tracker_pose_data_identify_everything_but_redundancies(rng):
    """Full pose of a 6-DOF arm, tracker frame unknown: offsets are redundant with twists and home (6) and the
    tracker frame with moving the whole chain rigidly (6, base not free); scale is measured by the tracker."""
    true = random_arm(rng, 6, name="arm")
    nominal = true.replace(offsets=np.zeros(6))
    q = rng.uniform(-2, 2, (30, 6))
    W = se3.exp(np.array([0.3, -0.2, 1.0, 0.1, 0.2, -0.3]))
    ds = Dataset("pose", "r", ("arm",), {"arm": q}, {"T_tracker_tool": se3.inverse(W) @ forward_kinematics(true, q)})
    res = calibrate(Robot("r", {"arm": nominal}), [ds], "kinematic")
    ana = res.identifiability
    assert res.status == "converged"
    assert ana.deficiency == 12 and not ana.scale_unidentifiable
    pivots = [d.pivot for d in ana.directions]
    assert pivots[:6] == [f"arm.j{i}.offset" for i in range(1, 7)]
    assert not res.estimate("tracker.v_x").identifiable
    assert max(s.position_max for s in res.after) < 1e-9


def test_priority_gauge_holds_the_named_parameters(rng):
    """Gauge ['*.offset']: keep offsets as estimated parameters; dependent twist coordinates are held instead."""
    true = random_arm(rng, 6, name="arm")
    q = rng.uniform(-2, 2, (30, 6))
    ds = Dataset("pose", "r", ("arm",), {"arm": q}, {"T_tracker_tool": forward_kinematics(true, q)},
                 {"T_world_tracker": np.eye(4)})
    nominal = Robot("r", {"arm": true.replace(offsets=np.zeros(6))})
    res = calibrate(nominal, [ds], "kinematic", gauge=["*.offset"])
    np.testing.assert_allclose([res.estimate(f"arm.j{i}.offset").value for i in range(1, 7)], true.offsets, atol=1e-9)


def test_weak_directions_below_a_singular_value_gap_are_reported():
    """A cluster far below the rest (400x gap, below 1e-3) is weak even above the fixed 1e-5 threshold."""
    rng = np.random.default_rng(3)
    U, _ = np.linalg.qr(rng.normal(size=(40, 5)))
    V, _ = np.linalg.qr(rng.normal(size=(5, 5)))
    names = [f"p{i}" for i in range(5)]
    gap = analyse(U @ np.diag([1.0, 0.5, 0.03, 7e-5, 2e-5]) @ V.T, names)
    assert gap.rank == 5 and len(gap.weak) == 2
    smooth = analyse(U @ np.diag([1.0, 0.1, 1e-2, 1e-3, 1e-4]) @ V.T, names)
    assert smooth.rank == 5 and len(smooth.weak) == 0


def test_right_svd_falls_back_when_lapack_divide_and_conquer_fails(monkeypatch):
    """gesdd fails to converge on rare matrices (met on a UR10 marker problem): the QR-reduced SVD then uses
    gesvd instead of raising numpy's LinAlgError out of the solver."""
    import sys

    cov_module = sys.modules["kincal.analysis.covariance"]  # the package exports a function of the same name
    A = np.random.default_rng(0).normal(size=(40, 6))
    expected = np.linalg.svd(A, compute_uv=False)

    def failing(*args, **kwargs):
        raise np.linalg.LinAlgError("SVD did not converge")

    monkeypatch.setattr(cov_module.np.linalg, "svd", failing)
    S, Vt = cov_module.right_svd(A)
    np.testing.assert_allclose(S, expected, rtol=1e-12)
    np.testing.assert_allclose(np.abs(Vt @ Vt.T), np.eye(6), atol=1e-12)
