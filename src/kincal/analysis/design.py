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

D (also the start of A, I and G) takes the method whose exact score is cheaper (``_d_optimal``). Candidates of
at most ``POOLED_ROWS`` rows: every candidate scored at every step, from rank-k updates of the whole pool's
``X_j M^-1 X_j^T`` (``kincal.analysis.design_pool``). More rows: a stochastic greedy start (each step scores a
random sample of the pool), then the exchange finds each position's best swap by branch and bound
(``_LogDet.best``: bounds of every candidate's gain from one skinny product with the pool, exact scores only for
the few that could win), first on a shortlist of the candidates that add most to the design, then checked on the
whole pool.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular

from kincal.analysis import design_pool
from kincal.analysis.design_pool import information, logdet as _logdet
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
# Branch and bound of the D selection (``_LogDet.best``): candidates scored exactly in the first block (doubling
# after); the reference moves once a search scores this share of the pool, or once the bounds use this many
# times k directions; a relative and absolute slack covering the single precision of the bounds.
FIRST_BLOCK = 256
REFER_FRACTION = 0.25
REFER_RANK = 4
BOUND_SLACK = 1e-4
GREEDY_EPS = 0.01  # stochastic greedy: the sample per step is N / K ln(1 / GREEDY_EPS)
NEAR = 8  # per search, the best candidates scored that the exchange's shortlist keeps
SHORTLIST = (500, 100)  # the exchange's shortlist: at least 500 candidates, or 1 % of the pool
POOLED_ROWS = 3  # candidates of at most this many rows: design_pool (closed-form determinants, no bounds)
POOLED_SHORTLIST = (20_000, 100)  # design_pool's exchange passes run on a shortlist beyond twice this
STARTS = 1  # design_pool's starts (the greedy, then stochastic greedies), each exchanged
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
    if criterion in ("D", "O1") and exchange:
        first, best, swaps = _d_optimal(X, K, M0, seed)
        return Selection(np.array(best), criterion, criterion_value(M0 + information(X[best]), criterion, workspace, K),
                         criterion_value(M0 + information(X[first]), criterion, workspace, K), swaps)
    chosen = _greedy(X, K, criterion, workspace, M0, eps)
    greedy = criterion_value(M0 + information(X[chosen]), criterion, workspace, K)
    if not exchange:
        return Selection(np.array(chosen), criterion, greedy, greedy, 0)
    best, value, swaps = _exchange_smoothed(X, chosen, criterion, workspace, M0)
    if criterion in ("A", "I", "G"):  # also from the D-optimal design: a good start for variance criteria
        other, v, n = _exchange(X, _d_optimal(X, K, M0, seed)[1], criterion, workspace, M0)
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


