"""One linearization of the calibration problem and the steps taken from it.

A linearization evaluates every experiment once and reduces the tall whitened Jacobian to the triangular
factor of ``[J_free | J_fixed | r_len | r]`` (``kincal.analysis.Linearization``); the Gauss-Newton step, its
predicted cost and the convergence test read that factor only. ``inner_solve`` is the slow path, on the
identifiable subspace with the analytic Jacobian: Levenberg-Marquardt with geodesic acceleration
(``estimation.levenberg``) for plain least squares, ``scipy.optimize.least_squares`` with a robust loss.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np

from kincal.analysis import Identifiability, Linearization
from kincal.analysis.factor import Factor
from kincal.analysis.linalg import lstsq, norm, null_and_range
from kincal.errors import DegenerateExperimentError
from kincal.estimation import blocks, levenberg
from kincal.estimation.problem import Problem, triangular_factor
from kincal.params import State, scale_direction


def linearize(problem: Problem, state: State, W, every: bool) -> Linearization:
    """Evaluate at ``state`` (whitening there when ``W`` is None) and reduce to the triangular factor.
    ``every``: also the fixed columns the scale test needs, those that scale with the robot (lengths,
    compliances), and the residual's length part."""
    p = len(problem.free_idx)
    fixed, scale = np.zeros(0, int), None
    if every:
        layout = problem.layout
        scale = scale_direction(state, layout)  # kept for the scale test (``symmetries.scale_null``)
        moves = layout.lengths | (scale != 0)
        fixed = np.flatnonzero(~layout.free & moves)
    cols = np.concatenate([problem.free_idx, fixed]) if every else problem.free_idx
    if problem.blocked:
        return _linearize_blocks(problem, state, W, cols, every)
    r, J, W, raw = problem.linearize(state, W, cols)
    if not np.isfinite(r).all() or not np.isfinite(J).all():
        raise DegenerateExperimentError(NOT_FINITE)
    if every:
        R = triangular_factor([J, problem.length_part(raw, W), r], panels=True)
        J = J[:, :p]
    else:
        R = triangular_factor([J, r], panels=True)
    return Linearization(state, r, J, R, tuple(W), tuple(raw), problem.free_idx, fixed if every else None, scale)


NOT_FINITE = "residuals or Jacobian are not finite at the starting values"


def _linearize_blocks(problem: Problem, state: State, W, cols: np.ndarray, every: bool) -> Linearization:
    """``linearize`` of a large problem block by block (``estimation.blocks``): the same factor, up to row signs."""
    r, R, W, raw = blocks.linearize(problem, state, W, cols, every)
    if not np.all(np.isfinite(r)) or not np.all(np.isfinite(R)):
        raise DegenerateExperimentError(NOT_FINITE)
    J = blocks.BlockJacobian(problem, state, W, problem.free_idx, sum(x.size for x in raw))
    return Linearization(state, r, J, R, tuple(W), tuple(raw), problem.free_idx,
                         cols[len(problem.free_idx):] if every else None)


# The inner solve stops where the Gauss-Newton step left is this fraction of what ``converged`` calls negligible.
# Inside a curved valley a hundredth of a standard deviation along the valley still moves the coordinates that
# bend with it by more than their (linearized) standard deviations say; near the minimum each further step of
# Levenberg-Marquardt gains digits for a few evaluations, so the inner solve polishes to 1e-4 sigma.
INNER_TOLERANCE = 1e-2


def inner_solve(problem: Problem, state: State, lin: Linearization, V: np.ndarray, loss: str, f_scale: float,
                jac: str = "analytic"):
    """Minimize over coordinates ``z`` of the subspace V around ``state``, from the linearization at hand:
    ``estimation.levenberg`` (geodesic Levenberg-Marquardt) for plain least squares, scipy's ``least_squares``
    (TRF) with a robust loss or fewer residuals than coordinates. ``jac="2-point"``: forward differences
    instead of the analytic Jacobian (bench/bench_calibrate.py). Returns ``(z, cost, evaluations, converged)``,
    cost = 0.5 |r|^2; ``converged`` False when the solve stopped on its evaluation budget or stalled."""
    budget = 200 * (V.shape[1] + 1)
    if loss == "linear" and V.shape[1] <= len(lin.r):
        return _levenberg(problem, state, lin, V, jac, budget)
    return _least_squares(problem, state, lin, V, loss, f_scale, jac, budget)


