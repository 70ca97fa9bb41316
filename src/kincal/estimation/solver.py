"""The calibration solver: outer re-linearization around a state, inner ``scipy.optimize.least_squares``.

Each outer iteration: whiten at the current state, analyse the rank of the whitened Jacobian, restrict the
step to the identifiable subspace (gauge ``"min-change"``: the minimum-norm step in natural units, m and rad;
or a user priority list of globs: keep the first identifiable parameters in that order, hold the rest), solve
the inner problem with the analytic Jacobian, then re-centre (conform twists, re-linearize tangent bases).
"""

from __future__ import annotations

import fnmatch
import logging
from dataclasses import replace
from typing import Callable, Mapping, Sequence

import numpy as np

from kincal.analysis import analyse, correlated_pairs, covariance, select_columns, validation_predictions
from kincal.data import Dataset
from kincal.errors import DegenerateExperimentError, ModelError
from kincal.estimation import steps
from kincal.estimation.constraints import FrameDistance
from kincal.estimation.naming import analyse_named, block_of, context, degenerate, rotation_nulls, scale_null
from kincal.estimation.problem import Problem, residual_norms
from kincal.estimation.start import starting_state
from kincal.estimation.result import Estimate, Result
from kincal.experiments import build, frame_kinds
from kincal.kinematics import Robot
from kincal.noise import DEFAULT as DEFAULT_NOISE, Noise
from kincal.params import (
    HOME,
    TWISTS,
    Prior,
    State,
    build_layout,
    displacement,
    recentre,
    retract,
    twist_coordinates,
)

log = logging.getLogger(__name__)

# Residual variance factor above which the fit is reported as not explaining the data (RMS 10x the noise).
MISFIT_VARIANCE_FACTOR = 100.0


def calibrate(
    robot: Robot,
    datasets: Sequence[Dataset],
    free: str | Sequence[str] = "offsets",
    *,
    fixed: Sequence[str] = (),
    priors: Mapping[str, Prior] | None = None,
    noise: Noise | Mapping[str, Noise] | None = None,
    gauge: str | Sequence[str] = "min-change",
    loss: str = "linear",
    f_scale: float = 1.0,
    max_outer: int = 20,
    rank_rtol: float = 1e-9,
    correlation_threshold: float = 0.9,
    validation: Sequence[Dataset] = (),
    constraints: Sequence[FrameDistance] = (),
    progress: Callable[[int, float], None] | None = None,
) -> Result:
    """Calibrate ``robot`` from ``datasets``.

    ``free``: ``"offsets"`` (thesis level 1), ``"kinematic"`` (full POE: offsets, twists, home; level 2) or a
    list of names/globs (level words allowed inside the list). Frames absent from a data set's ``known``
    (fixture pose, clamp, tracker, markers, ...) are always estimated; known ones only when freed by name.
    ``noise``: one ``Noise`` for all data sets or a mapping data set name -> Noise.
    ``constraints``: known relations between frames (``FrameDistance``: e.g. two sockets 50 mm apart).
    """
    if not datasets:
        raise DegenerateExperimentError("no data sets given: nothing to calibrate from")
    problem, unknown = _problem(robot, datasets, free, fixed, priors, noise, constraints)
    p = len(problem.free_idx)
    if p == 0:
        raise DegenerateExperimentError(
            f"every parameter is fixed: nothing to estimate (free={free!r}, fixed={list(fixed)!r})"
        )
    eqs = problem.equations()
    m = sum(eqs) + len(problem.prior_idx) + len(problem.constraints)
    if m < p:
        per = ", ".join(f"'{e.name}' ({e.kind_name}, {e.size} samples): {n}" for e, n in zip(problem.experiments, eqs))
        raise DegenerateExperimentError(
            f"{m} equations for {p} unknowns: too few configurations for the free parameters "
            f"(equations per data set: {per})"
        )
    result = _solve(problem, robot, gauge, loss, f_scale, max_outer, rank_rtol, correlation_threshold, progress)
    if validation:
        result = _with_validation(result, validation, noise)
    return result


def evaluate(robot: Robot, datasets: Sequence[Dataset], noise=None) -> list[dict]:
    """Residual statistics of ``robot`` on ``datasets``; unknown frames (fixture, tracker, ...) are fitted first
    with every arm parameter fixed."""
    problem, unknown = _problem(robot, datasets, [], (), None, noise)
    state = problem.nominal
    if len(problem.free_idx):
        res = _solve(problem, robot, "min-change", "linear", 1.0, 10, 1e-9, 0.9, None, quiet=True)
        state = res.state
    return problem.statistics(state)


