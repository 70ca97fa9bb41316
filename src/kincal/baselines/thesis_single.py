"""Single clamped arm, as in the thesis: Algorithm 3 (CalibSingle_offsets) and several fixed points (Sec. 3.3).

Both identify joint offsets only, with the nominal twists. Flaws kept on purpose:
- unknown fixture: the "measurement" is the mean of the arm's own poses, recomputed every iteration,
  so any offset change that moves all poses together (joint 1 about its axis, joint 7 about the tool
  axis) is invisible and the offsets of joints 1 and 7 go wrong while the poses gather (Table 4.2);
- several fixed points: the plate pose is free, so joint 1 still trades against a rotation of the
  plate (Table 4.4), and the cost (eq. 3.6) adds metres to radians; BFGS with a numerical gradient.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from kincal._validate import check_transform
from kincal.baselines.thesis_common import (
    BaselineResult,
    LoopSettings,
    damped_loop,
    eval_error,
    mean_transform,
    stack,
)
from kincal.errors import DegenerateExperimentError, ShapeError
from kincal.kinematics import ArmModel, chain, joint_array, space_jacobian
from kincal.lie import se3


def _tool_poses(model: ArmModel, q: np.ndarray, offsets: np.ndarray):
    return chain(model.screws, q + offsets, model.base, model.home, model.tool)


def _offset_names(model: ArmModel, arm: str) -> tuple[str, ...]:
    return tuple(f"{arm}.{j}.offset" for j in model.joint_names)


def calib_single_offsets(
    model: ArmModel,
    q,
    T_world_fixture=None,
    *,
    settings: LoopSettings = LoopSettings(),
    arm: str | None = None,
) -> BaselineResult:
    """Algorithm 3: joint offsets of one arm whose tool was clamped at one fixture pose.

    Parameters
    ----------
    model : ArmModel
        Nominal model; its offsets are the initial guess (the thesis starts from zero).
    q : ndarray (N, n)
        Joint readings (rad) at the clamped configurations.
    T_world_fixture : ndarray (4, 4) or None
        Known tool pose at the fixture. None: unknown, replaced in every iteration by the mean
        transformation matrix of the current poses.
    settings : LoopSettings
        max_iter, accept_factor (1.0 or 1.5), initial damping, step tolerance.
    arm : str
        Name used in ``parameter_names`` (default: the model's name).

    Residual of arm sample i: ``y_i = log(T_ref T_i^-1)^vee`` (space error twist), Jacobian eq. 2.53
    (the offsets block of the identification Jacobian, ``Ad(P_{i-1}) xi_i``); update ``o += x`` (eq. 2.56).
    """
    q = joint_array(model, q)
    if q.ndim != 2:
        raise ShapeError(f"q: expected shape (N, {model.dof}), got {q.shape}")
    known = T_world_fixture is not None
    if known:
        T_world_fixture = check_transform(T_world_fixture, "T_world_fixture", tol=1e-6)
        if T_world_fixture.shape != (4, 4):
            raise ShapeError(f"T_world_fixture: expected shape (4, 4), got {T_world_fixture.shape}")
    elif q.shape[0] < 2:
        raise DegenerateExperimentError(f"q: an unknown fixture needs at least 2 configurations, got {q.shape[0]}")
    arm = model.name if arm is None else arm

    def reference(T):
        return T_world_fixture if known else mean_transform(T)

    def linearize(o):
        kin = _tool_poses(model, q, o)
        y = se3.log(reference(kin.tool) @ se3.inverse(kin.tool))
        return [stack(space_jacobian(model, q, kin), y)]

    def evaluate(o):
        T = _tool_poses(model, q, o).tool
        return eval_error(reference(T), T)

    out = damped_loop(np.array(model.offsets), linearize, lambda o, steps: o + steps[0], evaluate, settings)
    offsets = out.params
    return BaselineResult(
        method="thesis.single_offsets",
        models={arm: model.replace(offsets=offsets)},
        offsets={arm: offsets},
        parameter_names=_offset_names(model, arm),
        estimate=offsets.copy(),
        iterations=out.iterations,
        accepted=out.accepted,
        history=out.history,
        damping=out.damping,
        cost={arm: out.cost[0] if out.cost else float("nan")},
        converged=out.stopped_on_step,
        T_world_fixture=reference(_tool_poses(model, q, offsets).tool),
        meta={"fixture": "known" if known else "unknown (mean pose)", "accept_factor": settings.accept_factor},
    )


def calib_several_points(
    model: ArmModel,
    q,
    fixture,
    T_plate_fixture,
    *,
    original: int = 0,
    max_iter: int | None = None,
    gtol: float = 1e-5,
    arm: str | None = None,
) -> BaselineResult:
    """Sec. 3.3, several fixed points: offsets and one free pose, BFGS on eq. 3.6-3.7.

    Every clamped pose is moved to the original fixture with the known relative transform
    ``T_trans_k = T_additional^-1 T_original`` (eq. 3.4-3.5), then
    ``cost = sum_i |log(T_fkin_i T_twist^-1)^vee|^2`` is minimized over the offsets and the twist of
    ``T_twist`` with scipy's BFGS and its numerical gradient, as in the thesis. The initial T_twist is
    the mean transformation matrix of the moved poses (the thesis does not say; this is the natural one).

    Parameters
    ----------
    q : ndarray (N, n)
    fixture : int array (N,)
        Fixture index of each sample, in [0, K).
    T_plate_fixture : ndarray (K, 4, 4)
        Known fixture poses on the plate; only their relative transforms are used.
    original : int
        The fixture the others are moved to.
    max_iter, gtol : BFGS options; the defaults are scipy's (the thesis used scipy's defaults).
    """
    q = joint_array(model, q)
    fixture = np.asarray(fixture)
    T_plate_fixture = check_transform(T_plate_fixture, "T_plate_fixture", tol=1e-6)
    if T_plate_fixture.ndim != 3:
        raise ShapeError(f"T_plate_fixture: expected shape (K, 4, 4), got {T_plate_fixture.shape}")
    K = T_plate_fixture.shape[0]
    if fixture.shape != q.shape[:1] or not np.issubdtype(fixture.dtype, np.integer):
        raise ShapeError(f"fixture: expected {q.shape[0]} integers, got shape {fixture.shape} dtype {fixture.dtype}")
    if fixture.size and (fixture.min() < 0 or fixture.max() >= K):
        raise ShapeError(f"fixture: indices must lie in [0, {K}), found {fixture.min()}..{fixture.max()}")
    if not 0 <= original < K:
        raise ShapeError(f"original: expected a fixture index in [0, {K}), got {original}")
    arm = model.name if arm is None else arm
    n = model.dof
    T_trans = np.linalg.inv(T_plate_fixture) @ T_plate_fixture[original]  # eq. 3.4, (K, 4, 4)
    to_original = T_trans[fixture]

    def moved(o):
        return _tool_poses(model, q, o).tool @ to_original  # eq. 3.5

    def cost(x):
        f = se3.log(moved(x[:n]) @ se3.inverse(se3.exp(x[n:])))  # eq. 3.7
        return float(np.sum(f * f))  # eq. 3.6

    o0 = np.array(model.offsets)
    x0 = np.concatenate([o0, se3.log(mean_transform(moved(o0)))])
    history = [eval_error(se3.exp(x0[n:]), moved(o0))]

    def record(xk):
        history.append(eval_error(se3.exp(xk[n:]), moved(xk[:n])))

    options = {"gtol": gtol} if max_iter is None else {"gtol": gtol, "maxiter": max_iter}
    res = minimize(cost, x0, method="BFGS", callback=record, options=options)
    offsets = res.x[:n].copy()
    names = _offset_names(model, arm) + tuple(f"fixture.{c}" for c in ("v_x", "v_y", "v_z", "w_x", "w_y", "w_z"))
    return BaselineResult(
        method="thesis.several_points",
        models={arm: model.replace(offsets=offsets)},
        offsets={arm: offsets},
        parameter_names=names,
        estimate=res.x.copy(),
        iterations=int(res.nit),
        accepted=int(res.nit),  # BFGS' line search only takes decreasing steps
        history=np.array(history),
        damping=np.empty(0),
        cost={"eq_3_6": float(res.fun)},
        converged=bool(res.success),
        T_world_fixture=se3.exp(res.x[n:]),
        meta={"bfgs_message": str(res.message), "original_fixture": original, "fixtures": K},
    )
