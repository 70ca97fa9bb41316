"""Markers to pose (the partial-pose paper's "approach 1"): a rigid fit of a known marker layout to each row of a
``markers`` data set gives a ``pose`` data set, with the 6x6 covariance the fit implies.

Fit (per row, Kabsch): ``T = argmin sum_j |T x_j - y_j|^2`` with ``x_j`` the layout (``p_tool_marker``, tool
frame) and ``y_j`` the measured markers (tracker frame). Isotropic marker noise ``sigma`` makes it the maximum
likelihood pose.

Covariance, in the pose residual's convention (``kincal.experiments.pose``): the error
``e = (p_fit - p, log(R_fit R^T))`` (position of the tool origin and the left rotation increment, both in the
tracker frame). To first order ``T_fit x_j = T x_j + e_p - hat(R x_j) e_w``, so with
``A_j = [I, -hat(R x_j)]`` (3, 6) stacked over the markers, ``Cov(e) = sigma^2 (A^T A)^-1``. Since
``A_j = R [I, -hat(x_j)] blockdiag(R, R)^T``, that is ``B C0 B^T`` with ``B = blockdiag(R, R)`` and ``C0`` the
same for the layout in the tool frame: one 6x6 inverse for all rows.
"""

from __future__ import annotations

import numpy as np

from kincal.data import Dataset
from kincal.errors import DegenerateExperimentError, ShapeError
from kincal.experiments._kernel import fit_transform
from kincal.experiments.pose import file_line
from kincal.lie import so3
from kincal.noise import effective

# Below this ratio of the layout's second to first singular value, the markers are taken as collinear.
COLLINEAR_RATIO = 1e-6


def markers_to_pose(dataset: Dataset, p_tool_marker=None, sigma: float | None = None) -> Dataset:
    """The ``pose`` data set fitted to a ``markers`` data set, with its per-row covariance ``pose_cov`` (N, 6, 6).

    ``p_tool_marker`` (m, 3), m >= 3 non-collinear: the layout (default: the data set's known one);
    ``sigma`` (m): isotropic marker noise (default: the data set's stated position noise, else
    ``kincal.noise.DEFAULT``'s). Joint readings, loads, the tracker frame and stated noise carry over.
    """
    where = f"data set '{dataset.name}'"
    if dataset.kind != "markers":
        raise ShapeError(f"{where}: expected kind 'markers' to convert to poses, found '{dataset.kind}'")
    x = _layout(where, dataset, p_tool_marker)
    y = np.asarray(dataset.measured["p_tracker_marker"], dtype=float)
    if y.shape[1] != len(x):
        raise ShapeError(f"{where}: rows have {y.shape[1]} markers, the layout p_tool_marker has {len(x)}")
    bad = np.flatnonzero(~np.isfinite(y).all(axis=(1, 2)))
    if bad.size:
        raise ShapeError(f"{where}: sample {bad[0]}{file_line(dataset, bad[0])}, field p_tracker_marker: expected "
                         f"finite marker positions, found {y[bad[0]].tolist()}")
    if sigma is None:
        sigma = effective(None, dataset.meta.get("noise")).position
    if not (np.isfinite(sigma) and sigma > 0):
        raise ShapeError(f"{where}: expected a marker noise sigma > 0 (m), found {sigma!r}")
    T = fit_transform(x, y)  # Kabsch per row
    B = np.zeros(T.shape[:1] + (6, 6))
    B[:, :3, :3] = B[:, 3:, 3:] = T[:, :3, :3]
    cov = B @ layout_covariance(x, sigma) @ np.swapaxes(B, -1, -2)
    measured = {"T_tracker_tool": T, "pose_cov": 0.5 * (cov + np.swapaxes(cov, -1, -2))}
    if "wrench_tool" in dataset.measured:
        measured["wrench_tool"] = dataset.measured["wrench_tool"]
    known = {k: v for k, v in dataset.known.items() if k == "T_world_tracker"}
    frames = {k: v for k, v in dataset.frames.items() if k == "tracker"}
    return Dataset("pose", dataset.robot, dataset.arms, dict(dataset.q), measured, known, dataset.name,
                   dict(dataset.meta), frames)


def layout_covariance(x: np.ndarray, sigma: float) -> np.ndarray:
    """``sigma^2 (A^T A)^-1`` (6, 6) for the layout ``x`` in the tool frame, ``A_j = [I, -hat(x_j)]``: the
    covariance of the fitted pose's error (position, left rotation) at identity orientation."""
    A = np.zeros((len(x), 3, 6))
    A[:, :, :3] = np.eye(3)
    A[:, :, 3:] = -so3.hat(x)
    A = A.reshape(-1, 6)
    return sigma**2 * np.linalg.inv(A.T @ A)


def _layout(where: str, dataset: Dataset, p_tool_marker) -> np.ndarray:
    if p_tool_marker is None:
        p_tool_marker = dataset.known.get("p_tool_marker")
        if p_tool_marker is None:
            raise ShapeError(f"{where}: field p_tool_marker: expected the marker layout (known, or given), "
                             f"found none: the rigid fit needs it")
    x = np.asarray(p_tool_marker, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3 or not np.isfinite(x).all():
        raise ShapeError(f"{where}: field p_tool_marker: expected finite (m, 3) marker positions, found shape "
                         f"{x.shape}")
    if len(x) < 3:
        raise DegenerateExperimentError(f"{where}: field p_tool_marker: expected at least 3 markers for a pose, "
                                        f"found {len(x)}")
    s = np.linalg.svd(x - x.mean(axis=0), compute_uv=False)
    if s[1] <= COLLINEAR_RATIO * s[0]:
        raise DegenerateExperimentError(f"{where}: field p_tool_marker: expected markers not on one line, found "
                                        f"them collinear (singular values {s[0]:.3g}, {s[1]:.3g}): the rotation "
                                        f"about that line is not measured")
    return x

