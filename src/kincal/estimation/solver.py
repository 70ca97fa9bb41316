"""The calibration spine: ``Problem.build`` -> ``solve(problem, options)`` = ``iterate`` then ``finalize`` ->
``Result``; ``calibrate`` is the convenience call, ``validate`` adds held-out data sets.

Each outer iteration (``estimation.iterate``): whiten at the current state, analyse the rank of the whitened
Jacobian (``kincal.analysis.identify``), restrict the step to the identifiable subspace (gauge
``"min-change"``: the minimum-norm step in natural units, m and rad; or a user priority list of globs: keep the
first identifiable parameters in that order, hold the rest), solve the inner problem with the analytic
Jacobian, then re-centre (conform twists, re-linearize tangent bases). ``estimation.finalize`` reports.
"""

from __future__ import annotations

from contextlib import ExitStack
from dataclasses import replace
from functools import partial
from typing import Callable, Mapping, Sequence

import numpy as np

from kincal.analysis import Prediction, validation_predictions
from kincal.analysis.prediction import understated, with_doubts
from kincal.data import Dataset
from kincal.errors import DataFormatError, DegenerateExperimentError, ModelError
from kincal.estimation.constraints import FrameDistance
from kincal.estimation.crossval import cross_validate, with_cross_validation
from kincal.estimation.finalize import finalize, untrusted_note
from kincal.estimation.iterate import iterate
from kincal.estimation.options import SolverOptions
from kincal.estimation.outliers import (ROBUST_F_SCALE, ROBUST_LOSS, any_beyond, find_outliers, kept,
                                        outlier_threshold, states_noise)
from kincal.estimation.plausibility import implausible_units
from kincal.estimation.problem import Problem
from kincal.estimation.result import Result
from kincal.estimation.stages import Stage, solve_stages, stage_problems
from kincal.estimation.stats import ResidualStats, ValidationStats
from kincal.experiments import remembered_kinematics
from kincal.kinematics import Robot
from kincal.noise import Noise, effective
from kincal.params import Prior


def calibrate(
    robot: Robot,
    datasets: Sequence[Dataset],
    free: str | Sequence[str] | None = None,
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
    outliers: str | float = "reject",
    cv: int | None = None,
    stages: Sequence[Stage] = (),
) -> Result:
    """Calibrate ``robot`` from ``datasets``: ``solve(Problem.build(...), SolverOptions(...))``, then
    ``validate`` on the held-out ``validation`` sets.

    ``free``: ``"offsets"`` (the default; thesis level 1), ``"kinematic"`` (full POE: offsets, twists, home;
    level 2) or a list of names/globs (level words allowed inside the list). Frames absent from a data set's ``known``
    (fixture pose, clamp, tracker, markers, ...) are always estimated; known ones only when freed by name.
    ``noise``: one ``Noise`` for all data sets or a mapping data set name -> Noise; per quantity it goes over
    each data set's stated noise (``Dataset.meta["noise"]``), over ``kincal.noise.DEFAULT`` (the one noise rule,
    ``kincal.noise.effective``).
    ``constraints``: known relations between frames (``FrameDistance``: e.g. two sockets 50 mm apart).
    ``outliers``: ``"reject"`` (default: rows beyond a tail probability of 1e-6 after a robust pass are left out
    and listed in ``Result.outliers``), ``"keep"``, or the tail probability (``estimation.outliers``); the
    same rule flags validation rows (``validate``).
    ``cv``: K-fold cross-validation by configuration (``estimation.crossval``, ``Result.cross_validation``);
    its model error replaces the variance factor's in the predictions.
    ``stages``: solve in turn with each ``Stage``'s free set, each stage from the previous one's final state
    (``estimation.stages``); then ``free`` and ``fixed`` are not given. The result is the last stage's, with
    ``Result.stages``; outliers are looked for at its end, and the stages run again without them.
    The other keywords are ``SolverOptions``.
    """
    if not datasets:
        raise DegenerateExperimentError("no data sets given: nothing to calibrate from")
    threshold = outlier_threshold(outliers)
    options = SolverOptions(gauge, loss, f_scale, max_outer, rank_rtol, correlation_threshold, progress)
    run = partial(_fit, robot, free=free, fixed=fixed, priors=priors, noise=noise, constraints=constraints,
                  options=options, stages=tuple(stages))
    result = run(datasets)
    if threshold is not None and any_beyond(result.problem, result.state, threshold):
        result = _without_outliers(result, options, threshold, run)
    if cv:
        fit = partial(calibrate, robot, free=free, fixed=fixed, priors=priors, noise=noise, gauge=gauge, loss=loss,
                      f_scale=f_scale, max_outer=max_outer, rank_rtol=rank_rtol,
                      correlation_threshold=correlation_threshold, constraints=constraints, outliers=outliers,
                      stages=stages)
        result = with_cross_validation(result, cross_validate(datasets, cv, fit, threshold=threshold))
    return validate(result, validation, noise, outliers) if validation else result


