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

from kincal.analysis.observability import index
from kincal.errors import ModelError

CRITERIA = ("D", "A", "E", "I", "G", "O1", "O2", "O3", "O4", "O5")
# Ridge of the start, relative to one average candidate's information: defines the criteria before the design
# has full rank without biasing it once it has.
RIDGE = 1e-8
# Candidates scored at once (bounds the (chunk, k, r) work arrays).
CHUNK = 4096
MAX_PASSES = 10
# A D-exchange swap must raise log det by this much (0.01 % of the determinant): smaller gains are round-off's
# or not worth another pass over the pool.
D_GAIN = 1e-4
SPECTRAL = ("E", "O2", "O3", "O4", "O5")  # non-smooth in M: exchanged from random starts too
RESTARTS = 8
SMOOTHING = (1, 4, 16)  # exponents p of phi_p on the way to a spectral criterion


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
    """The criterion (larger is better) of information M (r, r); an integer p: Kiefer's phi_p."""
    if not isinstance(criterion, int):
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
    return float(_spectral(np.sqrt(np.maximum(lam, 0))[None, ::-1], criterion, configurations)[0])


def select(X: np.ndarray, K: int, criterion: str = "D", *, workspace: np.ndarray | None = None,
           exchange: bool = True, seed: int = 0, base: np.ndarray | None = None) -> Selection:
    """Choose K of the N candidates X (N, k, r): greedy, then exchange passes (each selected configuration
    swapped for the best candidate while the criterion improves). The non-smooth criteria (E, O2..O5) also
    exchange from ``RESTARTS`` random starts and keep the best. ``base`` (r, r): information already at hand
    (an existing calibration's data) that the chosen candidates add to. Deterministic for a seed."""
    _check(criterion, workspace)
    N, k, r = X.shape
    if not 1 <= K <= N:
        raise ModelError(f"cannot choose {K} of {N} candidates")
    eps = RIDGE * max(np.trace(information(X)) / (N * r), 1e-300)
    M0 = eps * np.eye(r) + (0.0 if base is None else base)
    chosen = _greedy(X, K, criterion, workspace, M0, eps)
    greedy = criterion_value(M0 + information(X[chosen]), criterion, workspace, K)
    if not exchange:
        return Selection(np.array(chosen), criterion, greedy, greedy, 0)
    best, value, swaps = _exchange_smoothed(X, chosen, criterion, workspace, M0)
    if criterion in ("A", "I", "G"):  # also from the D-optimal design: a good start for variance criteria
        other, v, n = _exchange(X, _exchange_d(X, _greedy_d(X, K, M0), M0)[0], criterion, workspace, M0)
        swaps += n
        if v > value:
            best, value = other, v
    if criterion in SPECTRAL:
        rng = np.random.default_rng(seed)
        for _ in range(RESTARTS):
            other, v, n = _exchange_smoothed(X, list(rng.choice(N, K, replace=False)), criterion, workspace, M0)
            swaps += n
            if v > value:
                best, value = other, v
    return Selection(np.array(best), criterion, value, greedy, swaps)


def _greedy(X, K, criterion, workspace, M0, eps) -> list[int]:
    """Add the best candidate K times; until the design has full rank every criterion but D is flat in the
    missing directions, so D chooses until then."""
    if criterion in ("D", "O1"):
        return _greedy_d(X, K, M0)
    M = M0
    chosen: list[int] = []
    for _ in range(K):
        full = np.linalg.eigvalsh(M)[0] > 1e3 * eps
        scores = _scores(M, X, criterion if full else "D", workspace, len(chosen) + 1)
        scores[chosen] = -np.inf
        i = int(np.argmax(scores))
        chosen.append(i)
        M = M + X[i].T @ X[i]
    return chosen


def _exchange_smoothed(X, chosen, criterion, workspace, M0):
    """Exchange for ``criterion``; the smallest eigenvalue (E, O3: single swaps stall where several eigenvalues
    tie) first through Kiefer's smooth phi_p = -(mean lambda^-p)^(1/p), p = 1, 4, 16, which
    tends to the smallest eigenvalue as p grows."""
    swaps = 0
    if criterion in ("E", "O3"):
        for p in SMOOTHING:
            chosen, _, n = _exchange(X, chosen, p, workspace, M0)
            swaps += n
    chosen, value, n = _exchange(X, chosen, criterion, workspace, M0)
    return chosen, value, swaps + n


def _exchange(X, chosen, criterion, workspace, M0) -> tuple[list[int], float, int]:
    """Fedorov exchange from ``chosen``: (design, criterion value, swaps)."""
    if criterion in ("D", "O1"):
        chosen, _, swaps = _exchange_d(X, chosen, M0)
        return chosen, criterion_value(M0 + information(X[chosen]), criterion, workspace, len(chosen)), swaps
    chosen = list(chosen)
    K = len(chosen)
    M = M0 + information(X[chosen])
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