def _levenberg(problem: Problem, state: State, lin: Linearization, V: np.ndarray, jac: str, budget: int):
    """``inner_solve`` for plain least squares."""
    dof, r0 = len(lin.r) - V.shape[1], np.sqrt(lin.cost2)

    def evaluate(z, need_jac):
        if jac == "analytic" or not need_jac:
            return _evaluate_in(problem, state, V, z, lin.W, need_jac)
        return _forward_differences(lambda x: _evaluate_in(problem, state, V, x, lin.W, False)[0], z)

    def done(step, cost2):
        return converged(step / INNER_TOLERANCE, r0, 0.5 * cost2, dof)

    out = levenberg.minimize(evaluate, lin.r, lin.J @ V, done, budget)
    return out.z, 0.5 * float(out.r @ out.r), out.evaluations, out.status == "converged"


def _forward_differences(f, z: np.ndarray):
    """``(f(z), df/dz)`` by forward differences (scipy's "2-point" step)."""
    r = f(z)
    h = np.sqrt(np.finfo(float).eps) * np.maximum(1.0, np.abs(z))
    return r, np.column_stack([(f(z + h[j] * e) - r) / h[j] for j, e in enumerate(np.eye(len(z)))])


def _least_squares(problem: Problem, state: State, lin: Linearization, V: np.ndarray, loss: str, f_scale: float,
                   jac: str, budget: int):
    """``inner_solve`` by ``scipy.optimize.least_squares`` (TRF: a robust loss, or more coordinates than
    residuals)."""
    from scipy.optimize import least_squares  # a fallback; importing scipy.optimize costs more than kincal

    cache = {np.zeros(V.shape[1]).tobytes(): (lin.r, lin.J @ V)}

    def both(z, need_jac):
        key = z.tobytes()
        if key not in cache or (need_jac and cache[key][1] is None):
            cache.clear()
            cache[key] = _evaluate_in(problem, state, V, z, lin.W, need_jac)
        return cache[key]

    sol = least_squares(lambda z: both(z, False)[0], np.zeros(V.shape[1]),
                        jac=(lambda z: both(z, True)[1]) if jac == "analytic" else jac, method="trf", loss=loss,
                        f_scale=f_scale, x_scale=1.0, ftol=1e-10, xtol=1e-10, gtol=1e-10, max_nfev=budget)
    return sol.x, float(sol.cost), sol.nfev, sol.status > 0


def _evaluate_in(problem: Problem, state: State, V: np.ndarray, z: np.ndarray, W, jac: bool):
    """The whitened residual at ``retract(state, V z)`` and, with ``jac``, its Jacobian in ``z`` (``J V``): a
    large problem by blocks, so only ``J V`` is ever held whole."""
    if problem.blocked:
        return blocks.evaluate(problem, state, V @ z, W, V if jac else None)
    r, J = problem.evaluate(state, V @ z, W, jac=jac)
    return r, None if J is None else J @ V


def converged(step: float, r0_norm: float, cost: float, dof: int) -> bool:
    """A step is negligible against the residual, or (with noise) well below one sigma of scatter: the
    whitened step |J delta| is the step's length in standard deviations of the estimate, so 1e-2 moves no
    estimate by more than a hundredth of its standard deviation."""
    return bool(step < step_limit(r0_norm, cost, dof))


def step_limit(r0_norm: float, cost: float, dof: int) -> float:
    """The whitened step length below which ``converged`` calls a step negligible."""
    scatter = math.sqrt(2 * cost / max(dof, 1))  # a float: numpy's sqrt of a scalar, without its call overhead
    return max(1e-6 * (1.0 + r0_norm), 1e-2 * scatter)


