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

That split is first order at the point it is taken. Gauge moves of several cm (``frida_plate4`` at
``kinematic``) bend the orbit of equally fitting values enough to shift the first-order split by a hundred
standard deviations, so ``representative`` first walks the estimate along its orbit to the ``min-change``
point itself: a step removing the gauge move along the null directions, then a Gauss-Newton step on the
identifiable subspace restoring the fit, until the gauge move is below ``REPRESENTATIVE_TOL``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from kincal.analysis.identifiability import Identifiability
from kincal.analysis.linalg import lstsq
from kincal.analysis.linearization import Linearization
from kincal.analysis.naming import block_of
from kincal.params import Layout, State, displacement, recentre, retract

NAME = "min-change"
DESCRIPTION = ("min-change: of all parameter values that fit the data equally, the displacement from nominal of "
               "least norm over the arm coordinates (m and rad, 1 m counting as 1 rad; experiment frames take "
               "what is left)")
FRAME_WEIGHT = 1e-6  # experiment frames' weight in the metric: they only break ties
REPRESENTATIVE_TOL = 1e-9  # gauge move (norm, natural units) at which the walk to the min-change point stops
FIT_TOL = 1e-6  # whitened chi^2 a further Gauss-Newton step would win, below which the fit counts as restored
REPRESENTATIVE_STEPS = 8


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
    local_covariance: np.ndarray  # (p, p) the same in local coordinates at ``state`` (for propagation)
    state: State | None = None  # the values in the gauge (the min-change point), when the walk there was taken
    names: tuple[str, ...] = ()  # of the free coordinates

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0, None))

    def split(self, name: str) -> tuple[float, float, float]:
        """(determined, its standard deviation, gauge move) of the coordinate ``name``."""
        k = self.names.index(name)
        return float(self.determined[k]), float(self.std[k]), float(self.gauge_move[k])


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
        MtW = (M * w[:, None]).T
        move = M @ _gauge_coefficients(change, M, w)
        P = np.eye(p) - null @ np.linalg.solve(MtW @ M, MtW @ D)
    local = P @ covariance @ P.T
    return GaugeView(NAME, DESCRIPTION, change, change - move, move, D @ local @ D.T, local)


def _gauge_coefficients(change: np.ndarray, M: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``a`` minimizing ``|change - M a|_W``: the gauge move is ``M a``."""
    s = np.sqrt(w)
    return lstsq(s[:, None] * M, s * change)


def representative(state: State, nominal: State, layout: Layout, free: np.ndarray, w: np.ndarray,
                   relinearize: Callable[[State], tuple[Linearization, Identifiability]]):
    """The ``min-change`` point of the orbit of ``state`` (values fitting the data equally): ``(state, lin, ana)``
    there (after at most ``REPRESENTATIVE_STEPS``), or None when a step is not finite.
    ``relinearize(state)``: the problem's linearization and null space there. Each step removes the gauge move
    to first order (along the null directions) and restores the fit (Gauss-Newton on the identifiable
    subspace, from the triangular factor)."""
    s = state
    for _ in range(REPRESENTATIVE_STEPS):
        lin, ana = relinearize(s)
        d, D = displacement(s, nominal, layout)
        D = D[np.ix_(free, free)]
        N, R = ana.null_space, ana.range_space
        a = _gauge_coefficients(d[free], D @ N, w) if N.shape[1] else np.zeros(0)
        z = lstsq(lin.Rf @ R, -lin.qtr)
        gain = float(np.sum((lin.Rf @ R @ z) ** 2))  # whitened chi^2 the Gauss-Newton step would still win
        if np.linalg.norm(D @ N @ a) < REPRESENTATIVE_TOL and gain < FIT_TOL:
            return s, lin, ana
        delta = np.zeros(layout.size)
        delta[free] = R @ z - N @ a
        s = recentre(retract(s, layout, delta))
        if not np.all(np.isfinite(delta)):
            return None
    lin, ana = relinearize(s)
    return s, lin, ana
