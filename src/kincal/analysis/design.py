"""Choosing configurations (design of experiments): greedy selection then Fedorov exchange over a candidate
pool, with rank-k updates of the information matrix.

Every candidate i contributes ``k`` whitened residual rows ``X_i`` (k, r) on the identifiable subspace (r
coordinates), and a design's information matrix is ``M = eps I + sum X_i^T X_i`` (``eps``: a tiny ridge so
the greedy start is defined; it is far below any candidate's information). Criteria, all "larger is better"
internally:

- ``D``: log det M (the volume of the confidence ellipsoid); ``A``: -trace M^-1 (sum of variances);
  ``E``: the smallest eigenvalue of M;
- ``O1``..``O5``: the observability indices of the singular values ``sqrt(eig M)``
  (``kincal.analysis.observability``);
- ``I`` and ``G``: minus the mean and the max over a workspace sample of the predicted tool variance
  ``trace(E_w M^-1 E_w^T)``, with ``E_w`` (c, r) the tool's sensitivity at sample w: what a user cares about.

Adding candidate i to M: with ``L L^T = M``, ``Y = X_i L^-T``, ``G = Y Y^T`` (k, k), ``H = (I + G)^-1`` and
``Z = X_i M^-1``, ``log det`` grows by ``log det(I + G)`` and ``M^-1`` shrinks by ``Z^T H Z`` (Woodbury), so
D, A, I and G are scored for every candidate at once from (N, k, r) arrays; spectral criteria take one batched
eigen-decomposition per step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular

from kincal.analysis.observability import MEANINGS, observability
from kincal.errors import ModelError

CRITERIA = ("D", "A", "E", "I", "G", "O1", "O2", "O3", "O4", "O5")
# Ridge of the start, relative to one average candidate's information: defines the criteria before the design
# has full rank without biasing it once it has.
RIDGE = 1e-8
# Candidates scored at once (bounds the (chunk, k, r) work arrays).
CHUNK = 4096
MAX_PASSES = 10
SPECTRAL = ("E", "O2", "O3", "O4", "O5")  # non-smooth in M: exchanged from random starts too
RESTARTS = 4


@dataclass(frozen=True)
class Selection:
    """``indices`` into the pool (selection order after exchanges), ``value`` of the criterion (as defined
    in the module docstring, larger is better), ``greedy``: the value after the greedy phase, ``exchanges``:
    swaps made."""

    indices: np.ndarray
    criterion: str
    value: float
    greedy: float
    exchanges: int


def information(X: np.ndarray) -> np.ndarray:
    """sum_i X_i^T X_i of candidate rows X (N, k, r)."""
    flat = X.reshape(-1, X.shape[-1])
    return flat.T @ flat


def criterion_value(M: np.ndarray, criterion: str, workspace: np.ndarray | None = None, configurations: int = 1):
    """The criterion (larger is better) of information M (r, r)."""
    _check(criterion, workspace)
    lam = np.linalg.eigvalsh(M)
    if criterion == "D":
        return float(np.sum(np.log(np.maximum(lam, 1e-300))))
    if criterion in ("A", "I", "G"):
        Minv = np.linalg.inv(M)
        if criterion == "A":
            return -float(np.trace(Minv))
        var = np.einsum("wcr,rs,wcs->w", workspace, Minv, workspace)
        return -float(var.mean() if criterion == "I" else var.max())
    return _spectral(np.sqrt(np.maximum(lam, 0))[None], criterion, configurations)[0]


def select(X: np.ndarray, K: int, criterion: str = "D", *, workspace: np.ndarray | None = None,
           exchange: bool = True, seed: int = 0) -> Selection:
    """Choose K of the N candidates X (N, k, r): greedy, then exchange passes (each selected configuration
    swapped for the best candidate while the criterion improves). The non-smooth criteria (E, O2..O5) also
    exchange from ``RESTARTS`` random starts and keep the best. Deterministic for a seed."""
    _check(criterion, workspace)
    N, k, r = X.shape
    if not 1 <= K <= N:
        raise ModelError(f"cannot choose {K} of {N} candidates")
    eps = RIDGE * max(np.trace(information(X)) / (N * r), 1e-300)
    chosen = _greedy(X, K, criterion, workspace, eps)
    greedy = criterion_value(eps * np.eye(r) + information(X[chosen]), criterion, workspace, K)
    if not exchange:
        return Selection(np.array(chosen), criterion, greedy, greedy, 0)
    best, value, swaps = _exchange(X, chosen, criterion, workspace, eps)
    if criterion in SPECTRAL:
        rng = np.random.default_rng(seed)
        for _ in range(RESTARTS):
            start = list(rng.choice(N, K, replace=False))
            other, v, n = _exchange(X, start, criterion, workspace, eps)
            swaps += n
            if v > value:
                best, value = other, v
    return Selection(np.array(best), criterion, value, greedy, swaps)


def _greedy(X, K, criterion, workspace, eps) -> list[int]:
    """Add the best candidate K times; until the design has full rank every criterion but D is flat in the
    missing directions, so D chooses until then."""
    r = X.shape[-1]
    M = eps * np.eye(r)
    chosen: list[int] = []
    for _ in range(K):
        full = np.linalg.eigvalsh(M)[0] > 1e3 * eps
        scores = _scores(M, X, criterion if full else "D", workspace, len(chosen) + 1)
        scores[chosen] = -np.inf
        i = int(np.argmax(scores))
        chosen.append(i)
        M = M + X[i].T @ X[i]
    return chosen


def _exchange(X, chosen, criterion, workspace, eps) -> tuple[list[int], float, int]:
    """Fedorov exchange from ``chosen``: (design, criterion value, swaps)."""
    chosen = list(chosen)
    K, r = len(chosen), X.shape[-1]
    M = eps * np.eye(r) + information(X[chosen])
    value, swaps = criterion_value(M, criterion, workspace, K), 0
    for _ in range(MAX_PASSES):
        changed = False
        for pos in range(K):
            out = chosen[pos]
            base = M - X[out].T @ X[out]
            scores = _scores(base, X, criterion, workspace, K)
            scores[chosen] = -np.inf
            j = int(np.argmax(scores))
            if scores[j] > value + 1e-9 * max(abs(value), 1.0):
                chosen[pos], M, value = j, base + X[j].T @ X[j], float(scores[j])
                swaps += 1
                changed = True
        if not changed:
            break
    return chosen, value, swaps


def _check(criterion: str, workspace) -> None:
    if criterion not in CRITERIA:
        raise ModelError(f"criterion {criterion!r}: expected one of {', '.join(CRITERIA)}")
    if criterion in ("I", "G") and workspace is None:
        raise ModelError(f"criterion {criterion}: needs a workspace sample (the tool's sensitivity there)")


def _scores(M: np.ndarray, X: np.ndarray, criterion: str, workspace, configurations: int) -> np.ndarray:
    """The criterion of ``M + X_i^T X_i`` for every candidate i, in chunks."""
    out = np.empty(len(X))
    if criterion == "O1":  # a monotone function of D for a fixed number of configurations
        return np.exp(_scores(M, X, "D", workspace, configurations) / (2 * X.shape[-1])) / np.sqrt(configurations)
    if criterion in SPECTRAL:
        for s in range(0, len(X), CHUNK):
            x = X[s: s + CHUNK]
            lam = np.linalg.eigvalsh(M + np.einsum("nkr,nks->nrs", x, x))
            out[s: s + CHUNK] = _spectral(np.sqrt(np.maximum(lam, 0))[:, ::-1], criterion, configurations)
        return out
    L = np.linalg.cholesky(M)
    Minv = np.linalg.inv(M)
    logdet = 2 * np.sum(np.log(np.diag(L)))
    chunk = CHUNK
    if criterion == "G":  # its work array is (chunk, w, k, c)
        chunk = max(1, int(CHUNK * 64 // (len(workspace) * X.shape[1] * workspace.shape[1])))
    for s in range(0, len(X), chunk):
        out[s: s + chunk] = _woodbury(M, L, Minv, logdet, X[s: s + chunk], criterion, workspace)
    return out


def _woodbury(M, L, Minv, logdet, x, criterion, workspace) -> np.ndarray:
    """Scores of D, A, I, G for the candidates x (n, k, r) added to M (module docstring)."""
    n, k, _ = x.shape
    Y = solve_triangular(L, x.reshape(-1, x.shape[-1]).T, lower=True).T.reshape(x.shape)  # X L^-T
    Gm = Y @ np.swapaxes(Y, 1, 2) + np.eye(k)
    if criterion == "D":
        return logdet + np.linalg.slogdet(Gm)[1]
    Z = x @ Minv  # (n, k, r)
    H = np.linalg.inv(Gm)
    if criterion == "A":
        return -(np.trace(Minv) - np.einsum("nab,nar,nbr->n", H, Z, Z))
    if criterion == "I":  # mean_w trace(H Z E_w^T E_w Z^T) = trace(H Z B Z^T) / W with B = sum_w E_w^T E_w
        B = np.einsum("wcr,wcs->rs", workspace, workspace)
        base = np.einsum("wcr,rs,wcs->", workspace, Minv, workspace)
        drop = np.einsum("nab,nar,rs,nbs->n", H, Z, B, Z, optimize=True)
        return -(base - drop) / len(workspace)
    EW = workspace @ Minv  # (w, c, r): E_w M^-1
    base = np.einsum("wcr,wcr->w", EW, workspace)  # trace(E_w M^-1 E_w^T)
    P = np.einsum("nkr,wcr->nwkc", x, EW)  # X M^-1 E_w^T per candidate and sample
    var = base[None, :] - np.einsum("nab,nwac,nwbc->nw", H, P, P)
    return -var.max(axis=1)


def _spectral(s: np.ndarray, criterion: str, configurations: int) -> np.ndarray:
    """Criterion per row of singular values s (n, r), descending."""
    if criterion == "E":
        return s[:, -1] ** 2
    s = np.maximum(s, 1e-300)
    if criterion == "O1":
        return np.exp(np.mean(np.log(s), axis=1)) / np.sqrt(configurations)
    if criterion == "O2":
        return s[:, -1] / s[:, 0]
    if criterion == "O3":
        return s[:, -1]
    if criterion == "O4":
        return s[:, -1] ** 2 / s[:, 0]
    return 1.0 / np.sum(1.0 / s, axis=1)


__all__ = ["CRITERIA", "MEANINGS", "Selection", "criterion_value", "information", "observability", "select"]
