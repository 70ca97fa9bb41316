"""The rank analysis' own SVD of a linearization's triangular factor, reused where the null space is exactly its
trailing directions: the Gauss-Newton step and the covariance on the identifiable subspace then need no other
decomposition.

``identify`` decomposes the column-scaled factor ``Rf / c = U S Vt`` (``identifiability._spectrum``). Where its
null space is that SVD's trailing ``p - r`` directions (nothing lifted, pinned or held), ``Rf`` restricted to the
identifiable subspace is ``B = U1 S1 V1^T diag(c)`` up to the excluded singular values, which the gap test
(``GAP``) bounds far below round-off of the kept ones."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# The first excluded singular value must be below this fraction of the last kept one: the part of ``Rf`` the
# truncation drops then changes a step or a covariance by less than that, relative (exact symmetries sit at
# round-off, about 1e-16). Above it (a direction just under the rank threshold) callers decompose again.
GAP = 1e-10


@dataclass(frozen=True, eq=False)
class Factor:
    """``Rf ~ U[:, :rank] diag(S[:rank]) Vt[:rank] diag(c)``: the analysed factor's identifiable part."""

    U: np.ndarray  # (m, p) left singular vectors of the column-scaled factor
    S: np.ndarray  # (p,) its singular values, descending
    Vt: np.ndarray  # (p, p) right singular vectors (scaled coordinates)
    c: np.ndarray  # (p,) the column scale
    rank: int

    @classmethod
    def of(cls, U: np.ndarray, S: np.ndarray, Vt: np.ndarray, c: np.ndarray, rank: int) -> "Factor | None":
        """The factor, or None without an identifiable direction or where the excluded singular values are not
        negligible against the kept ones (``GAP``)."""
        if rank == 0 or U.shape[1] < rank or (rank < len(S) and not S[rank] <= GAP * S[rank - 1]):
            return None
        return cls(U, S, Vt, c, rank)

    def step(self, b: np.ndarray) -> np.ndarray:
        """A least-squares solution ``d`` (natural units) of ``Rf d = b`` on the identifiable part: any other
        differs by an unidentifiable direction, so its component in the identifiable subspace ``V`` is ``V^T d``."""
        r = self.rank
        return (self.Vt[:r].T @ ((self.U[:, :r].T @ b) / self.S[:r])) / self.c

    def inverse_gram_root(self, V: np.ndarray) -> np.ndarray:
        """``M^-1`` (rank x rank) for ``V`` (p, rank) an orthonormal basis of the identifiable subspace, ``Rf V = U1 M``
        (``covariance``): ``Rf V M^-1 = U1`` has orthonormal columns."""
        r = self.rank
        return (((self.Vt[:r] / self.c) / self.S[:r, None]) @ V).T

    def covariance(self, V: np.ndarray, sigma2: float = 1.0) -> np.ndarray:
        """``sigma2 * V (V^T Rf^T Rf V)^-1 V^T`` (``covariance.covariance``) for ``V`` (p, rank) an orthonormal basis
        of the identifiable subspace: ``Rf V = U1 M`` with ``M = S1 V1^T diag(c) V`` square, so the inverse Gram
        matrix is ``M^-1 M^-T``; and ``M^-1 = V^T diag(c)^-1 V1 S1^-1`` without a solve, since ``diag(c)`` maps the
        null space (``V``'s complement) into the scaled null space, orthogonal to ``V1``."""
        r = self.rank
        W = (self.Vt[:r] / self.c) / self.S[:r, None]  # S1^-1 V1^T diag(c)^-1
        Z = (W @ V) @ V.T  # (V M^-1)^T
        return sigma2 * (Z.T @ Z)
