"""What an experiment will identify, before (or without) calibrating: ``plan(problem)`` linearizes at the
starting values (the nominal model, frames started from the data) and reports rank and named null space,
observability indices, the standard deviation each identifiable coordinate would have at the stated noise
(variance factor 1: a model that fits), and how errors in held coordinates spread into the estimates.

The returned ``Plan.result`` is the nominal model dressed as a calibration result at variance factor 1, so
``Plan.result.predict(q, arm)`` gives the tool accuracy the experiment would deliver at any configurations.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from kincal.analysis import Identifiability, covariance
from kincal.analysis.linalg import svd
from kincal.analysis.observability import Observability, observability
from kincal.analysis.sensitivity import Sensitivity, sensitivity
from kincal.errors import ModelError
from kincal.estimation import steps
from kincal.estimation.finalize import finalize
from kincal.estimation.gauge import gauge_basis, priority, rigid_gauges
from kincal.estimation.iterate import Iteration, scale_test_needed
from kincal.estimation.options import SolverOptions
from kincal.estimation.problem import Problem
from kincal.estimation.result import Estimate, Result
from kincal.estimation.sandwich import Sandwich


@dataclass(frozen=True, eq=False)
class Plan:
    """``plan``'s answer. ``estimates``: nominal values with the standard deviations the experiment would give
    (nan where unidentifiable); ``sensitivity``: per held coordinate, the first-order shift of every free one
    (None when nothing is held)."""

    problem: Problem
    identifiability: Identifiability
    observability: Observability
    estimates: tuple[Estimate, ...]
    covariance: np.ndarray
    sensitivity: Sensitivity | None
    result: Result

    @property
    def rank(self) -> int:
        return self.identifiability.rank

    def estimate(self, name: str) -> Estimate:
        for e in self.estimates:
            if e.name == name:
                return e
        raise KeyError(name)


def plan(problem: Problem, options: SolverOptions | None = None, held: Sequence[str] | None = None) -> Plan:
    """The plan of ``problem`` at its starting values. ``held``: names or globs of fixed coordinates whose
    errors to propagate (default: every fixed coordinate of a known experiment frame: clamps, fixtures,
    trackers given as known)."""
    options = options or SolverOptions()
    order = priority(problem, options.gauge)
    lin = steps.linearize(problem, problem.start, None, scale_test_needed(problem))
    it = Iteration(problem.start, "converged", 0, 0, lin, lin.W, None, lin.W,
                   tuple(order), held=rigid_gauges(problem, lin))
    nominal = finalize(problem, options, it)
    ana = nominal.identifiability
    cov = _unit_covariance(problem, lin, ana, options.gauge, order) if ana.rank else np.zeros((lin.p, lin.p))
    std = np.where(ana.identifiable, np.sqrt(np.clip(np.diag(cov), 0, None)), np.nan)
    estimates = tuple(replace(e, value=e.nominal if np.isnan(e.value) else e.value, std=float(s),
                              identifiable=bool(ok)) for e, s, ok in zip(nominal.estimates, std, ana.identifiable))
    result = replace(nominal, covariance=cov, sigma2=1.0, status="converged", estimates=estimates,
                     messages=tuple(ana.messages))
    configurations = sum(e.size for e in problem.experiments)
    B = identifiable_basis(problem, ana)
    obs = observability(svd(lin.Rf @ B, compute_uv=False) if B.shape[1] else np.zeros(0), configurations)
    return Plan(problem, ana, obs, estimates, cov, _held_sensitivity(problem, lin, cov, held), result)


def reach(robot) -> float:
    """A characteristic length of ``robot``: the largest distance of a tool from its arm's base at the zero
    configuration (1 m if that is zero), the unit of lengths in the observability indices."""
    d = [np.linalg.norm((a.home @ a.tool)[:3, 3]) for a in robot.arms.values()]
    return float(max(d)) if d and max(d) > 0 else 1.0


def identifiable_basis(problem: Problem, ana: Identifiability) -> np.ndarray:
    """(p, r) basis of the identifiable subspace in natural units whose coordinates are orthonormal with lengths
    in units of the robot's ``reach``: the scaling of the observability indices and of the design criteria, so
    one set of configurations compares with another (D, I and G do not depend on it)."""
    scale = np.where(np.array(problem.layout.units)[problem.free_idx] == "m", reach(problem.robot), 1.0)
    Q = np.linalg.qr(ana.range_space / scale[:, None])[0]
    return scale[:, None] * Q


def _unit_covariance(problem, lin, ana, gauge, order) -> np.ndarray:
    """The covariance at variance factor 1 in the solve's gauge: what the stated noise alone gives (the sandwich
    where the data are weighted otherwise than by their noise, ``estimation.sandwich``)."""
    V, sw = gauge_basis(lin.Rf, ana, gauge, order), Sandwich.of(problem, lin, np.ones(len(lin.r)))
    return covariance(lin.Rf, V, 1.0) if sw is None else sw.covariance(V, 1.0)


def held_coordinates(problem: Problem, held: Sequence[str] | None) -> np.ndarray:
    """Layout indices of the fixed coordinates ``held`` names (globs over coordinate or block names); default:
    the fixed coordinates of known experiment frames."""
    layout = problem.layout
    fixed = [i for i in range(layout.size) if not layout.free[i]]
    blocks = {i: b for b in layout.blocks for i in range(b.start, b.stop)}
    if held is None:
        return np.array([i for i in fixed if blocks[i].arm is None], int)
    out: list[int] = []
    for pat in held:
        hit = [i for i in fixed if i not in out and (fnmatch.fnmatchcase(layout.names[i], pat)
                                                     or fnmatch.fnmatchcase(blocks[i].name, pat))]
        if not hit:
            raise ModelError(f"held parameter {pat!r} matches no fixed parameter (free ones are estimated, not held)")
        out += hit
    return np.array(out, int)


def _held_sensitivity(problem: Problem, lin, cov, held) -> Sensitivity | None:
    idx = held_coordinates(problem, held)
    if not len(idx):
        return None
    _, J_held, _, _ = problem.linearize(lin.state, lin.W, idx)
    names = [problem.layout.names[i] for i in problem.free_idx]
    return sensitivity(lin.J, J_held, cov, names, [problem.layout.names[i] for i in idx])