class _LogDet:
    """D-optimal bookkeeping with rank-k updates: ``M``, ``M^-1``, ``log det M`` and, for every candidate,
    ``G_i = X_i M^-1 X_i^T`` (k, k), kept current as candidates are added and removed (Woodbury), so that
    scoring all candidates costs O(N k^2 r) per step instead of O(N k r^2)."""

    def __init__(self, X: np.ndarray, M: np.ndarray):
        self.X, self.flat = X, X.reshape(-1, X.shape[-1])
        self.reset(M)

    def reset(self, M: np.ndarray) -> None:
        """Recompute from ``M`` (also against drift after many updates)."""
        self.M, self.Minv = M, np.linalg.inv(M)
        self.logdet = float(np.linalg.slogdet(M)[1])
        Y = (self.flat @ self.Minv).reshape(self.X.shape)
        self.G = Y @ np.swapaxes(self.X, 1, 2)

    def scores(self, G=None, logdet=None) -> np.ndarray:
        """log det of M (or the ``G``, ``logdet`` given) with each candidate added."""
        G = self.G if G is None else G
        return (self.logdet if logdet is None else logdet) + _logdet_plus_identity(G)

    def _cross(self, i: int, sign: float):
        """(Z_i, U, C): Z_i = X_i M^-1, U = X Z_i^T per candidate (N, k, k), C = (I + sign G_i)^-1."""
        Z = self.X[i] @ self.Minv
        U = (self.flat @ Z.T).reshape(self.X.shape[0], -1, Z.shape[0])
        C = np.linalg.inv(np.eye(Z.shape[0]) + sign * self.G[i])
        return Z, U, C

    def without(self, i: int):
        """(G, logdet) of M with candidate i removed, not committed."""
        _, U, C = self._cross(i, -1.0)
        return self.G + _sandwich(U, C), self.logdet + float(np.linalg.slogdet(np.linalg.inv(C))[1])

    def add(self, i: int, sign: float = 1.0) -> None:
        """Commit adding (sign 1) or removing (sign -1) candidate i."""
        Z, U, C = self._cross(i, sign)
        self.logdet -= float(np.linalg.slogdet(C)[1])
        self.G = self.G - sign * _sandwich(U, C)
        self.Minv = self.Minv - sign * (Z.T @ C @ Z)
        self.M = self.M + sign * (self.X[i].T @ self.X[i])


def _sandwich(U: np.ndarray, C: np.ndarray) -> np.ndarray:
    """U_i C U_i^T for every i: (N, k, k) (batched matmul: several times faster than einsum here)."""
    N, k, _ = U.shape
    return (U.reshape(-1, k) @ C).reshape(N, k, k) @ np.swapaxes(U, 1, 2)


def _logdet_plus_identity(G: np.ndarray) -> np.ndarray:
    """log det(I + G_i) for symmetric positive semi-definite G (N, k, k); closed forms for k <= 3 (batched
    LAPACK calls on tiny matrices cost more than the arithmetic)."""
    k = G.shape[-1]
    A = G + np.eye(k)
    if k == 1:
        det = A[:, 0, 0]
    elif k == 2:
        det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
    elif k == 3:
        det = np.einsum("ni,ni->n", A[:, 0], np.cross(A[:, 1], A[:, 2]))
    else:
        try:
            return 2 * np.log(np.diagonal(np.linalg.cholesky(A), axis1=1, axis2=2)).sum(axis=1)
        except np.linalg.LinAlgError:  # a chosen candidate's own downdate may be singular at round-off
            sign, logdet = np.linalg.slogdet(A)
            return np.where(sign > 0, logdet, -np.inf)
    return np.log(np.maximum(det, 1e-300))  # round-off can leave a chosen candidate's downdate at <= 0


def _greedy_d(X, K, M0) -> list[int]:
    st = _LogDet(X, M0.copy())
    chosen: list[int] = []
    for _ in range(K):
        sc = st.scores()
        sc[chosen] = -np.inf
        i = int(np.argmax(sc))
        chosen.append(i)
        st.add(i)
    return chosen


def _exchange_d(X, chosen, M0) -> tuple[list[int], float, int]:
    """Fedorov exchange for D with the rank-k bookkeeping of ``_LogDet``."""
    chosen = list(chosen)
    st = _LogDet(X, M0 + information(X[chosen]))
    swaps = 0
    for _ in range(MAX_PASSES):
        changed = False
        for pos in range(len(chosen)):
            out = chosen[pos]
            G, logdet = st.without(out)
            sc = st.scores(G, logdet)
            sc[chosen] = -np.inf
            j = int(np.argmax(sc))
            if sc[j] > st.logdet + D_GAIN:
                st.add(out, -1.0)
                st.add(j)
                chosen[pos] = j
                swaps += 1
                changed = True
        st.reset(st.M)
        if not changed:
            break
    return chosen, st.logdet, swaps


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
    if criterion in SPECTRAL or isinstance(criterion, int):
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


def _spectral(s: np.ndarray, criterion, configurations: int) -> np.ndarray:
    """Criterion per row of singular values s (n, r), descending; an integer p: Kiefer's phi_p of s^2."""
    if isinstance(criterion, int):
        lam = np.maximum(s, 1e-150) ** 2
        return -np.mean(lam ** -float(criterion), axis=1) ** (1.0 / criterion)
    if criterion == "E":
        return s[:, -1] ** 2
    return index(criterion, np.maximum(s, 1e-300), configurations)