def gauss_newton(lin: Linearization, V: np.ndarray, factor: Factor | None = None) -> tuple[np.ndarray, float]:
    """Gauss-Newton step in the subspace V and the predicted |r|^2 after it, from the triangular factor alone:
    with ``J = Q R``, ``z = argmin |R V z + Q^T r|`` and ``|r + J V z|^2 = |r|^2 - |Q^T r|^2 + |R V z + Q^T r|^2``.
    ``factor``: the rank analysis' own SVD of ``lin.Rf`` when V is its identifiable subspace (``analysis.factor``):
    the step from it, without another least-squares solve."""
    RV = lin.Rf @ V
    z = V.T @ factor.step(-lin.qtr) if factor is not None else lstsq(RV, -lin.qtr)
    return z, _predicted(lin, RV @ z)


def _predicted(lin: Linearization, image: np.ndarray) -> float:
    """|r|^2 after a step whose image under ``lin.Rf`` is ``image``, by ``lin``'s linear model (``gauss_newton``)."""
    qtr = lin.qtr
    e = qtr + image
    return max(lin.cost2 - float(qtr @ qtr) + float(e @ e), 0.0)


# A step is carried from an earlier linearization's rank analysis (``carried_step``) while the factor on the
# carried subspace, preconditioned to orthonormal columns at the analysed linearization, keeps every singular value
# above this (checked by the bound 1 / |R^-1|_F on its triangular factor R): each identifiable direction of the
# analysis has lost at most a factor 1e3 of its singular value, which the analysis found more than ``factor.GAP``
# (1e10) above round-off, so none can have become unidentifiable.
CARRY_MIN = 1e-3


@dataclass(frozen=True, eq=False)
class Carrying:
    """An earlier linearization's rank analysis carried to a linearization ``lin`` (``carrying``): ``VP`` (p, r) the
    analysis' identifiable basis preconditioned (``Factor.inverse_gram_root``), ``Q``, ``R`` the QR of
    ``[Rf VP, qtr]`` (``R``'s first r columns: ``Rf VP``'s factor, its column r: ``Q^T qtr``), ``inverse`` =
    ``R[:r, :r]^-1``, ``null0`` the analysis' null space. The step's image ``-Q Q^T qtr`` (its length, its predicted
    cost: ``negligible``) needs no step; ``subspaces`` and ``step`` give the rest."""

    VP: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    inverse: np.ndarray
    null0: np.ndarray

    def negligible(self, lin: Linearization) -> bool:
        """``negligible(lin, *step)`` without the step: its image under ``Rf`` (``Rf V z``, the null part of the
        least-squares solution in span(VP) removed, which ``Rf`` maps to round-off) is ``-Q Q^T qtr``."""
        r = self.VP.shape[1]
        image = self.Q @ -self.R[:r, r]
        return _negligible_image(lin, image, _predicted(lin, image), r)

    def subspaces(self, lin: Linearization) -> tuple[np.ndarray, np.ndarray]:
        """(null space, its complement) of ``lin`` (natural units, orthonormal): ``N0 + VP X`` with ``Rf VP X =
        -Rf N0``."""
        N0 = self.null0
        return null_and_range(N0 - self.VP @ (self.inverse @ (self.Q.T @ (lin.Rf @ N0))), scratch=True)

    def step(self, lin: Linearization):
        """``(V, z, r1sq)``: ``gauss_newton``'s step at ``lin`` in the min-change gauge, or None (a singular factor)."""
        from scipy.linalg.lapack import dtrtrs  # here: importing scipy.linalg costs more than importing kincal

        r = self.VP.shape[1]
        w, info = dtrtrs(self.R[:r, :r], self.R[:r, r])
        if info != 0:
            return None
        V = self.subspaces(lin)[1]
        z = V.T @ (self.VP @ -w)
        return V, z, _predicted(lin, lin.Rf @ (V @ z))


