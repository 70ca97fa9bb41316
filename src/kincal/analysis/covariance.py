"""Parameter covariance in the gauge of the solve, and strongly correlated parameter pairs by name."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from kincal.analysis.linalg import svd


def right_svd(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values and right singular vectors (S, Vt) of A (m, p) without forming the m x p left factor.

    For a tall A (a whitened Jacobian has thousands of rows) the SVD of R from ``A = QR`` gives the same
    S and Vt in a fraction of the time and without squaring the condition number as ``A^T A`` would.
    """
    m, p = A.shape
    if m > 2 * p:
        A = np.linalg.qr(A, mode="r")
    _, S, Vt = svd(A, full_matrices=False)
    return S, Vt


def covariance(J: np.ndarray, range_space: np.ndarray, sigma2: float = 1.0) -> np.ndarray:
    """``sigma2 * V (V^T J^T J V)^-1 V^T`` for whitened J (m, p) restricted to the identifiable subspace V (p, r).

    Directions outside V (unidentifiable, held by the gauge) get zero variance here; callers report those
    parameters as unidentifiable rather than as exact.
    """
    return sigma2 * range_space @ _gram_inverse(J @ range_space) @ range_space.T


def sandwich(J: np.ndarray, meat: np.ndarray, range_space: np.ndarray, sigma2: float = 1.0) -> np.ndarray:
    """``sigma2 * V B^-1 V^T meat V B^-1 V^T`` with ``B = V^T J^T J V``: the covariance of the least-squares fit
    of whitened J (m, p) on the subspace V (p, r) when the whitened residual's covariance is ``Omega`` rather than
    the identity, ``meat = J^T Omega J`` (p, p). With ``Omega = I`` it is ``covariance``."""
    V = range_space
    Binv = _gram_inverse(J @ V)
    return sigma2 * V @ Binv @ (V.T @ meat @ V) @ Binv @ V.T


def weighted_fit_dof(J: np.ndarray, meat: np.ndarray, fisher: np.ndarray, range_space: np.ndarray, m: int,
                     rank: int) -> float:
    """The expected chi^2 of the residuals of that fit whitened by ``Omega`` (``fisher = J^T Omega^-1 J``):
    ``m - 2 rank + tr(F C)``, C the unscaled sandwich on V. Its excess over ``m - rank`` is the
    chi^2 the fit loses against the best weighted one (zero when ``Omega = I``)."""
    C = sandwich(J, meat, range_space)
    return m - 2.0 * rank + float(np.sum(fisher * C.T))


def _gram_inverse(A: np.ndarray) -> np.ndarray:
    """``(A^T A)^-1`` from the SVD of A (``right_svd``)."""
    S, Vt = right_svd(A)
    return (Vt.T / S**2) @ Vt


def correlated_pairs(cov: np.ndarray, names: Sequence[str], threshold: float = 0.9, mask=None):
    """[(name_a, name_b, rho)] with |rho| >= threshold, strongest first; ``mask`` limits to some parameters."""
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    ok = std > 0 if mask is None else (std > 0) & np.asarray(mask)
    idx = np.flatnonzero(ok)
    out = []
    for a_i, a in enumerate(idx):
        for b in idx[a_i + 1:]:
            rho = cov[a, b] / (std[a] * std[b])
            if abs(rho) >= threshold:
                out.append((names[a], names[b], float(rho)))
    return sorted(out, key=lambda t: -abs(t[2]))
