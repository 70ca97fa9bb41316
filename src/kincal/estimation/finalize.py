"""The end of ``solve``: identifiability, covariance, estimates and messages at the state the loop stopped at."""

from __future__ import annotations

import math

import numpy as np

from kincal.analysis import Identifiability, Linearization, correlated_pairs, covariance, identify
from kincal.analysis.identifiability import coupling_gauges
from kincal.estimation import steps
from kincal.estimation.blocks import weighted_factor
from kincal.estimation.gauge import gauge_basis
from kincal.estimation.iterate import Iteration, scale_test_needed
from kincal.estimation.options import SolverOptions
from kincal.estimation.plausibility import negative_compliance_notes, negative_compliances
from kincal.estimation.problem import SENSITIVITY_SAMPLES, Problem
from kincal.estimation.result import (Deferred, Estimate, FinalReport, Result, TwistEstimate, estimates_of,
                                      low_redundancy, new_result)
from kincal.estimation.sandwich import Sandwich
from kincal.estimation.stats import mean
from kincal.experiments.markers import MarkersExperiment
from kincal.experiments.pose import PoseExperiment
from kincal.params import HOME, TWISTS, displacement, twist_coordinates

# Residual variance factor above which the fit is reported as not explaining the data (RMS 10x the noise).
MISFIT_VARIANCE_FACTOR = 100.0
# Below it, a factor above this (residuals twice the noise) on at least NOISE_NOTE_DOF degrees of freedom is no
# chance (chi^2 with 10 dof exceeds 4 x 10 one time in 60,000): the result says so, its status unchanged.
NOISE_NOTE_FACTOR, NOISE_NOTE_DOF = 4.0, 10
# A model whose residuals depend this much less (or 1/this more) on the joint readings than the nominal's has
# collapsed (or blown up): calibration corrects a geometry, it does not rescale the arm's motion 10 times.
COLLAPSE_RATIO = 0.1
# Statuses of a ``Result``, in the order a verdict prefers them (docs/calibration.md "Statuses and exit codes").
STATUSES = ("converged", "misfit", "not converged", "degenerate")


def untrusted_note(result, predictions) -> str | None:
    """Why a converged, validated ``result`` must not read as success although it fits: directions the data
    cannot (or barely) determine move the tool at a validation set's configurations, so the model cannot
    vouch for its accuracy there (``Result.trusted`` false; ``kincal calibrate`` exits 5). None otherwise."""
    moving = sorted({name for name, p in predictions if p.null_moving or p.weak_moving})
    if result.status != "converged" or not moving:
        return None
    return (f"not trusted: directions the calibration data cannot determine (held at nominal) or determine only "
            f"from the noise move the tool on the validation set(s) {', '.join(moving)}; the model fits its data "
            "but cannot vouch for its accuracy there (exit code 5)")


