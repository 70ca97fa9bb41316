"""How errors in held (assumed-known) parameters spread into the estimates, to first order.

At a linearization with whitened Jacobian ``J`` (m, p) of the free coordinates and ``J_h`` (m, h) of the held
ones, an error ``e`` in the held values shifts the least-squares estimate by ``S e`` with

    S = -(J^T J)^+ J^T J_h

where ``(J^T J)^+`` is the covariance at unit variance factor in the solve's gauge (``analysis.covariance``):
the estimates absorb what they can of the held parameters' effect on the residuals. Whitening does not change
``S`` when every row carries its own stated noise, it only weights the rows as the solve does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kincal.errors import ShapeError


@dataclass(frozen=True, eq=False)
class Sensitivity:
    """``matrix`` (p, h): change of each free coordinate (rows, ``free``) per unit error of each held coordinate
    (columns, ``held``), natural units (m, rad)."""

    free: tuple[str, ...]
    held: tuple[str, ...]
    matrix: np.ndarray

    def shift(self, errors: dict[str, float]) -> np.ndarray:
        """(p,) change of the free coordinates for held errors {held name: error}, to first order."""
        e = np.zeros(len(self.held))
        for name, value in errors.items():
            if name not in self.held:
                raise ShapeError(f"held error for {name!r}: not a held parameter of this analysis; held: "
                                 f"{', '.join(self.held[:8])}{' ...' if len(self.held) > 8 else ''}")
            e[self.held.index(name)] = value
        return self.matrix @ e


def sensitivity(J: np.ndarray, J_held: np.ndarray, cov_unit: np.ndarray, free, held) -> Sensitivity:
    """``S = -C J^T J_h`` with ``C`` the unit-variance covariance (p, p) of the whitened problem J (m, p)."""
    if J.shape[0] != J_held.shape[0] or cov_unit.shape != (J.shape[1], J.shape[1]):
        raise ShapeError(f"sensitivity: J {J.shape}, J_held {J_held.shape} and covariance {cov_unit.shape} "
                         "do not match")
    return Sensitivity(tuple(free), tuple(held), -cov_unit @ (J.T @ J_held))
