"""The rank analysis of a solve's last linearization carried from an earlier one (``carried_analysis``): where the
Gauss-Newton step carried there (``estimation.steps.carried_step``) is negligible, the result's rank, null space
and covariance come from that step's factor, without an SVD of its own.

The carried step proves that the linearization keeps the earlier analysis' numerical rank. The result needs
more, each checked here or the caller analyses afresh (``identify``):
- no identifiable direction is weak: with ``Rf VP = Q R`` and ``G = VP R^-1``, ``Rs B = Q`` for ``B = diag(c) G``
  (``Rs``: the column-scaled factor), so by Courant-Fischer on span(B) the r-th singular value of ``Rs`` is at
  least ``1 / |B|_2 >= 1 / |B|_F`` (tight where B's columns are near the singular vectors: ``|B|_F^2`` sums
  ``1 / s_i^2``), and its largest is at most ``|Rs|_F``; a ratio of ``WEAK_CEILING`` or more leaves no weak
  direction;
- the carried null space ``N`` is a null space to round-off: ``|Rs Ns|`` at most ``factor.GAP`` of that floor
  (as ``Factor`` requires of an SVD), so the covariance ``V (V^T Rf^T Rf V)^-1 V^T`` is ``P_V G G^T P_V`` with
  ``G = VP R^-1`` (``Rf G = Q``), without a decomposition;
- no exact gauge or symmetry of the cost is lifted out of it (``hold_exact`` with the symmetries ``identify``
  holds), and no scale test applies (``lin.every``: ``identify`` would solve for the scale direction).
The words (named directions, spectrum, degenerate judgement) come from a rank analysis of the linearization
when a report is read (``estimation.result.FinalReport``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from kincal.analysis.factor import GAP
from kincal.analysis.identifiability import IDENTIFIABLE_TOL, WEAK_CEILING, hold_exact
from kincal.analysis.linalg import norm, norms, null_and_range
from kincal.analysis.linearization import Linearization, unit_columns
from kincal.analysis.symmetries import Structure, consistent_nulls, rotation_nulls
from kincal.params import Layout


@dataclass(frozen=True, eq=False)
class CarriedFactor:
    """``Rf G`` with orthonormal columns (G, p x rank, spans the identifiable part) and ``Rf`` negligible on the
    null space: ``Factor.covariance`` for a carried factor."""

    G: np.ndarray

    def covariance(self, V: np.ndarray, sigma2: float = 1.0) -> np.ndarray:
        """``sigma2 * V (V^T Rf^T Rf V)^-1 V^T`` for ``V`` (p, rank) an orthonormal basis of the identifiable
        subspace: with ``V = G X + N Y``, ``V^T Rf^T Rf V = X^T X``, so the covariance is ``P_V G G^T P_V``."""
        Z = (self.G.T @ V) @ V.T  # (P_V G)^T
        return sigma2 * (Z.T @ Z)


@dataclass(frozen=True, eq=False)
class CarriedAnalysis:
    """What ``identify(report=False)`` gives a solve's result (rank, null and identifiable subspaces, which
    coordinates are identifiable, the covariance's factor; nothing weak), carried (module docstring)."""

    names: tuple[str, ...]
    rank: int
    rtol: float
    null_space: np.ndarray  # (p, k) orthonormal, natural units
    range_space: np.ndarray  # (p, p - k) its orthonormal complement
    identifiable: np.ndarray  # (p,) bool
    factor: CarriedFactor
    weak: tuple[str, ...] = ()


def carried_analysis(lin: Linearization, layout: Layout, experiments: Sequence, rtol: float, names: Sequence[str],
                     null: np.ndarray, range_space: np.ndarray, VP: np.ndarray, inverse: np.ndarray,
                     structure: Structure | None = None) -> CarriedAnalysis | None:
    """The analysis of ``lin`` from a step carried to it (``null``, ``range_space``: its null space and complement;
    ``VP``, ``inverse``: the preconditioned basis and ``(R^-1)`` of ``Rf VP = Q R``), or None where one of the
    module docstring's conditions fails."""
    if lin.every:
        return None
    if structure is not None and not structure.fits(lin, layout, experiments, rtol):
        structure = None
    Rs, c = unit_columns(lin.Rf, lin.colnorm)
    G = VP @ inverse  # Rf G = Q: orthonormal columns
    floor = 1.0 / norm(c[:, None] * G)  # at most the r-th singular value of Rs
    if not floor >= WEAK_CEILING * norm(Rs):
        return None
    Ns = null_and_range(c[:, None] * null)[0]  # the null space in scaled coordinates, orthonormal
    if not norm(Rs @ Ns) <= GAP * floor:
        return None
    held = rotation_nulls(lin, layout, experiments, structure)
    gauges = consistent_nulls(lin, layout, experiments, rtol, Ns.shape[1], structure=structure)
    rank, lifted = hold_exact(Ns, c, held, False, gauges)[1:3]
    if lifted:
        return None
    return CarriedAnalysis(tuple(names), rank, rtol, null, range_space, norms(Ns, 1) < IDENTIFIABLE_TOL,
                           CarriedFactor(G))
