"""Motion along the self-motion manifold of a constrained (clamped or closed-chain) redundant arm.

``explore`` imitates a person moving a clamped arm by hand (thesis Sec. 3.3): from many random starts it
finds configurations on the constraint by IK (these land on different elbow/wrist branches), then walks
each one along the manifold: a step of ``step_rad`` along a null-space direction of the constraint
Jacobian (kept smooth by momentum; reversed at a joint limit), projected back onto the constraint by
IK. Non-converged projections and configurations outside the limits are rejected and counted;
near-duplicates are removed. The samples are returned in walk order, so the motion between consecutive
samples is a real path (used by the backlash model).

``joint_spread`` reports the range each joint covered and names the joints the self-motion hardly excites.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.spatial import cKDTree

from kincal.errors import DegenerateExperimentError
from kincal.simulate.ik import solve


@dataclass(frozen=True)
class Exploration:
    """Configurations on a constraint manifold, in walk order.

    Attributes
    ----------
    q : (M, m) joint readings (all within limits, closure below the IK tolerance).
    walk : (M,) int, which walk (one hand-guided session) each sample comes from.
    branch : (M,) int, connected piece of the manifold the walk lies on (walks that meet share a label).
    dim : dimension of the self-motion manifold (joints minus equations).
    n_seeds_tried, n_seeds_failed : IK starts tried and rejected (non-converged).
    n_steps_rejected : walk steps whose projection did not converge or left the limits.
    n_duplicates : samples dropped as near-duplicates.
    """

    q: np.ndarray
    walk: np.ndarray
    branch: np.ndarray
    n_seeds_tried: int
    n_seeds_failed: int
    n_steps_rejected: int
    n_duplicates: int
    dim: int

    @property
    def n_branches(self) -> int | None:
        """Distinct pieces of a one-dimensional self-motion visited; None for higher dimensions, where
        random walks rarely meet and the count would mean nothing."""
        return int(np.unique(self.branch).size) if self.dim == 1 else None


def _null_directions(J: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Project directions d (N, m) onto the null space of J (N, k, m), normalized."""
    _, s, Vt = np.linalg.svd(J)  # Vt (N, m, m)
    rank = J.shape[1]
    Vn = Vt[:, rank:, :]  # (N, m - k, m): null space rows
    out = np.einsum("nim,ni->nm", Vn, np.einsum("nim,nm->ni", Vn, d))
    return out / np.maximum(np.linalg.norm(out, axis=-1, keepdims=True), 1e-300)