def _fit(robot: Robot, datasets: Sequence[Dataset], *, free, fixed, priors, noise, constraints,
         options: SolverOptions, stages: tuple[Stage, ...]) -> Result:
    """One solve of ``datasets`` with ``free`` and ``fixed``, or the staged solve of ``stages``."""
    if stages:
        if free is not None or fixed:
            raise ModelError("give 'free' and 'fixed' in each stage, not beside 'stages'")
        problems = stage_problems(robot, datasets, stages, priors, noise, constraints)
        return solve_stages(problems, stages, options, solve)
    free = "offsets" if free is None else free
    with ExitStack() as keep:  # the nominal kinematics of the frames' initial guesses, for the solve's first step
        problem = Problem.build(robot, datasets, free, fixed, priors, noise, constraints, keep=keep)
        if len(problem.free_idx) == 0:
            raise DegenerateExperimentError(
                f"every parameter is fixed: nothing to estimate (free={free!r}, fixed={list(fixed)!r})"
            )
        if problem.blocked:  # solved by blocks: nothing of the data's size kept (``solve``)
            keep.close()
        return _solved(problem, options)  # ``solve``, whose kinematics ``keep`` remembers already (or, by blocks, none)


def _without_outliers(result: Result, options: SolverOptions, threshold: float, refit) -> Result:
    """The solve of ``result.problem`` again without its outlying rows: found at a robust pass (Cauchy loss,
    unless the solve's own loss is robust already), then ``refit`` (the whole solve, every stage of a staged one)
    on the kept data sets. ``result`` itself when no row is beyond ``threshold``."""
    problem = result.problem
    robust = result
    if options.loss == "linear":
        robust = solve(problem, replace(options, loss=ROBUST_LOSS, f_scale=ROBUST_F_SCALE, progress=None))
    found = find_outliers(problem, robust.state, threshold)
    if not found:
        return result
    final = refit(kept([e.dataset for e in problem.experiments], found))
    note = (f"{len(found)} configuration(s) left out as outliers (standardized residual beyond a tail probability "
            f"of {threshold:.3g}; listed in 'outliers'): the estimates and statistics are of the other rows")
    return replace(final, outliers=tuple(found), messages=(note,) + final.messages)


def solve(problem: Problem, options: SolverOptions = SolverOptions()) -> Result:
    """Solve ``problem``: the outer loop (``iterate``) and its report (``finalize``). Raises when nothing is
    free or there are fewer equations than free coordinates; reports (``Result.status``) everything else."""
    with remembered_kinematics(problem.experiments, not problem.blocked):  # an accepted trial's kinematics reused
        return _solved(problem, options)


def _solved(problem: Problem, options: SolverOptions) -> Result:
    """``solve`` within the kinematics it remembers."""
    _require_equations(problem)
    _require_plausible_units(problem)
    return finalize(problem, options, iterate(problem, options))


def evaluate(robot: Robot, datasets: Sequence[Dataset], noise=None) -> list[ResidualStats]:
    """Residual statistics of ``robot`` on ``datasets``; unknown frames (fixture, tracker, ...) are fitted first
    with every arm parameter fixed."""
    problem, state = _frames_fitted(robot, datasets, noise)
    return problem.statistics(state)


def _frames_fitted(robot: Robot, datasets: Sequence[Dataset], noise=None):
    """The problem of ``robot`` on ``datasets`` with every arm parameter fixed, and its state with the unknown
    frames fitted."""
    problem = Problem.build(robot, datasets, [], (), None, noise)
    state = problem.nominal
    if len(problem.free_idx):
        state = iterate(problem, SolverOptions(max_outer=10)).state
    return problem, state


def validate(result: Result, datasets: Sequence[Dataset], noise=None, outliers: str | float = "reject") -> Result:
    """``result`` with its errors on held-out ``datasets`` before and after calibration (``validation``) and what
    the model predicts about its own accuracy there (``predictions``). Each held-out set's noise follows the one
    rule (``kincal.noise.effective``): ``noise`` where it states a quantity (a mapping by data set name: what it
    gives for that set), else the set's own stated noise, else the default. A prediction is not trusted where
    the calibrated model is worse than the nominal one (``worse_than_nominal``); a converged result is then a
    ``misfit``: the model does not explain held-out data as well as the nominal one did. Rows beyond the
    ``outliers`` rule at the calibrated model are left out of the errors and predictions
    (``validation_outliers``; ``validation_all`` has the errors with them)."""
    noises = {v.name: effective(noise.get(v.name) if isinstance(noise, Mapping) else noise, v.meta.get("noise"))
              for v in datasets}
    result, datasets = _validation_outliers(result, datasets, noises, outlier_threshold(outliers))
    rows = validation_stats(result.nominal_robot, result.robot, datasets, noises)
    preds = validation_predictions(result, datasets, [noises[v.name] for v in datasets])
    by_set = {v.experiment: v for v in rows}
    worse = {name: worse_than_nominal(by_set[name], p) for name, p in preds}
    preds = tuple((name, with_doubts(p, worse[name] + understated(p, name, by_set[name].after.position_rms,
                                                                     by_set[name].after.orientation_rms)))
                  for name, p in preds)
    # next to the validation errors: what the model itself predicts about its accuracy there
    result = replace(result, validation=rows, predictions=preds)
    sets = sorted(name for name, why in worse.items() if why)
    if sets and result.status == "converged":
        note = (f"the calibrated model is worse than the nominal one on held-out data ({', '.join(sets)}): it does "
                "not explain the robot; status misfit")
        result = replace(result, status="misfit", messages=(note,) + result.messages)
    note = untrusted_note(result, preds)
    return replace(result, messages=(note,) + result.messages) if note else result