def finalize(problem: Problem, options: SolverOptions, run: Iteration) -> Result:
    """The ``Result`` of the loop's outcome ``run``: linearize the final state if the loop moved it, analyse it,
    the covariance in the solve's gauge scaled by the residual variance, estimates, twists and messages."""
    lin = run.linearization
    if lin is None:  # the loop stopped after a step: linearize the final state
        lin = steps.linearize(problem, run.state, None if problem.joint_noise else run.whiteners,
                              scale_test_needed(problem))
    ana, named_now = _final_analysis(problem, options, run, lin)
    weights, slopes = robust_weights(lin.r, options.loss, options.f_scale)
    dof = len(lin.r) - ana.rank
    sigma2, sw = noise_variance_factor(problem, lin, ana, weights, slopes)
    status, messages = _status(problem, run, options, sigma2)
    scale = covariance_scale(sigma2, dof, ana.rank)
    cov, ok = _uncertainty(lin, ana, options, run.order, scale, status, weights, sw)
    messages.append(_REPORT)  # where the final report's messages go (``FinalReport``: named when read)
    if low_redundancy(dof, ana.rank):
        messages.append(low_redundancy_note(len(lin.r), ana.rank, sigma2))
    if dof <= 0:
        messages.append("as many equations as identifiable parameters: no residual variance, standard deviations "
                        "are not scaled")
    elif sigma2 > MISFIT_VARIANCE_FACTOR:
        messages.insert(0, (
            f"the model does not explain the data: residuals are {np.sqrt(sigma2):.3g} times the stated noise "
            f"(residual variance factor {sigma2:.3g}); the estimates absorb what the free parameters cannot model "
            f"and their standard deviations assume a model that fits. {_misfit_advice(problem)}"))
    elif sigma2 > NOISE_NOTE_FACTOR and dof >= NOISE_NOTE_DOF:
        messages.append(_noise_note(sigma2))
    estimates = tuple(_estimates(problem, run.state, ok, cov))  # std from cov through the displacement
    negative = negative_compliances(problem.layout, estimates)
    messages[:0] = negative_compliance_notes(negative)
    k = messages.index(_REPORT)
    report = FinalReport(ana, lin, problem.layout, tuple(problem.experiments), tuple(run.order),
                         coupling_gauges(run.state, run.first), tuple(messages[:k]), tuple(messages[k + 1:]))
    if named_now is not None:
        report.__dict__["report"] = named_now  # named already (the loop stopped at its start)
    frozen_cov = cov.copy()  # what the deferred fields (read rarely) are computed from, whatever a reader does to cov
    return new_result(
        robot=run.state.to_robot(problem.robot), nominal_robot=problem.robot, state=run.state,
        layout=problem.layout, estimates=estimates, covariance=cov,
        correlated=Deferred(_correlated, frozen_cov, estimates, options.correlation_threshold, ok),
        identifiability=report, start_identifiability=run.first,
        before=Deferred(_after, problem, problem.start, run.start_whiteners),
        after=Deferred(_after, problem, run.state, lin.W), sigma2=sigma2, status=status,
        iterations=run.iterations, evaluations=run.evaluations, messages=report,
        extras=dict(run.state.extras), problem=problem, linearization=lin,
        twists=Deferred(_twists, problem, run.state, frozen_cov), weights=None if options.loss == "linear" else weights,
        covariance_scale=scale, negative_compliances=negative, held=run.held,
    )


_REPORT = object()  # the final report's place among the messages


def _final_analysis(problem: Problem, options: SolverOptions, run: Iteration, lin: Linearization):
    """The identifiability at the final linearization ``lin`` (not named), and its named report where that is
    at hand already (the loop stopped at its start: the start's report), else None."""
    if run.first is not None and run.analysis is run.first.analysis:  # the loop stopped at its start
        report = run.first.report
        return report, report
    if run.analysis is not None and run.linearization is not None:  # the loop analysed this linearization
        return run.analysis, None
    return identify(lin, problem.layout, problem.experiments, rtol=options.rank_rtol, priority=list(run.order),
                    report=False, hold=run.held), None


def covariance_scale(sigma2: float, dof: int, rank: int) -> float:
    """The factor that scales the covariance: the residual variance factor; with low redundancy never below 1
    (the stated noise), since a variance factor from a few degrees of freedom may come out small by chance
    (with 3 degrees of freedom below 0.07 one time in 20)."""
    if low_redundancy(dof, rank) and math.isfinite(sigma2):
        return max(sigma2, 1.0)
    return sigma2


def low_redundancy_note(m: int, rank: int, sigma2: float) -> str:
    return (f"low redundancy: {m} equations for {rank} identifiable parameters (fewer than {2 * rank}): the residual "
            f"variance factor ({sigma2:.3g}) rests on {m - rank} degrees of freedom and the fit barely checks the "
            "model; standard deviations use the stated noise where the residuals are smaller; not trusted until "
            "validated on fresh configurations (measure more, or give validation data)")