def _problem(robot, datasets, free, fixed, priors, noise, constraints=()):
    nominal_arms = State.from_robot(robot)
    exps, extras, unknown = build(datasets, nominal_arms)
    arms = [a for a in robot.arms if any(a in e.arms for e in exps)]
    nominal = State({a: nominal_arms.arms[a] for a in arms}, extras, frame_kinds(exps))
    layout = build_layout(nominal, free, fixed=fixed, priors=priors, free_extras=unknown, arms=arms)
    for name in unknown:
        b = layout.block(name)
        if not layout.free[b.start: b.stop].all():
            raise ModelError(f"'{name}' is unknown (not given in its data set) and cannot be fixed; give its value")
    if isinstance(noise, Mapping):
        bad = set(noise) - {e.name for e in exps}
        if bad:
            raise ModelError(f"noise given for unknown data set(s) {sorted(bad)}; data sets: {[e.name for e in exps]}")
        noises = [noise.get(e.name, DEFAULT_NOISE) for e in exps]
    else:
        noises = [noise or DEFAULT_NOISE] * len(exps)
    for c in constraints:
        c.check(nominal)
    start, nominal = starting_state(nominal, exps, layout, unknown)
    return Problem(exps, layout, nominal, noises, start=start, constraints=tuple(constraints)), unknown


def _priority(problem: Problem, gauge) -> list[int]:
    """Free-coordinate order for pivots: user globs first (if any), then arm offsets, twists, home, base, tool,
    then experiment frames."""
    names = problem.free_names
    blk = [problem.layout.block_at(i) for i in range(problem.layout.size)]
    default = sorted(range(len(names)), key=lambda k: (blk[problem.free_idx[k]].kind.rank, k))
    if isinstance(gauge, str):
        return default
    order: list[int] = []
    for pat in gauge:
        hit = [k for k in default if k not in order and (
            fnmatch.fnmatchcase(names[k], pat) or fnmatch.fnmatchcase(blk[problem.free_idx[k]].name, pat))]
        if not hit:
            raise ModelError(f"gauge priority pattern {pat!r} matches no free parameter")
        order += hit
    return order + [k for k in default if k not in order]


