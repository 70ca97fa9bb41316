"""Batch inverse kinematics by adaptive damped least squares (thesis eq. 3.1-3.3).

A *constraint* maps stacked joint readings ``q`` (N, m) to a residual ``e`` (N, k) and its Jacobian
``de/dq`` (N, k, m); IK drives ``e`` to zero. Every sample keeps its own damping ``lambda``: a step that
lowers ``|e|^2`` is taken and ``lambda`` divided by 10, otherwise the step is dropped and ``lambda``
multiplied by 10 (thesis Sec. 3.1). Joint limits are respected: the start is clipped into the limits,
joints sitting at a limit whose step points outward are frozen for that step, and every step is clipped.

Constraints provided:

- ``PoseConstraint``: ``T_world_tool(q) = T_target`` (one arm); residual ``log(T_target^-1 T(q))``.
- ``ClosedChainConstraint``: ``T_world_toolA(qA) T_toolA_toolB = T_world_toolB(qB)`` (two arms solved jointly,
  q = [qA, qB]); residual ``log(T_toolA_toolB^-1 T_A^-1 T_B)``.
- ``PositionConstraint``: the tool origin at a point (a ball held in a socket); residual ``p_tool - p``.

Solutions are only returned when converged (position error below ``tol_m`` and rotation error below
``tol_rad``); the rest are counted in ``IKResult.n_failed``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kincal._validate import as_array, check_transform
from kincal.errors import ShapeError
from kincal.kinematics import ArmModel, body_jacobian, kinematics
from kincal.lie import se3, so3

TOL_M = 1e-12
TOL_RAD = 1e-12
_LAMBDA_MAX = 1e12


@dataclass(frozen=True)
class IKResult:
    """Converged IK solutions only.

    Attributes
    ----------
    q : (M, m) joint readings (for a closed chain ``[qA, qB]``), within the joint limits.
    index : (M,) int, the input row (target / start) each solution belongs to.
    n_failed : int, inputs that did not converge (never returned).
    pos_err, rot_err : (M,) final position (m) and rotation (rad) errors.
    iterations : (M,) int, iterations used.
    split : int or None, number of joints of arm A in a closed-chain result.
    """

    q: np.ndarray
    index: np.ndarray
    n_failed: int
    pos_err: np.ndarray
    rot_err: np.ndarray
    iterations: np.ndarray
    split: int | None = None
    last: np.ndarray | None = None  # (N, m) where every input ended, converged or not
    last_pos_err: np.ndarray | None = None  # (N,) m
    last_rot_err: np.ndarray | None = None  # (N,) rad

    @property
    def n_converged(self) -> int:
        return int(self.index.shape[0])

    def arms(self) -> tuple[np.ndarray, np.ndarray]:
        """(qA, qB) of a closed-chain result."""
        if self.split is None:
            raise ShapeError("IKResult.arms(): not a closed-chain result")
        return self.q[:, : self.split], self.q[:, self.split :]


class _PoseResidual:
    """Residual ``e = log(X)`` of a pose error X with ``X(q + d) = X exp(Jx d)``: ``de/dq = J_r^-1(e) Jx``."""

    def residual(self, q, idx):
        X, Jx = self.pose_error(q, idx)
        e = se3.log(X)
        J = se3.right_jacobian_inv(e) @ Jx
        return e, J, np.linalg.norm(X[:, :3, 3], axis=-1), so3.angle(se3.split(e)[1])


class PoseConstraint(_PoseResidual):
    """``T_world_tool(q) = T_target``; targets (N, 4, 4) or one (4, 4) shared by all samples."""

    def __init__(self, model: ArmModel, T_target: np.ndarray):
        self.model = model
        self.T_target = check_transform(T_target, "T_target", tol=1e-6)
        self.T_target_inv = se3.inverse(self.T_target)
        self.lower, self.upper = model.lower, model.upper
        self.size = model.dof

    def _target_inv(self, idx):
        return self.T_target_inv if self.T_target_inv.ndim == 2 else self.T_target_inv[idx]

    def pose_error(self, q, idx):
        """X = T_target^-1 T(q) (N, 4, 4) and dX with X(q + d) = X exp(Jx d): Jx (N, 6, m)."""
        kin = kinematics(self.model, q)
        return self._target_inv(idx) @ kin.tool, body_jacobian(self.model, q, kin)


class ClosedChainConstraint(_PoseResidual):
    """Two arms whose tools are joined by ``T_toolA_toolB``: q = [qA, qB] (N, nA + nB)."""

    def __init__(self, model_a: ArmModel, model_b: ArmModel, T_toolA_toolB: np.ndarray):
        self.model_a, self.model_b = model_a, model_b
        self.clamp = check_transform(T_toolA_toolB, "T_toolA_toolB", tol=1e-6)
        self.clamp_inv = se3.inverse(self.clamp)
        self.split = model_a.dof
        self.lower = np.concatenate([model_a.lower, model_b.lower])
        self.upper = np.concatenate([model_a.upper, model_b.upper])
        self.size = model_a.dof + model_b.dof

    def pose_error(self, q, idx):
        """X = C^-1 T_A^-1 T_B; perturbing T_A -> T_A exp(d) gives X exp(-Ad(T_B^-1 T_A) d)."""
        qa, qb = q[:, : self.split], q[:, self.split :]
        ka, kb = kinematics(self.model_a, qa), kinematics(self.model_b, qb)
        Ta_inv_Tb = se3.inverse(ka.tool) @ kb.tool
        X = self.clamp_inv @ Ta_inv_Tb
        Ja = -se3.adjoint_inv(Ta_inv_Tb) @ body_jacobian(self.model_a, qa, ka)
        Jb = body_jacobian(self.model_b, qb, kb)
        return X, np.concatenate([Ja, Jb], axis=-1)


class PositionConstraint:
    """Tool origin at ``p_world`` (3,) or (N, 3); orientation free (a ball in a socket)."""

    def __init__(self, model: ArmModel, p_world: np.ndarray):
        self.model = model
        self.p = as_array(p_world, "p_world", (3,))
        self.lower, self.upper = model.lower, model.upper
        self.size = model.dof

    def residual(self, q, idx):
        kin = kinematics(self.model, q)
        p = self.p if self.p.ndim == 1 else self.p[idx]
        e = kin.tool[:, :3, 3] - p
        J = kin.tool[:, :3, :3] @ body_jacobian(self.model, q, kin)[:, :3, :]
        return e, J, np.linalg.norm(e, axis=-1), np.zeros(len(e))


def _step(J, e, lam, q, lower, upper):
    """Damped least-squares step -J^T (J J^T + lam I)^-1 e with joints blocked at a limit frozen."""
    n, k, m = J.shape
    free = np.ones((n, m), dtype=bool)
    at_lower = q <= lower
    at_upper = q >= upper
    for _ in range(3):
        Jf = J * free[:, None, :]
        if k <= m:
            A = Jf @ np.swapaxes(Jf, -1, -2) + lam[:, None, None] * np.eye(k)
            dq = -np.einsum("nkm,nk->nm", Jf, np.linalg.solve(A, e[..., None])[..., 0])
        else:
            A = np.swapaxes(Jf, -1, -2) @ Jf + lam[:, None, None] * np.eye(m)
            dq = -np.linalg.solve(A, np.einsum("nkm,nk->nm", Jf, e)[..., None])[..., 0]
        blocked = free & ((at_lower & (dq < 0)) | (at_upper & (dq > 0)))
        if not blocked.any():
            break
        free &= ~blocked
    return dq * free


def solve(
    constraint,
    q0: np.ndarray,
    *,
    tol_m: float = TOL_M,
    tol_rad: float = TOL_RAD,
    max_iter: int = 200,
    damping: float = 1e-3,
) -> IKResult:
    """Adaptive DLS on any constraint from starts q0 (N, m); see the module docstring."""
    q = np.clip(as_array(q0, "q0", (constraint.size,)).reshape(-1, constraint.size), constraint.lower, constraint.upper)
    N = q.shape[0]
    idx_all = np.arange(N)
    e, J, perr, rerr = constraint.residual(q, idx_all)
    cost = np.sum(e * e, axis=-1)
    lam = np.full(N, float(damping))
    iters = np.zeros(N, dtype=int)
    done = (perr < tol_m) & (rerr < tol_rad)
    alive = ~done
    for _ in range(max_iter):
        act = np.flatnonzero(alive)
        if act.size == 0:
            break
        iters[act] += 1
        qn = np.clip(q[act] + _step(J[act], e[act], lam[act], q[act], constraint.lower, constraint.upper),
                     constraint.lower, constraint.upper)
        en, Jn, pn, rn = constraint.residual(qn, act)
        cn = np.sum(en * en, axis=-1)
        better = cn < cost[act]
        good = act[better]
        q[good], e[good], J[good], cost[good] = qn[better], en[better], Jn[better], cn[better]
        perr[good], rerr[good] = pn[better], rn[better]
        lam[good] = np.maximum(lam[good] / 10, 1e-12)
        lam[act[~better]] *= 10
        done[act] = (perr[act] < tol_m) & (rerr[act] < tol_rad)
        alive = ~done & (lam < _LAMBDA_MAX)
    ok = np.flatnonzero(done)
    return IKResult(
        q[ok], ok, int(N - ok.size), perr[ok], rerr[ok], iters[ok], getattr(constraint, "split", None), q, perr, rerr
    )


def solve_ik(model: ArmModel, T_world_tool: np.ndarray, q0: np.ndarray, **options) -> IKResult:
    """Joint readings q with ``forward_kinematics(model, q) = T_world_tool``.

    Parameters
    ----------
    model : ArmModel
    T_world_tool : (N, 4, 4) or (4, 4) targets (one shared target for all starts if (4, 4)).
    q0 : (N, n) starting readings (clipped into the limits).
    **options : tol_m, tol_rad, max_iter, damping (initial lambda), see ``solve``.
    """
    return solve(PoseConstraint(model, T_world_tool), q0, **options)


def solve_closed_chain(
    model_a: ArmModel, model_b: ArmModel, T_toolA_toolB: np.ndarray, q0_a: np.ndarray, q0_b: np.ndarray, **options
) -> IKResult:
    """Both arms moved jointly until ``T_world_toolA(qA) @ T_toolA_toolB = T_world_toolB(qB)``.

    ``q0_a`` (N, nA), ``q0_b`` (N, nB); the result's ``q`` is ``[qA, qB]``, use ``IKResult.arms()``.
    """
    q0 = np.concatenate([np.asarray(q0_a, float), np.asarray(q0_b, float)], axis=-1)
    return solve(ClosedChainConstraint(model_a, model_b, T_toolA_toolB), q0, **options)


def closure_error(model_a: ArmModel, model_b: ArmModel, T_toolA_toolB, q_a, q_b) -> tuple[np.ndarray, np.ndarray]:
    """Closure of a two-arm chain: (position error m, rotation error rad) of ``T_A C`` vs ``T_B``, each (N,)."""
    X, _ = ClosedChainConstraint(model_a, model_b, T_toolA_toolB).pose_error(
        np.concatenate([np.atleast_2d(q_a), np.atleast_2d(q_b)], axis=-1), None
    )
    return np.linalg.norm(X[:, :3, 3], axis=-1), so3.angle(so3.log(X[:, :3, :3]))