def _validation_outliers(result: Result, datasets, noises, threshold):
    """``result`` with the validation rows beyond ``threshold`` (the calibration data's outlier rule, at the
    calibrated model with the sets' frames fitted) listed, their sets' errors with every row and a message;
    and the validation sets without those rows."""
    noisy = [d for d in datasets if states_noise(d, noises[d.name])]
    if threshold is None or not noisy:
        return result, datasets
    found = find_outliers(*_frames_fitted(result.robot, noisy, noises), threshold)
    if not found:
        return result, datasets
    named = {o.experiment for o in found}
    every = validation_stats(result.nominal_robot, result.robot, [d for d in datasets if d.name in named], noises)
    kept_sets = kept(datasets, found)
    without = {v.experiment: v for v in validation_stats(result.nominal_robot, result.robot,
                                                         [d for d in kept_sets if d.name in named], noises)}
    notes = tuple(f"validation set '{v.experiment}': {sum(o.experiment == v.experiment for o in found)} row(s) "
                  "beyond the outlier rule left out of its validation errors (listed in 'validation_outliers'); "
                  f"position RMS after calibration {_mm(without[v.experiment].after.position_rms)} without them, "
                  f"{_mm(v.after.position_rms)} with them" for v in every)
    return replace(result, validation_outliers=tuple(found), validation_all=every,
                   messages=result.messages + notes), kept_sets


def _mm(x) -> str:
    return "-" if x is None else f"{x * 1e3:.3g} mm"


# Validation after calibration this much above the nominal model's (and above the predicted error) is worse.
WORSE_RATIO = 1.1


def worse_than_nominal(v: ValidationStats, pred: Prediction) -> list[str]:
    """Why the calibrated model is worse than the nominal one on held-out set ``v``: position or orientation RMS
    after calibration above ``WORSE_RATIO`` times the nominal model's and above the predicted RMS error."""
    out = []
    for part, scale, unit, predicted in (("position", 1e3, "mm", pred.position_rms_predicted),
                                         ("orientation", 180 / np.pi, "deg", pred.orientation_rms_predicted)):
        before, after = getattr(v.before, f"{part}_rms"), getattr(v.after, f"{part}_rms")
        if before is not None and after > WORSE_RATIO * before and not after <= predicted:  # nan: not predicted
            out.append(f"on '{v.experiment}' the calibrated model's {part} error ({after * scale:.3g} {unit} RMS) "
                       f"is worse than the nominal model's ({before * scale:.3g} {unit})")
    return out


def validation_stats(nominal: Robot, calibrated: Robot, datasets: Sequence[Dataset],
                     noise=None) -> tuple[ValidationStats, ...]:
    """Errors of the ``nominal`` and of the ``calibrated`` robot on held-out ``datasets`` (``evaluate``), per set:
    also for models kincal did not calibrate (the thesis baselines)."""
    before = evaluate(nominal, datasets, noise)
    after = evaluate(calibrated, datasets, noise)
    return tuple(ValidationStats(b.experiment, b.kind, b.samples, b, a) for b, a in zip(before, after))


def _require_plausible_units(problem: Problem) -> None:
    """Refuse data whose joint readings or measured lengths do not fit the robot's size (a unit mix-up): the
    solve would grind towards an arm 1000 times too small or large (``estimation.plausibility``)."""
    for exp in problem.experiments:
        bad = implausible_units(problem.robot, exp.dataset)
        if bad is not None:
            raise DataFormatError(f"data set '{exp.name}' ({exp.kind}): {bad.describe(problem.robot)}; check the "
                                  "units of its joint readings (rad) and lengths (m)")


def _require_equations(problem: Problem) -> None:
    """Something to estimate. Fewer equations than free coordinates is no error by itself: only the identifiable
    parameters must be fewer than the equations (``iterate``, after the first linearization gives the rank)."""
    if len(problem.free_idx) == 0:
        raise DegenerateExperimentError("every parameter is fixed: nothing to estimate")


__all__ = ["Problem", "SolverOptions", "calibrate", "evaluate", "solve", "validate", "validation_stats"]