def _solve(problem, robot, gauge, loss, f_scale, max_outer, rank_rtol, corr_threshold, progress, quiet=False):
    if not (gauge == "min-change" or not isinstance(gauge, str)):
        raise ModelError(f"gauge must be 'min-change' or a list of parameter globs in priority order, got {gauge!r}")
    names = problem.free_names
    p = len(names)
    order = _priority(problem, gauge)
    state = problem.start
    describe_ctx = context(problem)
    every = any(problem.layout.units[i] == "m" for i in problem.free_idx)  # the scale test needs every column
    messages: list[str] = []
    id_before = None
    evaluations = 0
    status = "not converged"
    lin = None
    it = 0
    W = None
    fast = True  # Gauss-Newton steps first while they converge fast
    for it in range(1, max_outer + 1):
        # Whiten at the start and once more at the first estimate, then hold: when the model cannot explain
        # the data, re-whitening at every estimate moves the optimum each time and the loop never settles.
        # Without encoder noise the whitening does not depend on the state at all.
        if it <= 2 and problem.joint_noise:
            W = None
        first = id_before is None
        lin = steps.linearize(problem, state, W, every)
        W = lin.W
        if first:
            before = problem.statistics(state, W)
            ana = id_before = analyse_named(problem, state, lin, rank_rtol, order, describe_ctx)
            if degenerate(problem, lin.Rf, ana):
                status = "degenerate"
                break
            _require_redundancy(problem, len(lin.r), ana.rank)
        else:
            ana = analyse(lin.Rf, names, rtol=rank_rtol, priority=order,
                          scale=scale_null(problem, state, lin) if every else None,
                          held=rotation_nulls(problem, state, lin))
        V = _gauge_basis(lin.Rf, ana, gauge, order)
        z, r1sq = steps.gauss_newton(lin, V)
        if it > 1 and steps.negligible(lin, V, z, r1sq):
            status = "converged"  # the re-linearized problem asks for no step
            break
        # Gauss-Newton step first (it costs one residual evaluation); least_squares (LM, or TRF with a robust
        # loss) solves the inner problem when the full step does not reduce the cost as the linear model
        # predicts (far from the optimum, strongly nonlinear), when Gauss-Newton has stopped converging fast,
        # or when a robust loss is asked for.
        accepted = False
        if loss == "linear" and fast:
            r_new = problem.evaluate(state, V @ z, W, jac=False)[0]
            evaluations += 1
            cost2_new = float(r_new @ r_new)
            accepted = lin.cost2 - cost2_new >= 0.25 * (lin.cost2 - r1sq)
            # Gauss-Newton is fast near a small-residual optimum (the cost falls by orders of magnitude); on
            # a large-residual problem (a model that cannot fit) it crawls: least_squares from then on.
            # At the noise floor (chi^2 about its degrees of freedom) the remaining steps are small either way.
            fast = accepted and (cost2_new <= 0.1 * lin.cost2 or cost2_new <= 2.0 * (len(lin.r) - V.shape[1]))
        if accepted:
            x, cost = z, 0.5 * cost2_new
        else:
            x, cost, nfev = steps.inner_solve(problem, state, lin, V, loss, f_scale)
            evaluations += nfev
        delta = V @ x
        step = float(np.linalg.norm(lin.Rf @ delta))
        state = recentre(retract(state, problem.layout, problem.full_delta(delta)))
        if progress:
            progress(it, 2 * cost)
        log.debug("outer %d (%s): cost %.6g, whitened step %.3g, max |delta| %.3g", it,
                  "Gauss-Newton" if accepted else "least_squares", 2 * cost, step, np.max(np.abs(delta), initial=0))
        r0_norm, m = np.sqrt(lin.cost2), len(lin.r)
        lin = None  # the state moved
        # stop when the step is negligible against the residual (or, with noise, well below one sigma)
        if steps.converged(step, r0_norm, cost, m - V.shape[1]) or np.max(np.abs(delta), initial=0) < 1e-13:
            status = "converged"
            break

    if lin is None:  # the loop stopped after a step: linearize the final state
        if problem.joint_noise:
            W = None
        lin = steps.linearize(problem, state, W, every)
        W = lin.W
    ana = analyse_named(problem, state, lin, rank_rtol, order, describe_ctx)
    if status == "degenerate":
        messages.append("degenerate experiment: no arm parameter can be identified from these data; "
                        "nothing was estimated")
    elif status == "not converged":
        messages.append(f"did not converge in {max_outer} outer iterations")
    if status != "degenerate":
        for name, before_q, after_q in _lost_joint_sensitivity(problem, state):
            status = "degenerate"
            messages.append(
                f"degenerate solution for '{name}': its residuals no longer depend on the joint readings "
                f"(sensitivity {before_q:.3g} at the nominal model, {after_q:.3g} at the solution): the solver found "
                "a model whose tool does not move with the joints, which fits any such data exactly (with "
                "position-only loops and no known length, every joint axis through one point). Free fewer "
                "parameters (e.g. 'offsets'), or measure a length")
    dof = len(lin.r) - ana.rank
    sigma2 = lin.cost2 / dof if dof > 0 else float("nan")
    V = _gauge_basis(lin.Rf, ana, gauge, order)
    cov = covariance(lin.Rf, V, sigma2 if np.isfinite(sigma2) else 1.0) if V.shape[1] else np.zeros((p, p))
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    ok = ana.identifiable & (status != "degenerate")
    std = np.where(ok, std, np.nan)
    estimates = _estimates(problem, state, std, ok)
    messages += list(ana.messages)
    if dof <= 0:
        messages.append("as many equations as identifiable parameters: no residual variance, standard deviations "
                        "are not scaled")
    elif sigma2 > MISFIT_VARIANCE_FACTOR:
        messages.insert(0, (
            f"the model does not explain the data: residuals are {np.sqrt(sigma2):.3g} times the stated noise "
            f"(residual variance factor {sigma2:.3g}); the estimates absorb what the free parameters cannot model "
            f"and their standard deviations assume a model that fits. {_misfit_advice(problem)}"))
    tw_names, tw_vals, tw_cov = twist_coordinates(state, problem.layout, _embed(cov, problem))
    twists = (tuple(tw_names), tw_vals, np.sqrt(np.clip(np.diag(tw_cov), 0, None)) if tw_cov is not None else None)
    return Result(
        robot=state.to_robot(robot) if not quiet else robot,
        nominal_robot=robot,
        state=state,
        layout=problem.layout,
        estimates=tuple(estimates),
        covariance=cov,
        correlated=tuple(correlated_pairs(cov, names, corr_threshold, ok)),
        identifiability=ana,
        identifiability_before=id_before,
        before=tuple(before),
        after=tuple(problem.statistics(state, W)),
        sigma2=sigma2,
        status=status,
        iterations=it,
        evaluations=evaluations,
        messages=tuple(messages),
        extras=dict(state.extras),
        twists=twists,
    )


