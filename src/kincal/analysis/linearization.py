"""What identifiability (and the solver's steps) read of one linearization of a calibration problem."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from kincal.analysis.linalg import norms

from kincal.params import State


@dataclass(frozen=True, eq=False)
class Linearization:
    """One evaluation at ``state``, reduced to the small triangular factor ``R`` of ``[J_free | J_fixed | r_len | r]``.

    Everything asked of a linearization (rank, null space, gauge, covariance, the Gauss-Newton convergence
    test, the scale test) depends on the tall whitened Jacobian only through its Gram matrix, so one QR serves
    them all: ``R[:p, :p]`` stands in for ``J_free``, the next columns for the fixed coordinates that scale with
    the robot and the residual's length part (only when ``fixed`` is given: the scale test), the last for the
    residual. The tall ``J`` is kept for the rotation test and the inner solve's first evaluation.
    """

    state: State
    r: np.ndarray  # (m,) whitened stacked residual: experiments, then prior rows, then constraint rows
    J: np.ndarray  # (m, p) whitened Jacobian of the free coordinates
    R: np.ndarray  # (q, p + len(fixed) + 2) or (q, p + 1) triangular factor, columns ordered as above
    W: tuple  # per experiment (N, k, k) whiteners (inverse Cholesky factors of the residual covariance)
    residuals: tuple  # per experiment (N, k) residual before whitening
    free: np.ndarray  # (p,) layout indices of the free coordinates: the columns of J
    fixed: np.ndarray | None = None  # layout indices of the fixed columns in R (with the length part), or None
    scale: np.ndarray | None = None  # the layout's scale direction at ``state`` (``params.scale_direction``), or None

    @cached_property  # asked at every step of a solve: read from the instance once known
    def p(self) -> int:
        return len(self.free)

    @property
    def every(self) -> bool:
        """Whether ``R`` has the fixed columns and the length part the scale test needs."""
        return self.fixed is not None

    @property
    def Rall(self) -> np.ndarray:
        """Columns of the free coordinates, then of the fixed ones in ``fixed`` (``every`` only)."""
        return self.R[:, :-2]

    @property
    def Rlen(self) -> np.ndarray:
        """The residual's length part (``every`` only)."""
        return self.R[:, -2]

    @cached_property
    def Rf(self) -> np.ndarray:
        return self.R[: self.p, : self.p]

    @cached_property
    def colnorm(self) -> np.ndarray:
        """Column norms of ``Rf``: those of the whitened Jacobian ``J`` (its triangular factor), computed once
        (read-only: the rank analysis shares it as its column scale, ``unit_columns``)."""
        c = norms(self.Rf, 0)
        c.flags.writeable = False
        return c

    @cached_property
    def qtr(self) -> np.ndarray:
        return self.R[: self.p, -1]

    @cached_property  # asked at every step, the convergence test and the rank analysis: computed once
    def cost2(self) -> float:
        return float(self.r @ self.r)


# A column whose norm is below this fraction of the largest (whitened units) is zero up to round-off: the
# parameter does not affect the residuals (a last joint turning a tool point on its own axis).
ZERO_COLUMN_RTOL = 1e-10


def unit_columns(J: np.ndarray, c: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(Js, c)``: J with every column scaled to unit norm, columns zero up to round-off (``ZERO_COLUMN_RTOL``)
    set exactly to zero, and the scale ``c`` (1 for those), so that ``J ~ Js * c``. ``c``: J's column norms when
    known (``Linearization.colnorm``), returned as they are when no column is zero."""
    if c is None:
        c = norms(J, 0)
    zero = c <= ZERO_COLUMN_RTOL * (c.max() if c.size else 0.0)
    if not zero.any():  # the common case: nothing to set
        return J / c, c
    c = np.where(zero, 1.0, c)
    Js = J / c
    Js[:, zero] = 0.0
    return Js, c
