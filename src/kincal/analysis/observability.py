"""Observability indices of an identification Jacobian (Sun and Hollerbach, "Observability index selection for
robot calibration", ICRA 2008): one number each for how well a set of configurations determines the
identifiable parameters.

They are computed from the singular values ``s_1 >= ... >= s_m`` of the whitened Jacobian restricted to the
identifiable subspace (``kincal.estimation.plan.identifiable_basis``), with lengths in units of a characteristic length of
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


def index(name: str, s: np.ndarray, configurations: int) -> np.ndarray:
    """Index ``name`` (``MEANINGS``) of every row of singular values s (n, m), descending and positive."""
    if name == "O1":
        return np.exp(np.mean(np.log(s), axis=1)) / np.sqrt(configurations)
    if name == "O2":
        return s[:, -1] / s[:, 0]
    if name == "O3":
        return s[:, -1]
    if name == "O4":
        return s[:, -1] ** 2 / s[:, 0]
    return 1.0 / np.sum(1.0 / s, axis=1)


def observability(singular_values: np.ndarray, configurations: int) -> Observability:
    """The indices of the (positive) singular values of the identifiable part, over ``configurations``."""
    s = np.sort(np.asarray(singular_values, float))[::-1]
    if s.ndim != 1 or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ShapeError(f"singular values: expected positive finite values, found {s!r}")
    if configurations < 1:
        raise ShapeError(f"configurations: expected at least 1, found {configurations}")
    if not len(s):
        return Observability(0.0, 0.0, 0.0, 0.0, 0.0, 0, configurations)
    return Observability(*(float(index(k, s[None], configurations)[0]) for k in MEANINGS), len(s), configurations)
