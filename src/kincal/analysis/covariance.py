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
    S, Vt = right_svd(J @ range_space)
    inv = (Vt.T / S**2) @ Vt
    return sigma2 * range_space @ inv @ range_space.T


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
