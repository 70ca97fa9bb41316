"""Large problems in blocks of configurations: the whitened Jacobian is never held whole.

A problem that would need more than a few blocks' memory held at once (``memory.by_blocks``) is evaluated in
blocks of ``memory.chunk_rows`` residual rows: each block is a sub-problem over a row range of one data set, without the prior and constraint rows
(the "tail", evaluated once). The linearization folds each block's ``[J | r_len | r]`` into the triangular
factor as it goes (TSQR: ``R = qr([R_prev; A_block])``): orthogonal transformations only, so the factor has the
conditioning of a QR of the stacked matrix, not the squared one of the normal equations. Everything the solver
asks of a linearization reads that factor (``kincal.analysis.Linearization``); the rare readers of the tall
Jacobian get a ``BlockJacobian``, which evaluates it again block by block.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kincal.experiments.base import Residual
from kincal.params import pose_retraction_jacobians, retract


def split(experiments, configurations) -> list[tuple[int, slice]]:
    """(experiment index, row range) of every block: ``configurations(exp)`` rows of each data set at a time."""
    out = []
    for i, exp in enumerate(experiments):
        step = max(int(configurations(exp)), 1)
        out += [(i, slice(a, min(a + step, exp.size))) for a in range(0, exp.size, step)] or [(i, slice(0, 0))]
    return out


def part_problem(problem, i: int, rows: slice, cache):
    """The sub-problem of rows ``rows`` of experiment ``i``, without prior and constraint rows."""
    exp = problem.experiments[i]
    sub = exp if rows == slice(0, exp.size) else type(exp)(exp.dataset.subset(rows), exp.frames)
    return replace(problem, experiments=(sub,), noise=(problem.noise[i],), constraints=(),
                   prior_idx=np.zeros(0, int), cache=cache)


def tail_problem(problem, cache):
    """The prior and constraint rows alone (None when there are none)."""
    if not len(problem.prior_idx) and not problem.constraints:
        return None
    return replace(problem, experiments=(), noise=(), cache=cache)


def gather(parts, n: int, evaluate) -> list[Residual]:
    """Per experiment, the residuals (``r`` and ``jq``, never parameter Jacobians) of ``evaluate(part)`` joined
    over the blocks ``parts`` ((i, rows, sub-problem)) of ``n`` experiments."""
    got: list[list[Residual]] = [[] for _ in range(n)]
    for i, _, part in parts:
        got[i].append(evaluate(part))
    return [join(g) for g in got]


def join(residuals) -> Residual:
    """One residual from the residuals of consecutive row blocks (their Jacobians dropped)."""
    jq = {a: np.concatenate([x.jq[a] for x in residuals]) for a in residuals[0].jq}
    return Residual(np.concatenate([x.r for x in residuals]), {}, jq)


def join_whiteners(blocks) -> np.ndarray:
    """One experiment's whiteners from its blocks'; a constant one (a broadcast view) stays a view."""
    if all(w.strides[0] == 0 for w in blocks if len(w)):
        first = next((w for w in blocks if len(w)), blocks[0])
        return np.broadcast_to(first[0] if len(first) else first, (sum(len(w) for w in blocks),) + first.shape[1:])
    return np.concatenate(blocks)


def fold(R: np.ndarray | None, A: np.ndarray) -> np.ndarray:
    """The triangular factor of ``[R; A]`` (TSQR: the factor of the rows seen so far, extended by ``A``)."""
    return np.linalg.qr(A if R is None else np.vstack([R, A]), mode="r")


def linearize(problem, state, W, cols: np.ndarray, every: bool):
    """Block by block: ``(r, R, W, raw)``, the whitened residual (m,), the triangular factor of
    ``[J_cols | r_len | r]`` (``every``) or ``[J_cols | r]``, the whiteners and the residuals before whitening per
    experiment. ``W=None``: whiten at ``state``, each block from its own evaluation."""
    n, R, rs = len(problem.experiments), None, []
    Ws, raws, res = [[] for _ in range(n)], [[] for _ in range(n)], [[] for _ in range(n)]
    for i, rows, part in problem.parts():
        r, J, Wp, raw = part.linearize(state, None if W is None else [W[i][rows]], cols)
        cached = part.cache.get(state)
        part.cache.put(None, None)  # the block's residuals hold its Jacobians: not kept
        A = [J, part.length_part(raw, Wp), r] if every else [J, r]
        R = fold(R, np.column_stack(A))
        rs.append(r)
        Ws[i].append(Wp[0])
        raws[i].append(raw[0])
        res[i].append(None if cached is None else Residual(cached[0].r, {}, cached[0].jq))
    tail = problem.tail()
    if tail is not None:
        r, J, _, _ = tail.linearize(state, [], cols)
        R = fold(R, np.column_stack([J, np.zeros(len(r)), r] if every else [J, r]))
        rs.append(r)
    W = [join_whiteners(w) for w in Ws]
    if all(x is not None for g in res for x in g):  # statistics at this state need no second evaluation
        problem.cache.put(state, [join(g) for g in res])
    return np.concatenate(rs), R, W, [np.concatenate(x) for x in raws]


class BlockJacobian:
    """The whitened Jacobian (m, len(cols)) of a blocked linearization, evaluated again block by block when read:
    ``J @ X`` by blocks, row ranges ``J[a:b]`` from the blocks that hold them (the prior and constraint rows are
    held); anything else (``np.asarray``) builds the whole matrix."""

    ndim = 2

    def __init__(self, problem, state, W, cols: np.ndarray, rows: int):
        self.problem, self.state, self.W, self.cols = problem, state, W, np.asarray(cols)
        tail = problem.tail()
        self.tail = tail.linearize(state, [], self.cols)[1] if tail is not None else np.zeros((0, len(self.cols)))
        self.shape = (rows + len(self.tail), len(self.cols))
        self.dtype = np.dtype(float)

    def blocks(self, start: int = 0, stop: int | None = None):
        """The Jacobian's rows, block by block, the tail last; only the blocks that meet rows ``start:stop``."""
        stop = self.shape[0] if stop is None else stop
        at = 0
        for i, rows, part in self.problem.parts():
            n = (rows.stop - rows.start) * len(part.experiments[0].components())
            if at < stop and at + n > start:
                yield part.linearize(self.state, [self.W[i][rows]], self.cols)[1]
                part.cache.put(None, None)
            at += n
        if stop > at:
            yield self.tail

    def __matmul__(self, X):
        return np.concatenate([J @ X for J in self.blocks()])

    def __getitem__(self, key):
        """Rows ``a:b`` evaluate the blocks that hold them (the tail is held); other keys the whole matrix."""
        if isinstance(key, slice) and key.step in (None, 1):
            start, stop, _ = key.indices(self.shape[0])
            first = 0  # the first row of the first block that meets start:stop
            for i, rows, part in self.problem.parts():
                n = (rows.stop - rows.start) * len(part.experiments[0].components())
                if first + n > start:
                    break
                first += n
            return np.concatenate(list(self.blocks(start, stop)) or [self.tail[:0]])[start - first: stop - first]
        return np.asarray(self)[key]

    def __array__(self, dtype=None, copy=None):
        J = np.concatenate(list(self.blocks()))
        return J if dtype is None else J.astype(dtype)

    def __len__(self) -> int:
        return self.shape[0]

    def weighted_factor(self, weights: np.ndarray) -> np.ndarray:
        """The triangular factor of ``sqrt(weights) * J`` (rows weighted), by blocks."""
        R, start, w = None, 0, np.sqrt(weights)
        for J in self.blocks():
            R = fold(R, w[start: start + len(J), None] * J)
            start += len(J)
        return R


