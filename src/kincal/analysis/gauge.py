"""The gauge in which estimates and standard deviations are reported: ``min-change``.

When the data do not determine every parameter (a full POE model always has offsets trading off against the
later axes and home; an unknown tracker against the whole arm), many parameter values fit the data equally,
and which one the solver ends at is a matter of its path. kincal reports the estimate's displacement from
nominal split in two (to first order at the estimate):

- ``determined``: the change the data ask for, in the ``min-change`` gauge: of all displacements that fit the
  data equally, the one of least norm over the arm's coordinates (m and rad, 1 m counting as 1 rad); the
  experiment frames (tracker, plate, markers ...) take what is left (weight ``FRAME_WEIGHT``: they only break
  ties). Its standard deviations are finite for every coordinate.
- ``gauge_move``: the rest, a move along unidentifiable directions that changes no residual.

The standard deviation of ``determined`` is that of the estimate with its unidentifiable components removed
in this metric: ``P C P^T`` (local coordinates), ``P = I - N (M^T W M)^-1 M^T W D`` with ``N`` the null basis,
``D`` the derivative of the displacement, ``M = D N``, ``W`` the metric's weights.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kincal.analysis.naming import block_of
from kincal.params import Layout

NAME = "min-change"
DESCRIPTION = ("min-change: of all parameter values that fit the data equally, the displacement from nominal of "
               "least norm over the arm coordinates (m and rad, 1 m counting as 1 rad; experiment frames take "
               "what is left); first order at the estimate")
FRAME_WEIGHT = 1e-6  # experiment frames' weight in the metric: they only break ties


@dataclass(frozen=True, eq=False)
class GaugeView:
    """The estimate's displacement from nominal (free coordinates) split into the part the data determine (in
    the gauge ``name``) and a move along unidentifiable directions, with the determined part's covariance."""

    name: str
    description: str
    change: np.ndarray  # (p,) displacement from nominal, as solved
    determined: np.ndarray  # (p,) its part in the gauge
    gauge_move: np.ndarray  # (p,) change - determined: changes no residual (to first order)
    covariance: np.ndarray  # (p, p) of ``determined`` (displacement coordinates)
    local_covariance: np.ndarray  # (p, p) the same in local coordinates at the estimate (for propagation)

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0, None))


def weights(layout: Layout, free: np.ndarray) -> np.ndarray:
    """The metric of ``min-change`` per free coordinate: 1 on arm coordinates, ``FRAME_WEIGHT`` on frames."""
    return np.array([1.0 if block_of(layout, int(i)).arm is not None else FRAME_WEIGHT for i in free])


def min_change(change: np.ndarray, D: np.ndarray, null: np.ndarray, covariance: np.ndarray,
               w: np.ndarray) -> GaugeView:
    """``change`` (p,): displacement from nominal; ``D`` (p, p): its derivative w.r.t. local coordinates at the
    estimate; ``null`` (p, k): the unidentifiable directions (local, natural units); ``covariance`` (p, p) in
    any gauge (local); ``w`` (p,) the metric's weights."""
    p = len(change)
    if null.shape[1] == 0:
        P = np.eye(p)
        move = np.zeros(p)
    else:
        M = D @ null
        s = np.sqrt(w)[:, None]
        MtW = (M * w[:, None]).T
        coef = np.linalg.lstsq(s * M, s[:, 0] * change, rcond=None)[0]
        move = M @ coef
        P = np.eye(p) - null @ np.linalg.solve(MtW @ M, MtW @ D)
    local = P @ covariance @ P.T
    return GaugeView(NAME, DESCRIPTION, change, change - move, move, D @ local @ D.T, local)
