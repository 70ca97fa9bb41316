"""D-optimal selection scoring the whole pool at once, for candidates of few rows (``kincal.analysis.design``
chooses it by the cost of an exact score).

Every candidate j's ``G_j = X_j M^-1 X_j^T`` (k, k) is held for the whole pool as one (k, k, N) array. Adding
or removing candidate i changes M by a rank-k term, and by Woodbury every ``G_j`` by
``-/+ W_j C W_j^T`` with ``W_j = X_j M^-1 X_i^T`` and ``C = (I +/- G_i)^-1``: one skinny product of the pool with
the k columns ``M^-1 X_i^T`` and a few vector operations, O(N k^2 r) where scoring afresh costs O(N k r^2). Each
candidate's gain, ``log det(I + G_j)`` (matrix determinant lemma), comes from an elementwise Cholesky over the
pool: no per-candidate loop and no batched LAPACK call on tiny matrices.

The greedy adds the best candidate of the whole pool K times; the exchange takes each chosen configuration out
(a downdate), scores every candidate against the rest, and swaps while log det rises. On a large pool the
passes run on a shortlist (the candidates that add most to the design, and those that scored best in earlier
passes over the whole pool), then one pass over the whole pool confirms; both repeat while that pass swaps.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve_triangular

NEAR = 4  # per whole-pool search, the best candidates kept for the next shortlist
# Single-precision updates only where C = (I +/- G_i)^-1 stays below this: a large C (a candidate alone in some
# direction, or the greedy's start on the ridge) would amplify their round-off.
SINGLE_C = 1e3


def information(X: np.ndarray) -> np.ndarray:
    """sum_i X_i^T X_i of candidate rows X (N, k, r)."""
    flat = X.reshape(-1, X.shape[-1])
    return flat.T @ flat


def logdet(A: np.ndarray) -> float:
    return float(np.linalg.slogdet(A)[1])


def logdet_eye_plus(G: np.ndarray) -> np.ndarray:
    """log det(I + G_j) for every j of G (k, k, N), symmetric: closed forms for k <= 3, else an elementwise
    Cholesky over the pool. A determinant or pivot at or below zero (a chosen candidate's own downdate at
    round-off) counts as 1e-300."""
    k = len(G)
    if k <= 3:
        return np.log(np.maximum(_det_eye_plus(G), 1e-300))
    L = [[None] * k for _ in range(k)]
    out, bad = np.zeros(G.shape[-1]), np.zeros(G.shape[-1], bool)
    for j in range(k):
        d = 1.0 + G[j, j] - sum(L[j][m] ** 2 for m in range(j))
        bad |= ~(d > 1e-300)
        d = np.where(bad, 1.0, d)  # a failed candidate's remaining pivots are meaningless: kept finite
        out += np.log(d)
        L[j][j] = np.sqrt(d)
        for i in range(j + 1, k):
            L[i][j] = np.where(bad, 0.0, (G[i, j] - sum(L[i][m] * L[j][m] for m in range(j))) / L[j][j])
    return np.where(bad, np.log(1e-300), out)


def _det_eye_plus(G: np.ndarray) -> np.ndarray:
    """det(I + G_j) for symmetric G (k, k, N), k <= 3."""
    a = 1.0 + G[0, 0]
    if len(G) == 1:
        return a
    b, d = G[0, 1], 1.0 + G[1, 1]
    if len(G) == 2:
        return a * d - b * b
    c, e, f = G[0, 2], G[1, 2], 1.0 + G[2, 2]
    return a * (d * f - e * e) - b * (b * f - c * e) + c * (b * e - c * d)


class Pool:
    """M, M^-1, log det M and every candidate's ``G_j`` (module docstring) under rank-k updates. ``single``: the
    updates' products with the pool in single precision (half the memory traffic) where the update is well
    conditioned (``C`` below ``SINGLE_C``); the gains then carry errors near 1e-7, far below any swap worth
    making, and ``reset`` clears the drift."""

    def __init__(self, X: np.ndarray, M: np.ndarray, single: bool = False):
        N, k, r = X.shape
        self.X = X
        self.XR = np.ascontiguousarray(X.transpose(2, 1, 0)).reshape(r, k * N)  # column a * N + j: row a of X_j
        self.XR32 = self.XR.astype(np.float32)
        self.single = single
        self.reset(M)

    def reset(self, M: np.ndarray) -> None:
        """Recompute from M (also against drift after many updates)."""
        N, k, r = self.X.shape
        L = np.linalg.cholesky(M)
        Li = solve_triangular(L, np.eye(r), lower=True, check_finite=False)
        Y = (Li @ self.XR).reshape(r, k, N)  # L^-1 X_j^T; one product with the pool is faster than a solve
        self.M, self.Minv = M, Li.T @ Li
        self.logdet = 2 * float(np.log(np.diag(L)).sum())
        self.G = np.empty((k, k, N))
        for a in range(k):
            for c in range(a, k):
                self.G[a, c] = self.G[c, a] = np.einsum("rn,rn->n", Y[:, a], Y[:, c])

    def gains(self, G: np.ndarray | None = None) -> np.ndarray:
        """log det(I + G_j) of every candidate: the rise of log det on adding it (to M, or to the base of G)."""
        return logdet_eye_plus(self.G if G is None else G)

    def moved(self, i: int, sign: float) -> tuple[np.ndarray, np.ndarray, float]:
        """(G, M^-1, log det M) after adding (sign 1) or removing (sign -1) candidate i, not committed."""
        N, k, _ = self.X.shape
        C = np.linalg.inv(np.eye(k) + sign * self.G[:, :, i])
        Z = self.X[i] @ self.Minv
        if self.single and np.abs(C).max() < SINGLE_C:
            W = (Z.astype(np.float32) @ self.XR32).reshape(k, k, N)  # W[b, a, j] = X_j,a M^-1 X_i,b
            CW = (C.astype(np.float32) @ W.reshape(k, -1)).reshape(k, k, N)
        else:
            W = (Z @ self.XR).reshape(k, k, N)
            CW = (C @ W.reshape(k, -1)).reshape(k, k, N)
        return self.G - sign * np.einsum("ban,bcn->acn", W, CW), self.Minv - sign * (Z.T @ C @ Z), \
            self.logdet - logdet(C)

    def commit(self, i: int, sign: float, moved=None) -> None:
        """Add (sign 1) or remove (sign -1) candidate i; ``moved``: ``self.moved(i, sign)`` if already at hand."""
        self.G, self.Minv, self.logdet = self.moved(i, sign) if moved is None else moved
        self.M = self.M + sign * (self.X[i].T @ self.X[i])


def d_optimal(X: np.ndarray, K: int, M0: np.ndarray, rng: np.random.Generator, *, starts: int, passes: int,
              min_gain: float, shortlist: int) -> tuple[list[int], list[int], int]:
    """(greedy choice, best design, swaps): the greedy on the whole pool, then the exchange; ``starts - 1`` more
    starts by a stochastic greedy (each step's best of a random sample, as ``kincal.analysis.design``'s),
    exchanged too; the design of largest log det wins (exchanges end in local optima that differ by start)."""
    pool = Pool(X, M0)
    first = greedy(pool, K, M0)
    best, swaps = exchange(pool, first, M0, passes=passes, min_gain=min_gain, shortlist=shortlist)
    value = pool.logdet
    sample = int(np.ceil(len(X) / K * np.log(100)))
    for _ in range(starts - 1):
        other, n = exchange(pool, greedy(pool, K, M0, rng, sample), M0, passes=passes, min_gain=min_gain,
                            shortlist=shortlist)
        swaps += n
        if pool.logdet > value:
            best, value = other, pool.logdet
    return first, best, swaps


def greedy(pool: Pool, K: int, M0: np.ndarray, rng: np.random.Generator | None = None,
           sample: int = 0) -> list[int]:
    """Add the candidate that raises log det most, K times: of the whole pool, or with ``rng`` of a random
    sample of ``sample`` candidates per step."""
    pool.single = False  # from the ridge, updates cancel large terms: double precision
    pool.reset(M0)
    N, chosen = len(pool.X), []
    for _ in range(K):
        g = pool.gains()
        g[chosen] = -np.inf
        if rng is not None and sample < N:
            idx = rng.choice(N, sample, replace=False)
            i = int(idx[np.argmax(g[idx])])
        else:
            i = int(np.argmax(g))
        chosen.append(i)
        pool.commit(i, 1.0)
    return chosen


def exchange(pool: Pool, chosen: list[int], M0: np.ndarray, *, passes: int, min_gain: float,
             shortlist: int) -> tuple[list[int], int]:
    """Fedorov exchange for D from ``chosen``: (design, swaps); ``pool`` ends at the design. A swap must raise
    log det by ``min_gain``. On a pool larger than twice ``shortlist`` the passes run on a shortlist first
    (module docstring)."""
    X, chosen, swaps, near = pool.X, [int(i) for i in chosen], 0, set()
    large = len(X) > 2 * shortlist
    pool.single = True
    for _ in range(passes):
        pool.reset(M0 + information(X[chosen]))
        if large:
            g = pool.gains()
            g[chosen + sorted(near)] = np.inf
            top = shortlist + len(chosen) + len(near)
            sub = np.sort(np.argpartition(-g, top)[:top]) if top < len(X) else np.arange(len(X))
            part, n = _passes(Pool(X[sub], pool.M, single=True), list(np.searchsorted(sub, chosen)), passes,
                              min_gain)
            chosen, swaps = [int(sub[i]) for i in part], swaps + n
            pool.reset(M0 + information(X[chosen]))
        chosen, n = _passes(pool, chosen, 1 if large else passes, min_gain, near if large else None)
        swaps += n
        if n == 0 or not large:
            break
    return chosen, swaps


def _passes(pool: Pool, chosen: list[int], limit: int, min_gain: float, near: set | None = None):
    """Up to ``limit`` exchange passes over the chosen positions: (design, swaps); ``pool`` ends at the design.
    ``near`` collects each search's best candidates."""
    chosen, swaps = [int(i) for i in chosen], 0
    for _ in range(limit):
        changed = False
        for pos in range(len(chosen)):
            out = chosen[pos]
            G, Binv, ld = pool.moved(out, -1.0)
            g = pool.gains(G)
            g[chosen] = -np.inf
            j = int(np.argmax(g))
            if near is not None:
                near.update(np.argpartition(-g, NEAR)[:NEAR].tolist())
            if ld + g[j] > pool.logdet + min_gain:
                pool.commit(out, -1.0, (G, Binv, ld))
                pool.commit(j, 1.0)
                chosen[pos], changed, swaps = j, True, swaps + 1
        if not changed:
            break
        pool.reset(pool.M)
    return chosen, swaps
