"""Levenberg-Marquardt with geodesic acceleration (Transtrum and Sethna 2012, "Improvements to the
Levenberg-Marquardt algorithm for nonlinear least-squares minimization"): the inner solve of
``estimation.steps`` for weak, curved valleys.

Plain LM walks along a valley only as far as its linear model holds. Where the valley curves (a joint offset
traded against the next joints' axes and the home pose, told apart only by a weight's sag; a tracker frame
traded against a reflector's position) its accepted steps shrink to the valley's width and it crawls for
thousands of evaluations. A refused step ``v`` is bent with the valley by the second-order correction ``a``
(the residual's second directional derivative along ``v``, one evaluation by finite differences, pulled back
through the same damped solve): ``v + a / 2``, unless the correction is not small against the step
(``2 |a| > ALPHA |v|``: refused without evaluating it). Steps are tried straight (one evaluation) until a bent
step has been accepted, bent from then on: straight steps keep a far start on plain LM's path (a camera pose a
radian away: bending every step took it to another minimum), and once in a valley, trying each step straight
first would cost an evaluation per step.

Each point's Jacobian is decomposed once (SVD): the damped step for any damping is then a diagonal formula,
exact at any conditioning (the valleys' singular values are 1e-9 of the largest). The damping is isotropic in
the solve's coordinates, as scipy's LM with ``x_scale=1`` was. It starts nearly at Gauss-Newton (``TAU``: an
over-damped start costs a step per factor 3 on the way down, dozens of evaluations on an easy problem) and
moves by Nielsen's rule, up by 2, 4, 8 ... on refusals and down by at most 3 on acceptance ("delayed
gratification", which suits long valleys). The solve stops when ``done`` accepts the undamped Gauss-Newton step
left at the current point (``steps``: a negligible fraction of a standard deviation), when the evaluation budget
is spent, or when not even a step damped to a gradient step ``STALL`` times shorter reduces the cost
(round-off)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from kincal.analysis.linalg import svd

ALPHA = 0.75  # largest 2 |a| / |v| accepted (Transtrum and Sethna)
H = 0.1  # finite-difference step along v for the second directional derivative, as a fraction of v
UP, DOWN = 2.0, 3.0  # damping up on a refused step (the factor doubling), down by at most DOWN on acceptance
TAU = 1e-15  # the first damping, relative to the largest squared singular value
ACCEPT = 1e-4  # smallest ratio of actual to predicted reduction accepted
SINGULAR_RTOL = 1e-13  # singular values below this fraction of the largest are exact zeros (round-off)
STALL = 1e10  # damping beyond this times the largest squared singular value: no step helps, the solve has stalled


@dataclass(frozen=True)
class Outcome:
    """``z``: the end point; ``r``: the residual there; ``evaluations``: model evaluations spent (a residual,
    or a residual with its Jacobian); ``status``: converged | budget (evaluations spent) | stalled (no step
    reduces the cost); ``steps``: accepted steps."""

    z: np.ndarray
    r: np.ndarray
    evaluations: int
    status: str
    steps: int


class _Point:
    """The residual, the Jacobian and its SVD at one point."""

    def __init__(self, z: np.ndarray, r: np.ndarray, J: np.ndarray):
        self.z, self.r, self.J = z, r, J
        U, S, Wt = svd(J, full_matrices=False)
        keep = S > SINGULAR_RTOL * S[0] if len(S) and S[0] > 0 else np.zeros(len(S), bool)
        self.U, self.S, self.Wt = U[:, keep], S[keep], Wt[keep]
        self.utr = self.U.T @ r  # the part of the residual the parameters can explain
        self.cost2 = float(r @ r)

    def damped(self, ub: np.ndarray, lam: float) -> np.ndarray:
        """``argmin |J x + b|^2 + lam |x|^2`` given ``U^T b``."""
        return -self.Wt.T @ (self.S / (self.S ** 2 + lam) * ub)

    def gauss_newton(self) -> float:
        """The whitened length |J x| of the undamped step: the square root of the cost reduction it predicts."""
        return float(np.linalg.norm(self.utr))


def minimize(evaluate: Callable, r0: np.ndarray, J0: np.ndarray, done: Callable[[float, float], bool],
             max_evaluations: int) -> Outcome:
    """Minimize ``|r(z)|^2`` from ``z = 0``, where the residual ``r0`` and Jacobian ``J0`` are known.
    ``evaluate(z, jac)`` gives ``(r, J)`` (``J`` None without ``jac``); ``done(step, cost2)``: whether an
    undamped step of whitened length ``step`` to a squared residual ``cost2`` is negligible."""
    pt = _Point(np.zeros(J0.shape[1]), r0, J0)
    top = pt.S[0] ** 2 if len(pt.S) else 1.0
    lam = TAU * top
    nu, evaluations, accepted, bent = UP, 0, 0, False
    while True:
        step = pt.gauss_newton()
        if done(step, pt.cost2 - step ** 2):
            return Outcome(pt.z, pt.r, evaluations, "converged", accepted)
        if evaluations + 3 > max_evaluations:
            return Outcome(pt.z, pt.r, evaluations, "budget", accepted)
        if lam > STALL * top:
            return Outcome(pt.z, pt.r, evaluations, "stalled", accepted)
        z, rho, spent, bent = _trial(evaluate, pt, lam, bent)
        evaluations += spent
        if z is None:
            lam, nu = lam * nu, nu * UP
            continue
        r, J = evaluate(z, True)
        evaluations += 1
        pt = _Point(z, r, J)
        accepted += 1
        lam, nu = lam * max(1.0 / DOWN, 1.0 - (2.0 * rho - 1.0) ** 3), UP


def _trial(evaluate: Callable, pt: _Point, lam: float, bent: bool):
    """One damped step from ``pt``: straight (unless ``bent``), then bent by its geodesic acceleration when
    refused. ``(z, rho, evaluations, bent)``: ``z`` None when refused, else the new point and the ratio of actual
    to predicted cost reduction; ``bent``: whether steps are bent from now on."""
    v = pt.damped(pt.utr, lam)
    if not np.any(v):
        return None, 0.0, 0, bent
    Jv = pt.J @ v
    linear = pt.r + Jv
    n = 0
    if not bent:
        z, rho = _accept(pt, pt.z + v, evaluate(pt.z + v, False)[0], pt.cost2 - float(linear @ linear))
        if z is not None:
            return z, rho, 1, False
        n = 1
    r_h = evaluate(pt.z + H * v, False)[0]
    rvv = (2.0 / H) * ((r_h - pt.r) / H - Jv)  # the second directional derivative of r along v
    if not np.all(np.isfinite(rvv)):
        return None, 0.0, n + 1, bent
    a = pt.damped(pt.U.T @ rvv, lam)
    if 2.0 * np.linalg.norm(a) > ALPHA * np.linalg.norm(v):
        return None, 0.0, n + 1, bent
    step = v + 0.5 * a
    model = linear + 0.5 * (pt.J @ a + rvv)  # the residual after the step, to second order
    z, rho = _accept(pt, pt.z + step, evaluate(pt.z + step, False)[0], pt.cost2 - float(model @ model))
    return z, rho, n + 2, bent or z is not None


def _accept(pt: _Point, z: np.ndarray, r_new: np.ndarray, predicted: float):
    """``(z, rho)`` when the cost at ``z`` fell by at least ``ACCEPT`` times the ``predicted`` reduction, else
    ``(None, 0)``."""
    actual = pt.cost2 - float(r_new @ r_new)
    if not (predicted > 0 and np.isfinite(actual) and actual > ACCEPT * predicted):
        return None, 0.0
    return z, actual / predicted