def weighted_factor(J, weights: np.ndarray) -> np.ndarray:
    """The triangular factor of the rows of J weighted by ``sqrt(weights)`` (a ``BlockJacobian`` by blocks)."""
    if isinstance(J, BlockJacobian):
        return J.weighted_factor(weights)
    return np.linalg.qr(np.sqrt(weights)[:, None] * J, mode="r")


def rows_at(problem, state0, delta_free: np.ndarray, W, jac: bool):
    """The whitened residual rows (and Jacobian of the free coordinates) at ``retract(state0, delta)``, block by
    block, the tail last: what ``Problem.evaluate`` stacks, never all at once."""
    delta = problem.full_delta(delta_free)
    state = retract(state0, problem.layout, delta)
    Rl = {k: v for k, v in pose_retraction_jacobians(problem.layout, delta).items() if k in problem.want} if jac else {}
    want = problem.want if jac else set()
    cols = problem.free_idx if jac else None
    for i, rows, part in problem.parts():
        res = [part.experiments[0].residual(state, want=want, jq=False)]
        yield part._stack(state, res, [W[i][rows]], cols, Rl)
    tail = problem.tail()
    if tail is not None:
        yield tail._stack(state, [], [], cols, Rl)


def evaluate(problem, state0, delta_free: np.ndarray, W, V: np.ndarray | None):
    """``Problem.evaluate`` by blocks, the Jacobian projected on the columns ``V`` as each block comes: the
    whitened residual (m,) and ``J @ V`` (m, V.shape[1]) or None (``V`` None)."""
    rs, JV = [], []
    for r, J in rows_at(problem, state0, delta_free, W, V is not None):
        rs.append(r)
        if V is not None:
            JV.append(J @ V)
    return np.concatenate(rs), None if V is None else np.concatenate(JV)
