"""``analyze``: what an experiment will identify and how accurate the calibrated tool will be, before measuring.

``kincal.estimation.plan`` reads one linearization at the starting values; this adds a workspace sample (random
configurations within each calibrated arm's joint limits, seeded) over which the tool accuracy the experiment
would give is predicted, and what errors in held parameters do to the estimates and to the calibrated tool
there (first order, with one common rigid motion removed as the predictions do).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from kincal.analysis.prediction import Prediction, tool_motion
from kincal.errors import ModelError
from kincal.estimation import Problem, SolverOptions
from kincal.estimation.plan import Plan, plan
from kincal.kinematics import Robot
from kincal.simulate import workspace_sample

WORKSPACE_SAMPLES = 200


@dataclass(frozen=True)
class ToolEffect:
    """RMS and max over the workspace sample of the calibrated tool's position (m) and orientation (rad)
    change."""

    position_rms: float
    position_max: float
    orientation_rms: float
    orientation_max: float


@dataclass(frozen=True, eq=False)
class Analysis:
    """``plan``: rank, named null space, indices, predicted standard deviations, held sensitivity;
    ``predictions``: per arm, the tool accuracy over the ``workspace`` sample; ``held_tool``: per held coordinate
    and arm, the tool change per unit error (m or rad); ``errors``, ``shift`` and ``error_tool``: the given
    held errors, the change of every free coordinate they cause and its effect on the tool per arm."""

    plan: Plan
    workspace: Mapping[str, np.ndarray]
    predictions: Mapping[str, Prediction]
    held_tool: Mapping[str, Mapping[str, ToolEffect]]
    errors: Mapping[str, float]
    shift: np.ndarray | None
    error_tool: Mapping[str, ToolEffect]


def analyze(robot: Robot, datasets, free="offsets", *, fixed: Sequence[str] = (), priors=None, noise=None,
            constraints=(), held: Sequence[str] | None = None, errors: Mapping[str, float] | None = None,
            workspace: int = WORKSPACE_SAMPLES, seed: int = 0, options: SolverOptions | None = None) -> Analysis:
    """Analyse the experiment of ``datasets`` (measured, or simulated from a scenario) for calibrating ``free``
    (arguments as ``calibrate``'s). ``held``: fixed coordinates (names or globs) whose errors to propagate
    (default: known experiment frames); ``errors``: {held name: error (m or rad)} to evaluate."""
    if workspace < 2:
        raise ModelError(f"workspace: expected at least 2 sample configurations, found {workspace}")
    problem = Problem.build(robot, datasets, free, fixed=fixed, priors=priors, noise=noise, constraints=constraints)
    p = plan(problem, options, held)
    rng = np.random.default_rng(seed)
    qs = {arm: workspace_sample(robot, arm, workspace, rng) for arm in p.result.state.arms}
    preds = {arm: p.result.predict(q, arm) for arm, q in qs.items()}
    held_tool: dict[str, dict[str, ToolEffect]] = {}
    shift, error_tool = None, {}
    if p.sensitivity is not None:
        per_unit = {arm: tool_motion(p.result, q, arm, p.sensitivity.matrix) for arm, q in qs.items()}
        held_tool = {name: {arm: _effect(m[:, :, j]) for arm, m in per_unit.items()}
                     for j, name in enumerate(p.sensitivity.held)}
        if errors:
            shift = p.sensitivity.shift(errors)
            error_tool = {arm: _effect(tool_motion(p.result, q, arm, shift)) for arm, q in qs.items()}
    elif errors:
        raise ModelError("errors of held parameters given, but nothing is held (every frame is estimated); "
                         "name held parameters that are fixed")
    return Analysis(p, qs, preds, held_tool, dict(errors or {}), shift, error_tool)


def _effect(dx: np.ndarray) -> ToolEffect:
    pos, rot = np.linalg.norm(dx[:, :3], axis=1), np.linalg.norm(dx[:, 3:], axis=1)
    return ToolEffect(float(np.sqrt(np.mean(pos**2))), float(pos.max()), float(np.sqrt(np.mean(rot**2))),
                      float(rot.max()))