def carrying(lin: Linearization, ana: Identifiability, rtol: float) -> Carrying | None:
    """``ana`` (a rank analysis at ``rtol`` of an earlier linearization, one whose null space is its SVD's own,
    ``ana.factor``) carried to ``lin``: None where ``lin``'s rank differs from ``ana``'s or its factor on ``ana``'s
    identifiable subspace is too weak (``CARRY_MIN``). Remembered for ``lin`` (``carried_step`` asks again).

    With ``M^-1`` the factor's ``inverse_gram_root``, ``C = Rf V0 M^-1`` (V0 = ``ana.range_space``) has orthonormal
    columns at the analysed linearization; its QR ``C = Q R`` carries the rest. Where ``C`` keeps its rank and the
    column-scaled ``Rf`` has no part outside span(Q) above ``rtol`` of the analysed largest singular value (a
    bound on its next singular value: no direction has become identifiable, as a compliance lifts the gauges it
    couples at its first move from 0), ``lin`` has ``ana``'s rank and V0 is a complement of its null space. That
    null space is then ``N0 + V0 X`` with ``Rf V0 X = -Rf N0`` (N0 = ``ana.null_space``), one solve with ``C``'s
    factor."""
    try:
        hit = _CARRYING.get(lin)
    except TypeError:  # not weakly referable (a stand-in for a linearization): not remembered
        return _carrying(lin, ana, rtol)
    if hit is not None and hit[0]() is ana and hit[1] == rtol:
        return hit[2]
    out = _carrying(lin, ana, rtol)
    _CARRYING[lin] = (weakref.ref(ana), rtol, out)
    return out


# ``carrying``'s answer per linearization, forgotten with it (its value holds neither the linearization nor the
# analysis, so neither is kept alive by it); the loop asks once to decide and ``carried_step`` again to step.
_CARRYING: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _carrying(lin: Linearization, ana: Identifiability, rtol: float) -> Carrying | None:
    from scipy.linalg.lapack import dtrtri  # here: importing scipy.linalg costs more than importing kincal

    V0, factor = ana.range_space, ana.factor
    VP = V0 @ factor.inverse_gram_root(V0)
    r = VP.shape[1]
    C = lin.Rf @ VP
    R = triangular_factor([C, lin.qtr])  # (r + 1) rows, or r where r = p: every row of R[:r, :r]
    inverse, info = dtrtri(R[:r, :r])  # the smallest singular value of C is at least 1 / |R^-1|_F
    if info != 0 or not norm(inverse) <= 1.0 / CARRY_MIN:
        return None
    Q, Rs = C @ inverse, lin.Rf / factor.c
    if not norm(Rs - Q @ (Q.T @ Rs)) <= rtol * factor.S[0]:
        return None
    return Carrying(VP, Q, R, inverse, ana.null_space)


def carried_step(lin: Linearization, ana: Identifiability, rtol: float):
    """``gauss_newton`` in the min-change gauge at ``lin`` from an earlier linearization's rank analysis ``ana`` at
    ``rtol`` (``carrying``), without a rank analysis of ``lin``: ``(V, z, r1sq)`` with V an orthonormal basis of
    the complement of ``lin``'s null space, as ``identify`` would give it; None where ``ana`` cannot be carried to
    ``lin``. The least-squares step in V0 projected on V is ``gauss_newton``'s step from a rank analysis of
    ``lin``, up to round-off."""
    carried = carrying(lin, ana, rtol)
    return None if carried is None else carried.step(lin)


def negligible(lin: Linearization, V: np.ndarray, z: np.ndarray, r1sq: float) -> bool:
    """Convergence test at a new linearization point: the Gauss-Newton step asked for there is negligible."""
    return _negligible_image(lin, lin.Rf @ (V @ z), r1sq, V.shape[1])


def _negligible_image(lin: Linearization, image: np.ndarray, r1sq: float, rank: int) -> bool:
    """``converged`` for a step of whitened image ``image`` (under ``lin.Rf``) in a subspace of dimension ``rank``
    that leaves ``r1sq`` (``negligible``, ``Carrying.negligible``)."""
    return converged(norm(image), math.sqrt(lin.cost2), 0.5 * r1sq, len(lin.r) - rank)