def _misfit_advice(problem: Problem) -> str:
    """What to try when the model does not fit, from what is free already."""
    layout = problem.layout
    geometric = [b for b in layout.blocks if b.kind in (TWISTS, HOME)]
    tips = []
    if not all(layout.free[b.start: b.stop].all() for b in geometric):
        tips.append("free more parameters (e.g. 'kinematic')")
    tips.append("check the stated noise")
    tips.append("look for outliers (a robust loss)")
    tips.append("check the starting values: the nominal model, and the nominal tool and base frames in particular, "
                "may be so far from the truth that the solve stopped in a local minimum")
    return "Possible causes: " + "; ".join(tips) + "."


# A model whose residuals depend this much less on the joint readings than the nominal's has collapsed.
COLLAPSE_RATIO = 1e-3


def _lost_joint_sensitivity(problem: Problem, state) -> list[tuple[str, float, float]]:
    """Experiments whose residuals hardly depend on the joint readings any more: (name, RMS |dr/dq| at the
    nominal state, at ``state``). The data are then explained without the arm moving: a degenerate model."""
    out = []
    for exp in problem.experiments:
        if exp.size > 200:  # a collapse is global: an evenly spread subset shows it as well
            exp = type(exp)(exp.dataset.subset(np.linspace(0, exp.size - 1, 200).astype(int)), exp.frames)
        rms = []
        for st in (problem.nominal, state):
            jq = exp.residual(st, want=set(), jq=True).jq
            rms.append(float(np.sqrt(np.mean([np.mean(j**2) for j in jq.values()]))) if jq else 0.0)
        if rms[0] > 0 and rms[1] < COLLAPSE_RATIO * rms[0]:
            out.append((exp.name, rms[0], rms[1]))
    return out


def _gauge_basis(Rf, ana, gauge, order) -> np.ndarray:
    """Columns spanning the coordinates the solver moves: the identifiable subspace (min-change) or the
    identifiable parameters first in the user's priority order (the rest held)."""
    if isinstance(gauge, str):
        return ana.range_space
    R = ana.range_space  # columns independent there avoid every null direction, a held scale included
    return np.eye(Rf.shape[1])[:, select_columns(Rf @ R @ R.T, order, ana.rank)]


def _require_redundancy(problem, m: int, rank: int) -> None:
    """At least as many residual degrees of freedom as identifiable parameters.

    The standard deviations are scaled by the residual variance; with fewer redundant equations than
    parameters that scale (and any check of the model against the data) rests on too little.
    """
    if m - rank < rank:
        per = ", ".join(f"'{e.name}' ({e.kind_name}): {e.size} configurations" for e in problem.experiments)
        need = ", ".join(f"'{e.name}'" for e in problem.experiments)
        raise DegenerateExperimentError(
            f"{m} equations for {rank} identifiable parameters: too few configurations to calibrate and check "
            f"the result (at least {2 * rank} equations needed; {per}); measure more configurations in {need}"
        )


def _embed(cov, problem):
    full = np.zeros((problem.layout.size, problem.layout.size))
    full[np.ix_(problem.free_idx, problem.free_idx)] = cov
    return full


def _estimates(problem, state, std, ok):
    layout = problem.layout
    disp, _ = displacement(state, problem.nominal, layout)
    out = []
    for k, i in enumerate(problem.free_idx):
        b = block_of(problem, i)
        nominal = float(b.kind.values(b.value(problem.nominal))[i - b.start]) if b.kind.absolute else 0.0
        out.append(Estimate(layout.names[i], nominal + float(disp[i]), nominal, float(std[k]), layout.units[i],
                            bool(ok[k])))
    return out


def _with_validation(result: Result, validation, noise) -> Result:
    if isinstance(noise, Mapping):  # per-set noise names the calibration data: kincal's default for the validation
        # sets, and for quantities it does not state (pixels) what each validation set states
        noise = {v.name: DEFAULT_NOISE.over(Noise.from_si(v.meta.get("noise") or {})) for v in validation}
    before = evaluate(result.nominal_robot, validation, noise)
    after = evaluate(result.robot, validation, noise)
    rows = []
    for b, a in zip(before, after):
        row = {"experiment": b["experiment"], "kind": b["kind"], "samples": b["samples"]}
        for k in ("position_rms", "position_max", "orientation_rms", "orientation_max", "pixel_rms", "pixel_max"):
            if k in b:
                row[f"{k}_before"], row[f"{k}_after"] = b[k], a[k]
        rows.append(row)
    # next to the validation errors: what the model itself predicts about its accuracy there
    return replace(result, validation=tuple(rows), predictions=validation_predictions(result, validation))


__all__ = ["calibrate", "evaluate", "residual_norms"]
