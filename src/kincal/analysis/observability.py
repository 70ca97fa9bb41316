"""Observability indices of an identification Jacobian (Sun and Hollerbach, "Observability index selection for
robot calibration", ICRA 2008): one number each for how well a set of configurations determines the
identifiable parameters.

They are computed from the singular values ``s_1 >= ... >= s_m`` of the whitened Jacobian restricted to the
identifiable subspace (``identifiable_singular_values``), with lengths in units of a characteristic length of
the robot (its reach) and angles in rad, so that one set of configurations compares with another: the scaling
does not depend on the data (scaling every column to unit norm, as the rank test does, would hide how strongly
the configurations excite each parameter). ``N`` is the number of configurations; whitening makes the values
"per stated noise".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kincal.errors import ShapeError

MEANINGS = {
    "O1": "(s1...sm)^(1/m) / sqrt(N): volume of the confidence ellipsoid per configuration (D-optimality); "
          "larger is better",
    "O2": "s_min / s_max: inverse condition number; 1 means every direction is determined equally well",
    "O3": "s_min: the worst-determined direction (E-optimality); its standard deviation is 1/s_min in "
          "whitened, column-scaled units",
    "O4": "s_min^2 / s_max: noise amplification (O2 x O3)",
    "O5": "1 / sum(1/s_i): all directions together, dominated by the weakest (A-optimality-like)",
}


@dataclass(frozen=True)
class Observability:
    """The five indices (``MEANINGS``) from ``rank`` singular values over ``configurations``."""

    O1: float
    O2: float
    O3: float
    O4: float
    O5: float
    rank: int
    configurations: int

    def as_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in MEANINGS}


def identifiable_singular_values(R: np.ndarray, range_space: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Singular values of ``J D`` (``J`` given by its triangular factor R (q, p), ``D = diag(scale)``) on the
    identifiable subspace: ``range_space`` (p, r) in natural units, mapped to the scaled coordinates and
    orthonormalized there. Descending, (r,)."""
    if range_space.shape[1] == 0:
        return np.zeros(0)
    Q = np.linalg.qr(range_space / scale[:, None])[0]
    return np.linalg.svd((R * scale) @ Q, compute_uv=False)


def observability(singular_values: np.ndarray, configurations: int) -> Observability:
    """The indices of the (positive) singular values of the identifiable part, over ``configurations``."""
    s = np.sort(np.asarray(singular_values, float))[::-1]
    if s.ndim != 1 or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ShapeError(f"singular values: expected positive finite values, found {s!r}")
    if configurations < 1:
        raise ShapeError(f"configurations: expected at least 1, found {configurations}")
    if not len(s):
        return Observability(0.0, 0.0, 0.0, 0.0, 0.0, 0, configurations)
    m = len(s)
    o1 = float(np.exp(np.mean(np.log(s))) / np.sqrt(configurations))
    return Observability(o1, float(s[-1] / s[0]), float(s[-1]), float(s[-1] ** 2 / s[0]),
                         float(1.0 / np.sum(1.0 / s)), m, configurations)
