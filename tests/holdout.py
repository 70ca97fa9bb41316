"""Held-out errors of calibrations on real data: k-fold cross-validation of tracker data sets (pose, markers)
and the consistency of socket data sets. Test helpers shared by tests/test_real_data.py and bench/real_data.py.

Held-out predictions use the calibrated arm *and* the frames estimated from the training folds (tracker,
marker positions): nothing is refitted on the held-out configurations, so the errors are what a user of the
calibrated model would see (refitting the tracker on the held-out data, as ``calibrate(validation=...)`` does,
would absorb part of the error).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from kincal.data import Dataset
from kincal.estimation import calibrate, crossval
from kincal.kinematics import forward_kinematics
from kincal.kinematics.branches import tree_loaded_kinematics
from kincal.lie import se3, so3


def folds(n: int, k: int, seed: int = 0) -> list[np.ndarray]:
    """k disjoint held-out index sets covering range(n), from one random permutation: the package's folds
    (``kincal.estimation.crossval.folds``) of one data set of n configurations."""
    return crossval.permuted_folds(n, k, np.random.default_rng(seed))


def honest_prediction(robot, ds: Dataset, free, k: int = 6, seed: int = 0, **options) -> crossval.CrossValidation:
    """The package's k-fold cross-validation (``calibrate``'s ``cv``) of one data set: held-out RMS against the
    RMS predicted from each fold's training fit alone (outlying held-out rows left out, as calibration does)."""
    return crossval.cross_validate([ds], k, lambda train: calibrate(robot, train, free, **options), seed)


def prediction_errors(result, ds: Dataset) -> tuple[np.ndarray, np.ndarray | None]:
    """Position errors (m; one per sample and marker) and orientation errors (rad; pose only, else None) of
    ``ds`` predicted by a calibration ``result`` with its estimated tracker (and markers). The tip is deflected by
    the robot's own weight when the model has one (``tree_loaded_kinematics``): a rigid prediction of a
    compliant calibration would score a model other than the one fitted."""
    arm = ds.arms[0]
    T = se3.inverse(result.extras[ds.frames.get("tracker", "tracker")]) @ tree_loaded_kinematics(result.robot, arm, ds.q).tool
    if ds.kind == "markers":
        x = np.asarray(result.extras[ds.frames.get("markers", "markers")])
        return np.linalg.norm(se3.transform_points(T[:, None], x) - ds.measured["p_tracker_marker"], axis=-1).ravel(), None
    meas = ds.measured["T_tracker_tool"]
    rot = np.linalg.norm(so3.log(T[:, :3, :3] @ np.swapaxes(meas[:, :3, :3], -1, -2)), axis=-1)
    return np.linalg.norm(T[:, :3, 3] - meas[:, :3, 3], axis=-1), rot


@dataclass(frozen=True)
class CrossValidation:
    position: np.ndarray  # held-out position errors (m), every fold
    orientation: np.ndarray | None  # held-out orientation errors (rad), pose only
    results: tuple  # one calibration Result per fold
    seconds: float  # wall time of all folds

    def summary(self) -> dict:
        out = {"pos_mean": self.position.mean(), "pos_rms": np.sqrt(np.mean(self.position**2)),
               "pos_max": self.position.max()}
        if self.orientation is not None:
            out |= {"ori_rms": np.sqrt(np.mean(self.orientation**2)), "ori_max": self.orientation.max()}
        return out


def cross_validate(robot, ds, free, k: int = 6, seed: int = 0, **options) -> CrossValidation:
    """Calibrate on k-1 folds, predict the held-out fold, for each of k folds (``options`` go to calibrate).
    ``ds``: one data set, or several whose rows were taken together (Justin's two hands: the same poses), which
    are split by the same folds and calibrated jointly."""
    sets = [ds] if isinstance(ds, Dataset) else list(ds)
    n = sets[0].size
    if any(d.size != n for d in sets):
        raise ValueError(f"joint folds need data sets of one size, got {[d.size for d in sets]}")
    pos, rot, results = [], [], []
    t0 = time.perf_counter()
    for test in folds(n, k, seed):
        train = np.setdiff1d(np.arange(n), test)
        res = calibrate(robot, [d.subset(train) for d in sets], free, **options)
        for d in sets:
            p, r = prediction_errors(res, d.subset(test))
            pos.append(p)
            rot.append(r)
        results.append(res)
    ori = None if rot[0] is None else np.concatenate(rot)
    return CrossValidation(np.concatenate(pos), ori, tuple(results), time.perf_counter() - t0)


def socket_consistency(model, datasets: list[Dataset]) -> tuple[np.ndarray, float]:
    """For the two socket data sets of one plate placement: mean distance (m) of the predicted tool points
    from their mean, per socket, and the distance between the two means (m)."""
    points = [forward_kinematics(model, ds.q[ds.arms[0]])[:, :3, 3] for ds in datasets]
    means = [p.mean(axis=0) for p in points]
    spread = np.array([np.linalg.norm(p - m, axis=-1).mean() for p, m in zip(points, means)])
    return spread, float(np.linalg.norm(means[0] - means[1]))