def _d_optimal(X, K, M0, seed) -> tuple[list[int], list[int], int]:
    """(greedy choice, exchanged design, swaps) for D, by the method whose exact score is cheaper: for
    candidates of at most ``POOLED_ROWS`` rows every candidate's gain costs a few vector operations
    (``kincal.analysis.design_pool``: the whole pool scored at each step, ``STARTS`` starts); for more rows the
    per-candidate determinants cost more than bounding them (a stochastic greedy start, then the exchange by
    branch and bound, ``_exchange_d``)."""
    rng = np.random.default_rng(seed)
    if X.shape[1] <= POOLED_ROWS:
        return design_pool.d_optimal(X, K, M0, rng, starts=STARTS, passes=MAX_PASSES, min_gain=D_GAIN,
                                     shortlist=max(POOLED_SHORTLIST[0], len(X) // POOLED_SHORTLIST[1]))
    first = _greedy_d(X, K, M0, rng)
    best, _, swaps = _exchange_d(X, first, M0)
    return first, best, swaps


def _greedy(X, K, criterion, workspace, M0, eps) -> list[int]:
    """Add the best candidate of the whole pool K times; until the design has full rank every criterion but D is
    flat in the missing directions, so D chooses until then."""
    if criterion in ("D", "O1"):
        return design_pool.greedy(design_pool.Pool(X, M0), K, M0) if X.shape[1] <= POOLED_ROWS else \
            _greedy_d(X, K, M0)
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
    """Fedorov exchange from ``chosen`` for any criterion but D and O1 (``_d_optimal``): (design, criterion
    value, swaps)."""
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
    """D-optimal bookkeeping: ``M``, ``M^-1`` and ``log det M`` under rank-k (Woodbury) updates, and the best
    candidate to add to a base information ``B`` by branch and bound (``best``).

    The gain of adding candidate j to B is ``log det(I + G_j)``, ``G_j = X_j B^-1 X_j^T`` (k, k). At a reference
    ``R`` every gain is known (``refer``); at B each is bounded from above (``_bound``: one skinny product with
    the pool), and candidates are scored exactly in blocks in the order of their bounds until no bound can beat
    the best found: the same choice as scoring the whole pool, at a fraction of the cost while B stays close to
    R (the reference moves to the next base when the bounds have grown loose)."""

    def __init__(self, X: np.ndarray, M: np.ndarray):
        self.X, self._ref = X, None
        self.near: set[int] = set()  # candidates that scored best in some search: the exchange's shortlist keeps them
        self.norms = np.square(X).sum(axis=(1, 2))  # |X_j|_F^2
        self.X32 = X.astype(np.float32)  # the bounds' projections: single precision, covered by BOUND_SLACK
        self.reset(M)

    def reset(self, M: np.ndarray) -> None:
        """Recompute from ``M`` (also against drift after many updates)."""
        self.M, self.Minv = M, np.linalg.inv(M)
        self.logdet = _logdet(M)

    def gram(self, Binv: np.ndarray, idx=None, single: bool = False) -> np.ndarray:
        """``X_i B^-1 X_i^T`` (n, k, k) of the candidates ``idx`` (default: all), in chunks; ``single``: in
        single precision."""
        X = self.X32 if single else self.X
        X = X if idx is None else X[idx]
        Binv = Binv.astype(X.dtype)
        out = np.empty((len(X), X.shape[1], X.shape[1]), X.dtype)
        for s in range(0, len(X), CHUNK):
            x = X[s: s + CHUNK]
            out[s: s + CHUNK] = (x.reshape(-1, x.shape[-1]) @ Binv).reshape(x.shape) @ np.swapaxes(x, 1, 2)
        return out

    def removed(self, i: int) -> tuple[np.ndarray, float]:
        """(B^-1, log det B) of B = M with candidate i taken out, not committed."""
        Z = self.X[i] @ self.Minv
        C = np.linalg.inv(np.eye(len(Z)) - self.X[i] @ Z.T)
        return self.Minv + Z.T @ C @ Z, self.logdet - _logdet(C)

    def add(self, i: int, sign: float = 1.0) -> None:
        """Commit adding (sign 1) or removing (sign -1) candidate i."""
        Z = self.X[i] @ self.Minv
        C = np.linalg.inv(np.eye(len(Z)) + sign * self.X[i] @ Z.T)
        self.logdet -= _logdet(C)
        self.Minv = self.Minv - sign * (Z.T @ C @ Z)
        self.M = self.M + sign * (self.X[i].T @ self.X[i])

    def best(self, Binv: np.ndarray, exclude, threshold: float = -np.inf) -> tuple[int, float]:
        """(j, gain): the candidate not in ``exclude`` whose addition to the base B (given as B^-1) raises
        log det most, if its gain exceeds ``threshold``; else (-1, -inf)."""
        if self._ref is None:  # no reference: score every candidate, make B the reference, rescore the best few
            gains = self.refer(Binv)
            gains[list(exclude)] = -np.inf
            idx = np.argsort(-gains, kind="stable")[:NEAR]
            g = _logdet_plus_identity(self.gram(Binv, idx))
            j = int(np.argmax(g))
            return (int(idx[j]), float(g[j])) if g[j] > threshold else (-1, -np.inf)
        bound, rank = self._bound(Binv)
        bound[list(exclude)] = -np.inf
        order = np.argsort(-bound, kind="stable")
        j, gain, done, block = -1, -np.inf, 0, FIRST_BLOCK
        while done < len(order) and bound[order[done]] > max(gain, threshold):
            idx = order[done: done + block]
            g = _logdet_plus_identity(self.gram(Binv, idx))
            m = int(np.argmax(g))
            if g[m] > gain:
                j, gain = int(idx[m]), float(g[m])
            self.near.update(idx[np.argsort(-g)[:NEAR]].tolist())
            done, block = done + len(idx), 2 * block
        if done > REFER_FRACTION * len(order) or rank > REFER_RANK * self.X.shape[1]:
            self._ref = None  # the bound has grown loose: the next call makes its base the reference
        return (j, gain) if gain > threshold else (-1, -np.inf)

    def refer(self, Binv: np.ndarray) -> np.ndarray:
        """Make B (given as B^-1) the reference of the bounds; returns every candidate's gain at B (single
        precision, as the bounds)."""
        G = self.gram(Binv, single=True)
        gains = _logdet_plus_identity(G).astype(float)
        self._ref = (Binv, gains, np.trace(G, axis1=1, axis2=2))
        return gains.copy()

    def _bound(self, Binv: np.ndarray) -> tuple[np.ndarray, int]:
        """Upper bounds of every candidate's gain at base B from the reference R, and the rank they used.

        Split ``B^-1 - R^-1 = P - Q`` by the signs of its eigenvalues (``P = sum delta_a d_a d_a^T``) and let
        ``U_j = X_j P X_j^T``, ``V_j = X_j Q X_j^T``: ``log det(I + G_j(R) + U_j) <= log det(I + G_j(R)) +
        sum_a log(1 + delta_a |X_j d_a|^2)``, and taking V away lowers that by at least
        ``tr V_j / (1 + tr G_j(R) + tr U_j)`` (``log(1 - w) <= -w``). Eigenvalues below 1e-12 of the largest are
        bounded together through ``|X_j|_F^2`` (positive) or left out (negative)."""
        Rinv, gains, traces = self._ref
        delta, d = np.linalg.eigh(Binv - Rinv)
        tiny = 1e-12 * max(np.abs(delta).max(), 1e-300)
        pos, neg = delta > tiny, delta < -tiny
        tail = delta[(delta > 0) & ~pos].sum() * self.norms
        D = np.hstack([d[:, pos] * np.sqrt(delta[pos]), d[:, neg] * np.sqrt(-delta[neg])]).astype(np.float32)
        out, p = gains + tail, int(pos.sum())
        for s in range(0, len(out) if D.shape[1] else 0, CHUNK):
            x = self.X32[s: s + CHUNK]
            proj = np.square(x.reshape(-1, x.shape[-1]) @ D).reshape(len(x), -1, D.shape[1]).sum(axis=1)
            up = proj[:, :p].sum(axis=1)
            out[s: s + CHUNK] += np.log1p(proj[:, :p]).sum(axis=1) - proj[:, p:].sum(axis=1) * (1 - BOUND_SLACK) / (
                1 + traces[s: s + CHUNK] + up + tail[s: s + CHUNK])
        return out * (1 + BOUND_SLACK) + BOUND_SLACK, D.shape[1]


def _logdet_plus_identity(G: np.ndarray) -> np.ndarray:
    """log det(I + G_i) for symmetric positive semi-definite G (N, k, k); closed forms for k <= 3 (batched
    LAPACK calls on tiny matrices cost more than the arithmetic)."""
    k = G.shape[-1]
    A = G + np.eye(k, dtype=G.dtype if k > 3 else float)  # single precision stays single for Cholesky
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


def _greedy_d(X, K, M0, rng=None) -> list[int]:
    """Greedy for D. With ``rng`` each step scores only a random sample of ``N / K ln(1 / GREEDY_EPS)`` of the N
    candidates (stochastic greedy, Mirzasoleiman et al. 2015: within ``GREEDY_EPS`` of the greedy's guarantee
    in expectation) when that is fewer than the pool: a start for the exchange, which searches the whole pool."""
    st = _LogDet(X, M0.copy())
    N = len(X)
    sample = N if rng is None else int(np.ceil(N / K * np.log(1 / GREEDY_EPS)))
    chosen: list[int] = []
    for _ in range(K):
        free = np.setdiff1d(np.arange(N), chosen)
        idx = free if sample >= len(free) else np.sort(rng.choice(free, sample, replace=False))
        g = _logdet_plus_identity(st.gram(st.Minv, idx))
        i = int(idx[np.argmax(g)])
        chosen.append(i)
        st.add(i)
    return chosen


def _exchange_d(X, chosen, M0) -> tuple[list[int], float, int]:
    """Fedorov exchange for D: each chosen configuration swapped for the best candidate (``_LogDet.best``) while
    log det rises. On a large pool the passes first run on a shortlist (the ``SHORTLIST`` candidates that add
    most to the current design, and those that came out best in earlier searches on the whole pool: a swap's
    partner is often close to the configuration it replaces, which adds little while that is chosen), then one
    pass on the whole pool checks the result; both repeat while that pass still swaps, so the result is as final
    as with passes on the whole pool."""
    size = max(SHORTLIST[0], len(X) // SHORTLIST[1])
    chosen, swaps, large = list(chosen), 0, len(X) > 2 * size
    st = _LogDet(X, M0 + information(X[chosen]))
    for _ in range(MAX_PASSES):
        st.reset(M0 + information(X[chosen]))
        if large:
            gains = st.refer(st.Minv)
            gains[chosen + sorted(st.near)] = np.inf
            top = size + len(chosen) + len(st.near)
            sub = np.sort(np.argpartition(-gains, top)[:top]) if top < len(X) else np.arange(len(X))
            part, n = _passes(_LogDet(X[sub], st.M), list(np.searchsorted(sub, chosen)), MAX_PASSES)
            chosen, swaps = [int(sub[i]) for i in part], swaps + n
            st.reset(M0 + information(X[chosen]))
        chosen, n = _passes(st, chosen, 1 if large else MAX_PASSES)
        swaps += n
        if n == 0 or not large:
            break
    return chosen, _logdet(M0 + information(X[chosen])), swaps


def _passes(st: "_LogDet", chosen: list[int], limit: int) -> tuple[list[int], int]:
    """Up to ``limit`` exchange passes over the chosen positions: (design, swaps)."""
    chosen, swaps = [int(i) for i in chosen], 0
    for _ in range(limit):
        changed = False
        for pos in range(len(chosen)):
            out = chosen[pos]
            Binv, logdet = st.removed(out)
            j, _ = st.best(Binv, chosen, st.logdet + D_GAIN - logdet)
            if j >= 0:
                st.add(out, -1.0)
                st.add(j)
                chosen[pos] = j
                swaps += 1
                changed = True
        st.reset(st.M)
        if not changed:
            break
    return chosen, swaps


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
