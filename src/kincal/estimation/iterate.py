"""The outer loop of ``solve``: re-linearize around the current state, analyse the rank, restrict the step to the
identifiable subspace (the gauge), take a Gauss-Newton step or solve the inner problem (``steps.inner_solve``:
geodesic Levenberg-Marquardt, or ``scipy.optimize.least_squares`` with a robust loss), re-centre (conform
twists, re-linearize tangent bases). A plain Gauss-Newton step between the first and the last linearization is
taken with the null space carried from the last rank analysis where that linearization provably has the same rank
(``_carried``, ``steps.carried_step``: the same step to round-off), without an analysis of its own; where that
step is negligible, the result's analysis is carried too (``analysis.carried``) where it provably is the
linearization's own, else the linearization is analysed."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from kincal.analysis import Identifiability, Linearization, identify
from kincal.analysis.carried import CarriedAnalysis, carried_analysis
from kincal.analysis.identifiability import DeferredReport
from kincal.analysis.covariance import right_svd
from kincal.analysis.linalg import norm
from kincal.analysis.symmetries import Structure, scale_visible
from kincal.errors import DegenerateExperimentError
from kincal.estimation import steps
from kincal.estimation.gauge import gauge_basis, priority, rigid_gauges
from kincal.estimation.options import SolverOptions
from kincal.estimation.problem import Problem
from kincal.params import State, conform, recentre, retract

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Iteration:
    """Where the outer loop stopped. ``status``: converged | not converged | degenerate; ``iterations``: outer
    iterations (linearizations, the one that confirmed convergence included); ``evaluations``: residual
    evaluations spent on steps; ``linearization``: at ``state`` when the loop stopped without moving (else None);
    ``whiteners``: the ones held at the end; ``first``: the identifiability report at the start (named when
    first read), with ``start_whiteners`` the whiteners there (the residual statistics at the start, ``before``,
    are computed from them when read); ``analysis``: the identifiability at ``linearization`` (not named; a
    ``CarriedAnalysis`` where it was carried)."""

    state: State
    status: str
    iterations: int
    evaluations: int
    linearization: Linearization | None
    whiteners: tuple | None
    first: DeferredReport | None
    start_whiteners: tuple | None
    order: tuple[int, ...]  # the free coordinates' pivot order (``gauge.priority``)
    # at ``linearization`` (``identify(report=False)``, or carried: ``analysis.carried``), when it is kept
    analysis: Identifiability | CarriedAnalysis | None = None
    held: np.ndarray | None = None  # the rigid model's gauges the solve holds (``gauge.rigid_gauges``, at the start)


def scale_test_needed(problem: Problem) -> bool:
    """The scale test (every length column in the linearization) applies when some length is free."""
    return bool(problem.layout.lengths[problem.free_idx].any())


def iterate(problem: Problem, options: SolverOptions) -> Iteration:
    """Run the outer loop from ``problem.start`` (module docstring)."""
    order = priority(problem, options.gauge)
    every = scale_test_needed(problem)
    state, W, lin, ana, hold, structure = problem.start, None, None, None, None, None
    first, start_whiteners = None, None
    evaluations, status, it, fast = 0, "not converged", 0, True  # Gauss-Newton first while it converges fast
    for it in range(1, options.max_outer + 1):
        # Whiten at the start and once more at the first estimate, then hold: when the model cannot explain
        # the data, re-whitening at every estimate moves the optimum each time and the loop never settles.
        # Without encoder noise the whitening does not depend on the state at all.
        if it <= 2 and problem.joint_noise:
            W = None
        lin = steps.linearize(problem, state, W, every)
        W = lin.W
        carrying = None if it == 1 else _carried(lin, ana, options, fast, hold)
        carried = None
        if carrying is not None and carrying.negligible(lin):  # converged: carry the result's analysis too
            final = _final(problem, options, lin, ana, carrying, structure)
            if final is not None:
                ana, status = final, "converged"
                break
        elif carrying is not None:  # a step between two rank analyses (``_carried``)
            carried = steps.carried_step(lin, ana, options.rank_rtol)
        if carried is not None:
            V, z, r1sq = carried
        else:
            hold = rigid_gauges(problem, lin) if it == 1 else hold
            # the problem's structure, read once: the same at every linearization of this solve (``Structure``)
            structure = structure or Structure.of(lin, problem.layout, problem.experiments, options.rank_rtol)
            ana = identify(lin, problem.layout, problem.experiments, rtol=options.rank_rtol, priority=order,
                           report=False, hold=hold, structure=structure)
            if every and it == 1 and scale_visible(lin, problem.layout, structure):
                every = False  # the data measure lengths: later linearizations skip the scale test's columns
            if first is None:  # named only if a report asks for it (``Result.identifiability_before``)
                first = DeferredReport.of(ana, lin, problem.layout, problem.experiments, order)
                start_whiteners = W
                if first.degenerate:
                    status = "degenerate"
                    break
                _require_redundancy(problem, lin, ana.rank)
            V = gauge_basis(lin.Rf, ana, options.gauge, order)
            z, r1sq = steps.gauss_newton(lin, V, ana.factor if V is ana.range_space else None)
            if it > 1 and steps.negligible(lin, V, z, r1sq):
                status = "converged"  # the re-linearized problem asks for no step
                break
        state, done, fast, spent = _step(problem, options, lin, V, z, r1sq, fast, it)
        evaluations += spent
        lin = None  # the state moved
        if done:
            status = "converged"
            break
    return Iteration(state, status, it, evaluations, lin, W, first, start_whiteners, tuple(order),
                     None if lin is None else ana, hold)


def _carried(lin: Linearization, ana: Identifiability, options: SolverOptions, fast: bool, hold):
    """``ana`` carried to ``lin`` (``steps.carrying``; its step, ``steps.carried_step``, is the Gauss-Newton step
    from a rank analysis of ``lin`` to round-off), or None where the step needs a rank analysis of its own: the
    first linearization has its own (the start's report), so does any step that is not a plain Gauss-Newton step
    in the min-change gauge of an analysis from its own SVD with nothing weak, held or pinned, or a linearization
    whose rank may differ. The loop only calls it after a step, so the analysis is that of an earlier state. A
    step it finds negligible ends the loop; the result's analysis is then carried (``analysis.carried``) or, where
    that is not provably ``lin``'s own, made afresh."""
    if not (fast and options.loss == "linear" and isinstance(options.gauge, str) and hold is None
            and ana.factor is not None and not ana.weak):
        return None
    return steps.carrying(lin, ana, options.rank_rtol)


def _final(problem: Problem, options: SolverOptions, lin: Linearization, ana: Identifiability,
           carrying: steps.Carrying, structure: Structure | None) -> CarriedAnalysis | None:
    """The analysis of the last linearization ``lin`` carried from ``ana`` (``analysis.carried``), or None."""
    null, V = carrying.subspaces(lin)
    return carried_analysis(lin, problem.layout, problem.experiments, options.rank_rtol, ana.names, null, V,
                            carrying.VP, carrying.inverse, structure)


def _step(problem: Problem, options: SolverOptions, lin: Linearization, V: np.ndarray, z: np.ndarray,
          r1sq: float, fast: bool, it: int) -> tuple[State, bool, bool, int]:
    """One step from ``lin`` in the subspace V: (new state, whether it was negligible, whether Gauss-Newton is
    still fast, residual evaluations spent).

    The Gauss-Newton step ``z`` first (it costs one residual evaluation); ``steps.inner_solve`` (geodesic
    Levenberg-Marquardt, or TRF with a robust loss) solves the inner problem when the full step does not reduce
    the cost as the linear model predicts (far from the optimum, strongly nonlinear), when Gauss-Newton has
    stopped converging fast, or when a robust loss is asked for. An inner solve that stopped on its budget is
    never the last step: the loop relinearizes and goes on (or ends "not converged")."""
    accepted, evaluations, moved, finished = False, 0, None, True
    if options.loss == "linear" and fast:
        # retracted once, kept if accepted (the screws only: the tangent bases are re-centred below), its twists
        # conformed as ``recentre`` conforms them, so the next linearization has its screws and reuses its
        # kinematics (``experiments.remembered_kinematics``)
        moved = conform(retract(lin.state, problem.layout, problem.full_delta(V @ z), tangents=False))
        r_new = problem.evaluate(moved, np.zeros(V.shape[0]), lin.W, jac=False)[0]
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
        x, cost, nfev, finished = steps.inner_solve(problem, lin.state, lin, V, options.loss, options.f_scale)
        evaluations += nfev
    delta = V @ x
    step = norm(lin.Rf @ delta)
    state = recentre(moved, conformed=True) if accepted else \
        recentre(retract(lin.state, problem.layout, problem.full_delta(delta)))
    if options.progress:
        options.progress(it, 2 * cost)
    biggest = np.abs(delta).max(initial=0.0)  # the method: without np.max's dispatch
    log.debug("outer %d (%s): cost %.6g, whitened step %.3g, max |delta| %.3g", it,
              "Gauss-Newton" if accepted else "inner solve", 2 * cost, step, biggest)
    # stop when the step is negligible against the residual (or, with noise, well below one sigma)
    done = finished and (steps.converged(step, np.sqrt(lin.cost2), cost, len(lin.r) - V.shape[1]) or biggest < 1e-13)
    return state, done, fast, evaluations


# Singular values below this fraction of the largest are exact zeros (structure, not weak data).
EXACT_RTOL = 1e-10


def _require_redundancy(problem: Problem, lin: Linearization, rank: int) -> None:
    """More equations than identifiable parameters: with none left over, nothing checks the fit (fewer than twice
    as many is allowed, with the consequences ``finalize`` states: ``low_redundancy``).

    With fewer equations than free coordinates, the number of equations may itself be what limits the rank:
    the data then cannot tell which parameters the robot's structure leaves identifiable. They can only where
    the Jacobian's exact rank (structure: every singular value above ``EXACT_RTOL``, weak ones included) stays
    below the number of equations; otherwise the experiment is refused as too small."""
    m, p = len(lin.r), len(problem.free_idx)
    exact = rank
    if m < p:
        S = right_svd(lin.J)[0]
        exact = int(np.sum(S > EXACT_RTOL * S[0])) if len(S) else 0
    if m <= max(rank, exact):
        per = ", ".join(f"'{e.name}' ({e.kind_name}): {e.size} configurations" for e in problem.experiments)
        need = ", ".join(f"'{e.name}'" for e in problem.experiments)
        raise DegenerateExperimentError(
            f"{m} equations for {p} unknowns ({max(rank, exact)} found identifiable from these equations): too few "
            f"configurations to calibrate and check the result (more equations than identifiable parameters "
            f"needed, twice as many to check the model; {per}); measure more configurations in {need}"
        )