def robust_weights(r: np.ndarray, loss: str, f_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Per whitened residual row, scipy's robust ``loss`` as weights: ``w = rho'(z)`` with ``z = (r / f_scale)^2``
    (at the optimum the robust fit is the least-squares fit weighted by ``w``) and the slope of the influence
    ``psi = w r``, ``psi' = rho'(z) + 2 z rho''(z)`` (clipped at 0): how much each row still informs the fit.
    Both 1 for ``linear``."""
    if loss == "linear":
        ones = np.ones_like(r)  # both: read, never written
        return ones, ones
    z = (r / f_scale) ** 2
    if loss == "huber":
        w = np.where(z <= 1, 1.0, 1.0 / np.sqrt(np.maximum(z, 1.0)))
        return w, np.where(z <= 1, 1.0, 0.0)
    if loss == "soft_l1":
        return 1.0 / np.sqrt(1.0 + z), (1.0 + z) ** -1.5
    if loss == "cauchy":
        return 1.0 / (1.0 + z), np.clip((1.0 - z) / (1.0 + z) ** 2, 0.0, None)
    if loss == "arctan":
        return 1.0 / (1.0 + z**2), np.clip((1.0 - 3.0 * z**2) / (1.0 + z**2) ** 2, 0.0, None)
    return np.ones_like(r), np.ones_like(r)


def noise_variance_factor(problem: Problem, lin: Linearization, ana: Identifiability, weights: np.ndarray,
                          slopes: np.ndarray) -> tuple[float, Sandwich | None]:
    """The residual variance factor against the stated noise, and the sandwich (``estimation.sandwich``) where
    a data set is weighted otherwise than by its noise (None elsewhere: ``variance_factor`` of the fit)."""
    sw = Sandwich.of(problem, lin, weights)
    if sw is None:
        return variance_factor(lin.r, weights, slopes, ana.rank), None
    return sw.variance_factor(ana.range_space, ana.rank), sw


def variance_factor(r: np.ndarray, weights: np.ndarray, slopes: np.ndarray, rank: int) -> float:
    """``sum psi^2 / (sum psi' - rank)`` (Huber's scale of an M-estimate; ``chi^2 / (m - rank)`` for the linear
    loss): rows a robust loss discounts neither inflate it nor count as degrees of freedom. nan without any."""
    dof = float(slopes.sum()) - rank
    return float(((weights * r) ** 2).sum()) / dof if dof > 0 else float("nan")


def _status(problem: Problem, run: Iteration, options: SolverOptions, sigma2: float) -> tuple[str, list[str]]:
    """The final status and what it says: a collapsed model makes a solve degenerate, a converged one that does
    not explain the data (variance factor above ``MISFIT_VARIANCE_FACTOR``) is a misfit."""
    status, messages = run.status, []
    if status == "degenerate":
        messages.append("degenerate experiment: no arm parameter can be identified from these data; "
                        "nothing was estimated")
    elif status == "not converged":
        messages.append(f"did not converge in {options.max_outer} outer iterations")
    if status != "degenerate":
        for name, before_q, after_q in _lost_joint_sensitivity(problem, run.state):
            status = "degenerate"
            messages.append(_collapse_message(name, before_q, after_q))
    if status == "converged" and sigma2 > MISFIT_VARIANCE_FACTOR:
        status = "misfit"
    return status, messages


def _collapse_message(name: str, before_q: float, after_q: float) -> str:
    sens = f"(sensitivity {before_q:.3g} at the nominal model, {after_q:.3g} at the solution)"
    if after_q > before_q:
        return (f"degenerate solution for '{name}': its residuals depend {after_q / before_q:.3g} times more on the "
                f"joint readings than at the nominal model {sens}: the calibrated arm's motion is out of scale with "
                "the robot. Check the units of the data (lengths in mm or m, joints in deg or rad)")
    return (f"degenerate solution for '{name}': its residuals no longer depend on the joint readings {sens}: "
            "the solver found a model whose tool hardly moves with the joints, which fits such data (with "
            "position-only loops and no known length, every joint axis through one point; measured points or "
            "poses in metres where the data set says mm). Check the units of the data, free fewer parameters "
            "(e.g. 'offsets'), or measure a length")


def _uncertainty(lin: Linearization, ana: Identifiability, options: SolverOptions, order, sigma2: float,
                 status: str, weights: np.ndarray, sw: Sandwich | None = None):
    """Covariance (p, p) in the solve's gauge (of the robustly weighted problem with a robust loss) scaled by
    ``sigma2`` (the sandwich ``sw`` where the fit is not weighted by the noise) and the mask of identifiable
    coordinates (the standard deviations are ``_estimates``': of the reported displacements)."""
    p = lin.p
    Rf = lin.Rf if options.loss == "linear" else weighted_factor(lin.J, weights)
    V = gauge_basis(Rf, ana, options.gauge, list(order))
    s2 = sigma2 if math.isfinite(sigma2) else 1.0
    if not V.shape[1]:
        cov = np.zeros((p, p))
    elif sw is not None:
        cov = sw.covariance(V, s2)
    elif ana.factor is not None and options.loss == "linear" and V is ana.range_space:  # the analysis' SVD of Rf
        cov = ana.factor.covariance(V, s2)
    else:
        cov = covariance(Rf, V, s2)
    return cov, ana.identifiable & (status != "degenerate")


def _noise_note(sigma2: float) -> str:
    return (f"residuals are {np.sqrt(sigma2):.3g} times the stated noise (residual variance factor {sigma2:.3g}, "
            f"below the misfit rule's {MISFIT_VARIANCE_FACTOR:g}): the stated noise is too small or the model misses "
            "an effect of that size; the standard deviations are scaled by the factor")


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


def _lost_joint_sensitivity(problem: Problem, state) -> list[tuple[str, float, float]]:
    """Experiments whose residuals (of one quantity: position, orientation, ...) depend on the joint readings
    ``COLLAPSE_RATIO`` less or 1 / ``COLLAPSE_RATIO`` more than at the nominal state: (name, RMS |dr/dq| at
    the nominal state, at ``state``). The data are then explained by an arm out of scale with the robot (a
    collapsed arm that hardly moves, a unit mix-up): a degenerate model."""
    out = []
    kept = [problem.cache.kept(st, problem.experiments) for st in (problem.nominal, state)]
    for i, exp in enumerate(problem.experiments):
        if exp.size > SENSITIVITY_SAMPLES:  # a collapse is global: an evenly spread subset shows it as well
            idx = np.linspace(0, exp.size - 1, SENSITIVITY_SAMPLES).astype(int)
            exp = type(exp)(exp.dataset.subset(idx), exp.frames)
        comps = exp.components()
        sens = [_joint_sensitivity(exp, st, comps, None if res is None else res[i])
                for st, res in zip((problem.nominal, state), kept)]
        for q in dict.fromkeys(comps):
            before, after = sens[0][q], sens[1][q]
            if before > 0 and not COLLAPSE_RATIO * before <= after <= before / COLLAPSE_RATIO:
                out.append((exp.name, before, after))
                break
    return out


def _joint_sensitivity(exp, state, comps, res=None) -> dict:
    """RMS of |dr/dq| over samples, arms and joints, per residual quantity of ``exp`` at ``state``; ``res``: its
    residual there with Jacobian blocks, if kept (``offset_columns``)."""
    jq = offset_columns(exp, state, res)
    if jq is None:
        jq = exp.residual(state, want=set(), jq=True).jq
    out = {}
    for q in dict.fromkeys(comps):
        # the rows of the quantity copied out even where they are all of them: the copy's memory order is numpy's
        # choice for the source's layout, and a mean sums in memory order (a C-ordered copy of a transposed
        # Jacobian sums in another order, one ulp apart)
        rows = np.array([c is q or c == q for c in comps], bool)
        means = [_mean_square(j[:, rows]) for j in jq.values()]
        # the mean of one mean is itself (x / 1): np.mean's list conversion only where there are more
        out[q] = math.sqrt(means[0] if len(means) == 1 else np.mean(means)) if jq else 0.0
    return out


def _mean_square(x: np.ndarray):
    """``np.mean(x ** 2)`` (``stats.mean``; ``math.sqrt`` of it is ``np.sqrt``'s: both round correctly)."""
    return mean(x * x)


# Kinds whose ``dr/dq`` is exactly their arm's offset columns (readings enter only as ``q + offset`` of one
# plain chain), computed by the same kernel call (``experiments._kernel.arm_jacobians``).
_OFFSET_KINDS = (MarkersExperiment, PoseExperiment)


def offset_columns(exp, state, res) -> dict | None:
    """``{arm: dr/dq}`` of ``exp`` at ``state`` read off the offset columns of its residual ``res`` (a
    linearization's, with Jacobian blocks), bit for bit what ``exp.residual(state, jq=True).jq`` gives; None
    where that does not hold or the offsets are not among the blocks: a chain carried by another arm, loaded
    (tool loads, its own weight), with lateral compliance or coupled joints."""
    if res is None or type(exp) not in _OFFSET_KINDS or len(exp.arms) != 1 or "wrench_tool" in exp.dataset.measured:
        return None
    arm = exp.arms[0]
    a = state.arms[arm]
    plain = not state.mounts and a.weights is None and a.lateral is None and a.coupling is None
    J = res.jac.get(f"{arm}.offsets")
    return {arm: J} if plain and J is not None else None


def _after(problem: Problem, state, whiteners) -> tuple:
    """The residual statistics at ``state`` (pure: the same numbers whenever computed)."""
    return tuple(problem.statistics(state, whiteners))


def _correlated(cov: np.ndarray, estimates, threshold: float, ok) -> tuple:
    """The pairs of ``estimates`` (the free coordinates, in order) correlated beyond ``threshold``."""
    return tuple(correlated_pairs(cov, [e.name for e in estimates], threshold, ok))


def _twists(problem: Problem, state, cov: np.ndarray) -> tuple[TwistEstimate, ...]:
    """Derived twist coordinates of every arm with free twists, with standard deviations from ``cov``."""
    full = np.zeros((problem.layout.size, problem.layout.size))
    full[np.ix_(problem.free_idx, problem.free_idx)] = cov
    names, values, tw_cov = twist_coordinates(state, problem.layout, full)
    std = np.sqrt(np.clip(np.diag(tw_cov), 0, None))
    return tuple(TwistEstimate(n, float(v), float(s)) for n, v, s in zip(names, values, std))


def _estimates(problem: Problem, state, ok, cov: np.ndarray) -> list[Estimate]:
    """One Estimate per free coordinate: absolute kinds (offsets, compliance) their value, the others the
    displacement from nominal, whose std is the covariance ``cov`` (in the tangent coordinates at ``state``)
    propagated through the displacement's Jacobian, so value and std are in the same coordinates (a twist moved
    far from nominal: its tilts at the estimate are no longer its tilts from nominal)."""
    layout = problem.layout
    free = problem.free_idx
    wanted = [b for b in layout.blocks if b.name in problem.want]  # those holding a free coordinate
    disp, D = displacement(state, problem.nominal, layout, free, jacobian=True, blocks=wanted)
    Df = D.take(free, 0).take(free, 1)  # D[np.ix_(free, free)], copied by take without fancy indexing
    var = ((Df @ cov) * Df).sum(axis=1)  # diag(Df cov Df^T) (a three-operand einsum loops in p^3 steps)
    std = np.where(ok, np.sqrt(np.maximum(var, 0)), np.nan)  # np.clip(x, 0, None) is np.maximum(x, 0)
    nominal = np.zeros(layout.size)  # absolute kinds (offsets, compliance) report values, the others changes
    value = disp.copy()
    for b in layout.blocks:
        if b.kind.absolute:  # the state's own value, bit for bit what the returned model carries
            nominal[b.slice] = b.kind.values(b.value(problem.nominal))
            value[b.slice] = b.kind.values(b.value(state))
    names, units = layout.names, layout.units  # Python floats and bools first: the same values, fewer conversions
    return estimates_of(names, units, free.tolist(), value[free].tolist(), nominal[free].tolist(),
                        np.asarray(std, float).tolist(), np.asarray(ok, bool).tolist())
