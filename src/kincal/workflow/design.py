"""``design``: choose N configurations to measure, from candidates kincal generates itself.

The candidate pool is the experiment's own generator run on the nominal robot without noise
(``kincal.simulate.GENERATORS``): free tracker poses sampled within the joint limits, one clamp sampled by
self-motion across IK branches, a plate of fixtures, the dual-arm closed chain. Every candidate is therefore
reachable, within the limits and satisfies the experiment's constraint. Tracker experiments can be limited to a
workspace box (tool position in the world frame) and a line-of-sight cone (the tool's z axis within a
half-angle of the direction to the tracker).

The pool is linearized once at the nominal model (``Problem.linearize``): each candidate's whitened rows on the
identifiable subspace feed ``kincal.analysis.design.select``. The I and G criteria use the tool position's
sensitivity over a workspace sample (registered as validation registers).

Tree-structured robots: the generators draw the carriers' readings with the arms' (a torso moves with them), so
every candidate is a configuration of the composite chain and the selection weighs the torso's joints like the
arms'; the limits, the workspace box and the workspace sample go through the composite chain.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from kincal.analysis.design import Selection, criterion_value, information, select
from kincal.analysis.prediction import tool_motion
from kincal.data import Dataset
from kincal.errors import DegenerateExperimentError, ModelError
from kincal.estimation import Problem, SolverOptions
from kincal.estimation.plan import identifiable_basis, plan
from kincal.kinematics import Robot
from kincal.kinematics.tree import tip_pose
from kincal.noise import Noise
from kincal.simulate import GENERATORS, workspace_sample
from kincal.simulate.noise import Noise as SimNoise

RANDOM_DRAWS = 20
WORKSPACE = 100


@dataclass(frozen=True, eq=False)
class Design:
    """The chosen configurations (``dataset``: the pool's rows, noise-free nominal measurements), the
    selection, the criterion of random designs of the same size (``random``: median, and all draws), the
    identifiable rank and the predicted tool position error (m, RMS and max over the workspace sample) of
    the designed design and the median over the random ones; ``outside``: the pool's configurations left out
    for lying outside the joint limits; ``unidentifiable``: the robot's free parameters the experiment cannot
    determine (a torso's, from a dual clamp)."""

    dataset: Dataset
    pool: int
    selection: Selection
    rank: int
    free: int
    random: float
    random_values: np.ndarray
    tool_rms: float
    tool_max: float
    random_tool_rms: float
    outside: int = 0
    unidentifiable: tuple[str, ...] = ()


@dataclass(frozen=True)
class Candidates:
    """Limits on tracker candidates: tool position within ``box`` (world frame, m: (lo (3,), hi (3,))), and the
    tool z axis within ``cone`` rad of the direction to the tracker's origin."""

    box: tuple[np.ndarray, np.ndarray] | None = None
    cone: float | None = None


def candidate_pool(robot: Robot, kind: str, options: Mapping, pool: int, seed: int,
                   limits: Candidates = Candidates()) -> Dataset:
    """``pool`` candidates of experiment ``kind`` (generator ``options`` as in scenario files) on the nominal
    robot, noise-free, filtered by ``limits``."""
    if kind not in GENERATORS:
        raise ModelError(f"experiment kind {kind!r}: expected one of {', '.join(sorted(GENERATORS))}")
    if pool < 1:
        raise ModelError(f"candidate pool: expected at least 1 candidate, found {pool}")
    options = {k: v for k, v in options.items() if k != "n"}  # the pool size decides
    ds, truth, _ = GENERATORS[kind](robot, n=pool, rng=seed, noise=SimNoise(), n_validation=2, **options)
    keep = _within(ds, robot, truth, limits)
    if not keep.any():
        raise DegenerateExperimentError(f"no candidate of {pool} lies in the workspace box and the line-of-sight "
                                        "cone: widen the box or the cone, or move the tracker")
    return ds.subset(np.flatnonzero(keep)) if not keep.all() else ds


def _within(ds: Dataset, robot: Robot, truth, limits: Candidates) -> np.ndarray:
    keep = np.ones(ds.size, bool)
    if limits.box is None and limits.cone is None:
        return keep
    if ds.kind not in ("pose", "markers"):
        raise ModelError(f"a workspace box or line-of-sight cone applies to tracker experiments (pose, markers), "
                         f"not to '{ds.kind}'")
    (arm,) = ds.arms
    T = tip_pose(robot, arm, ds.q)  # a mounted arm's through its carriers
    if limits.box is not None:
        lo, hi = limits.box
        keep &= np.all((T[:, :3, 3] >= lo) & (T[:, :3, 3] <= hi), axis=1)
    if limits.cone is not None:
        tracker = np.asarray(truth.values["T_world_tracker"])[:3, 3]
        to = tracker - T[:, :3, 3]
        cos = np.einsum("ni,ni->n", T[:, :3, 2], to) / np.maximum(np.linalg.norm(to, axis=1), 1e-12)
        keep &= cos >= np.cos(limits.cone)
    return keep


def design(robot: Robot, kind: str, options: Mapping, K: int, *, free="offsets", pool: int = 2000,
           criterion: str = "D", noise: Noise | None = None, seed: int = 0, limits: Candidates = Candidates(),
           workspace: int = WORKSPACE, exchange: bool = True) -> Design:
    """Choose K configurations of experiment ``kind`` for calibrating ``free`` from ``pool`` candidates the
    experiment's generator draws (module docstring)."""
    ds = candidate_pool(robot, kind, options, pool, seed, limits)
    return choose(robot, ds, K, free=free, criterion=criterion, noise=noise, seed=seed, workspace=workspace,
                  exchange=exchange)


def choose(robot: Robot, pool: Dataset, K: int, *, free="offsets", criterion: str = "D", noise: Noise | None = None,
           seed: int = 0, workspace: int = WORKSPACE, exchange: bool = True) -> Design:
    """Choose K of the configurations of the data set ``pool`` (any kind; only its configurations and known
    frames matter, the model is linearized at its nominal values). Configurations outside the joint limits are
    left out (``Design.outside`` counts them): a design never returns one."""
    pool, outside = _within_limits(robot, pool)
    problem = Problem.build(robot, [pool], free, noise=noise)
    p = plan(problem, SolverOptions())
    rows = ds_rows(problem)
    if K * rows <= p.rank:  # what calibrate needs: more equations than identifiable parameters
        raise ModelError(f"{K} configurations give {K * rows} equations for {p.rank} identifiable parameters; a "
                         f"calibration needs more equations than that (twice as many to check the fit): choose at "
                         f"least {p.rank // rows + 1} configurations ({-(-2 * p.rank // rows)} to check the fit), "
                         "or free fewer parameters")
    if K > pool.size:
        raise ModelError(f"cannot choose {K} configurations from a pool of {pool.size}: enlarge the pool")
    V = identifiable_basis(problem, p.identifiability)
    X = _candidate_rows(problem, p, V)
    W = _workspace_rows(robot, p, V, workspace, seed)
    sel = select(X, K, criterion, workspace=W, exchange=exchange, seed=seed)
    rng = np.random.default_rng(seed + 1)
    draws = [rng.choice(len(X), K, replace=False) for _ in range(RANDOM_DRAWS)]
    values = np.array([criterion_value(information(X[d]), criterion, W, K) for d in draws])
    tools = [_tool_error(information(X[d]), W)[0] for d in draws]
    tool = _tool_error(information(X[sel.indices]), W)
    ident = p.identifiability
    return Design(pool.subset(sel.indices), pool.size, sel, p.rank, len(ident.names), float(np.median(values)),
                  values, tool[0], tool[1], float(np.median(tools)), outside,
                  tuple(n for n, ok in zip(ident.names, ident.identifiable) if not ok and n.split(".")[0] in robot.arms))


def _within_limits(robot: Robot, pool: Dataset) -> tuple[Dataset, int]:
    """The pool without its configurations outside the joint limits, and how many those were."""
    keep = np.logical_and.reduce([robot[a].within_limits(pool.q[a]) for a in _readings_of(robot, pool)])
    if not keep.any():
        raise ModelError(f"none of the {pool.size} configurations of data set '{pool.name}' lies within the joint "
                         "limits: give configurations within the model's limits")
    return (pool if keep.all() else pool.subset(np.flatnonzero(keep))), int((~keep).sum())


def _readings_of(robot: Robot, ds: Dataset) -> list[str]:
    """The arms whose readings a configuration of ``ds`` sets: its arms and their carriers (a torso)."""
    return [a for a in robot.arms if a in ds.q and any(a in robot.lineage(b) for b in ds.arms)]


def ds_rows(problem: Problem) -> int:
    """Residual rows per configuration of the problem's one experiment."""
    (exp,) = problem.experiments
    return len(exp.components())


def _candidate_rows(problem: Problem, p, V: np.ndarray) -> np.ndarray:
    (exp,) = problem.experiments
    k = len(exp.components())
    J = p.result.linearization.J[: exp.size * k]
    return (J @ V).reshape(exp.size, k, V.shape[1])


def _workspace_rows(robot: Robot, p, V: np.ndarray, n: int, seed: int) -> np.ndarray:
    """(arms * n, 3, r): the registered tool position's sensitivity over a workspace sample of every arm."""
    rng = np.random.default_rng(seed + 2)
    out = [tool_motion(p.result, workspace_sample(robot, a, n, rng), a, V)[:, :3, :] for a in p.result.state.arms]
    return np.concatenate(out)


def _tool_error(M: np.ndarray, W: np.ndarray) -> tuple[float, float]:
    """RMS and max over the workspace sample of the predicted tool position std (m) for information M."""
    try:
        Minv = np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return float("inf"), float("inf")
    var = np.einsum("wcr,rs,wcs->w", W, Minv, W).clip(0)
    return float(np.sqrt(var.mean())), float(np.sqrt(var.max()))
