"""Shared parts of the clamped generators (clamp, plate, socket): walking the self-motion, reachable poses."""

from __future__ import annotations

import numpy as np

from kincal.errors import DegenerateExperimentError
from kincal.kinematics import ArmModel, forward_kinematics
from kincal.simulate.generators._common import random_configurations
from kincal.simulate.ik import PoseConstraint, solve
from kincal.simulate.selfmotion import explore, pick_evenly


def explore_to_n(constraint, n, rng, explore_options, progress):
    opts = {"n_seeds": 64, "n_steps": max(60, 3 * n // 8), "margin_rad": 0.0, **(explore_options or {})}
    ex = explore(constraint, rng, progress=progress, **opts)
    if ex.q.shape[0] < n:
        raise DegenerateExperimentError(
            f"self-motion gave {ex.q.shape[0]} distinct configurations, {n} asked; raise n_seeds or n_steps"
        )
    return ex, pick_evenly(ex.q.shape[0], n)


def candidate_poses(model, count, rng, margin, workspace):
    """Tool poses of random configurations (limits shrunk by ``margin``), inside ``workspace`` if given."""
    T = forward_kinematics(model, random_configurations(model, 20 * count if workspace else count, rng, margin))
    if workspace is not None:
        lo, hi = (np.asarray(w, dtype=float) for w in workspace)
        T = T[np.all((T[:, :3, 3] >= lo) & (T[:, :3, 3] <= hi), axis=-1)]
        if len(T) == 0:
            raise DegenerateExperimentError(f"workspace {workspace}: the arm '{model.name}' never reaches it")
    return T[:count]


def reachable_pose(
    model: ArmModel, rng: np.random.Generator, *, candidates: int = 20, margin: float = 0.2, min_solutions: int = 6,
    workspace: tuple | None = None,
) -> np.ndarray:
    """A tool pose the arm reaches in many ways within its limits (a place to bolt a fixture).

    Draws poses from configurations inside the limits (shrunk by ``margin``) with the tool inside the box
    ``workspace = (lower (3,), upper (3,))`` (world frame) if given; keeps the first with at least
    ``min_solutions`` distinct IK solutions from 24 random starts, else the one with the most.
    """
    best, best_count = None, -1
    for T in candidate_poses(model, candidates, rng, margin, workspace):
        res = solve(PoseConstraint(model, T), random_configurations(model, 24, rng), max_iter=60)
        count = np.unique(np.round(res.q, 2), axis=0).shape[0]
        if count > best_count:
            best, best_count = T, count
        if count >= min_solutions:
            break
    return best