def explore(
    constraint,
    rng: np.random.Generator,
    *,
    n_seeds: int = 64,
    n_steps: int = 150,
    step_rad: float = 0.05,
    momentum: float = 0.9,
    seeds: np.ndarray | None = None,
    accept: Callable[[np.ndarray], np.ndarray] | None = None,
    margin_rad: float = 0.0,
    dedup_rad: float = 1e-3,
    ik_options: dict | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Exploration:
    """Walk the self-motion manifold of ``constraint`` (see the module docstring).

    Parameters
    ----------
    constraint : an IK constraint (``kincal.simulate.ik``) with more joints than equations.
    n_seeds : random starts, uniform within the limits (shrunk by ``margin_rad``) unless ``seeds`` (S, m) given.
    n_steps : steps per walk; ``step_rad`` is the mean joint-space length of one step (drawn in [0.5, 1.5] x).
    momentum : 0 (random direction each step) to 1 (straight on); a 1-D manifold is swept back and forth.
    accept : optional filter q (N, m) -> bool (N,) (e.g. a workspace check); rejected steps count as blocked.
    dedup_rad : samples closer than this (max over joints) to an earlier one are dropped.
    ik_options : options for ``kincal.simulate.ik.solve`` (tolerances).
    progress : called as ``progress(done, total)`` after each step.
    """
    ik_options = dict(ik_options or {})
    lo, hi = constraint.lower + margin_rad, constraint.upper - margin_rad
    m = constraint.size
    if seeds is None:
        finite_lo = np.where(np.isfinite(lo), lo, -np.pi)
        finite_hi = np.where(np.isfinite(hi), hi, np.pi)
        seeds = rng.uniform(finite_lo, finite_hi, (n_seeds, m))
    res = solve(constraint, seeds, **ik_options)
    q = res.q
    ok = np.all((q >= lo) & (q <= hi), axis=-1)
    if accept is not None:
        ok &= accept(q)
    q = q[ok]
    n_tried, n_failed = len(seeds), len(seeds) - int(ok.sum())
    W = q.shape[0]
    if W == 0:
        raise DegenerateExperimentError(
            f"self-motion: none of {n_tried} IK starts reached the constraint within the joint limits"
        )
    dim = m - constraint.residual(q[:1], np.arange(1))[0].shape[1]
    d = rng.normal(size=(W, m))
    path = [q.copy()]
    rejected = 0
    idx = np.arange(W)
    for step in range(n_steps):
        _, J, _, _ = constraint.residual(q, idx)
        d = _null_directions(J, momentum * d + (1 - momentum) * rng.normal(size=(W, m)))
        # random step lengths keep walks that met at a limit from moving in lockstep afterwards
        h = step_rad * rng.uniform(0.5, 1.5, (W, 1))
        trial = q + h * d
        out = np.any((trial < lo) | (trial > hi), axis=-1)
        d[out] *= -1  # at a limit: turn round
        trial[out] = q[out] + h[out] * d[out]
        proj = solve(constraint, np.clip(trial, lo, hi), **{"max_iter": 30, **ik_options})
        new = proj.q
        good = np.all((new >= lo) & (new <= hi), axis=-1)
        if accept is not None:
            good &= accept(new)
        moved = proj.index[good]
        q[moved] = new[good]
        stuck = np.setdiff1d(idx, moved)
        d[stuck] = rng.normal(size=(stuck.size, m))
        rejected += stuck.size
        path.append(q.copy())
        if progress is not None:
            progress(step + 1, n_steps)
    P = np.stack(path, axis=1)  # (W, n_steps + 1, m)
    walk = np.repeat(np.arange(W), n_steps + 1)
    flat = P.reshape(-1, m)
    keep, branch_of_walk = _dedup_and_branches(flat, walk, W, dedup_rad, 2.5 * step_rad)
    return Exploration(
        flat[keep], walk[keep], branch_of_walk[walk[keep]], n_tried, n_failed, rejected,
        int(flat.shape[0] - keep.sum()), dim,
    )


def _dedup_and_branches(flat, walk, W, dedup_rad, link_rad):
    """Drop near-duplicates (keep first), and join walks that come within ``link_rad`` of each other."""
    tree = cKDTree(flat)
    keep = np.ones(len(flat), dtype=bool)
    for i, j in sorted(tree.query_pairs(dedup_rad, p=np.inf, output_type="ndarray").tolist()):
        if keep[i]:
            keep[j] = False
    parent = np.arange(W)

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    pairs = tree.query_pairs(link_rad, output_type="ndarray")
    for a, b in np.unique(np.sort(walk[pairs], axis=1), axis=0) if len(pairs) else []:
        if a != b:
            parent[find(a)] = find(b)
    roots = np.array([find(a) for a in range(W)])
    return keep, np.unique(roots, return_inverse=True)[1]


def pick_evenly(n_available: int, n: int) -> np.ndarray:
    """``n`` indices spread evenly over ``range(n_available)``, in order."""
    if n > n_available:
        raise DegenerateExperimentError(f"asked for {n} configurations, only {n_available} distinct ones were found")
    return np.unique(np.round(np.linspace(0, n_available - 1, n)).astype(int))


@dataclass(frozen=True)
class JointSpread:
    """Per-joint coverage of a set of configurations.

    ``names`` (n,), ``low``/``high``/``range`` (n,) in model units, ``fraction`` (n,) of the limit span
    (NaN without finite limits), ``weak``: names of joints whose range is below the threshold,
    ``n_branches``: connected pieces of the self-motion manifold visited (None if unknown).
    """

    names: tuple[str, ...]
    low: np.ndarray
    high: np.ndarray
    range: np.ndarray
    fraction: np.ndarray
    weak: tuple[str, ...]
    n_branches: int | None = None

    def lines(self) -> list[str]:
        """A plain-text table (for logs and reports)."""
        out = [f"{'joint':<14}{'min':>10}{'max':>10}{'range':>10}{'of limits':>11}"]
        for i, name in enumerate(self.names):
            frac = "" if np.isnan(self.fraction[i]) else f"{100 * self.fraction[i]:.0f}%"
            flag = "  weak" if name in self.weak else ""
            out.append(f"{name:<14}{self.low[i]:>10.3f}{self.high[i]:>10.3f}{self.range[i]:>10.3f}{frac:>11}{flag}")
        if self.n_branches is not None:
            out.append(f"self-motion branches visited: {self.n_branches}")
        if self.weak:
            out.append(f"hardly excited: {', '.join(self.weak)}")
        return out


def joint_spread(
    q: np.ndarray,
    names,
    lower=None,
    upper=None,
    *,
    weak_rad: float = 0.1,
    n_branches: int | None = None,
) -> JointSpread:
    """Range covered by each joint over configurations q (N, n); joints below ``weak_rad`` are named weak."""
    q = np.asarray(q, dtype=float)
    low, high = q.min(axis=0), q.max(axis=0)
    rng_ = high - low
    span = np.full(q.shape[1], np.inf) if lower is None else np.asarray(upper, float) - np.asarray(lower, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        fraction = np.where(np.isfinite(span), rng_ / span, np.nan)
    names = tuple(names)
    weak = tuple(n for n, r in zip(names, rng_) if r < weak_rad)
    return JointSpread(names, low, high, rng_, fraction, weak, n_branches)
