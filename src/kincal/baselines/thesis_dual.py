"""Two arms clamped tool to tool, as in the thesis: Algorithm 2 (CalibDual_offsets), Algorithm 1
(CalibDual_kinematic) and the clamp estimate of eq. 3.8.

Convention: ``T_world_toolB = T_world_toolA @ T_toolA_toolB`` (the thesis' ``T_l T_cd = T_r`` with A = left).
Each arm uses the other, uncalibrated, arm as its measurement:
``y_A = log(T_B T_AB^-1 T_A^-1)^vee`` and ``y_B = log(T_A T_AB T_B^-1)^vee``; each arm gets its own damped
least-squares step, of which ``share`` is applied. As the pseudocode says, Algorithm 1 applies 50 % ("the
error is divided equally between the two arms", Sec. 2.10) and Algorithm 2 the full step ("Update the
joint values with the joint value error"), so both arms correct the same error and overshoot; this is what
makes the thesis reject most iterations with the strict test (Table 4.5, 10(2)) and accept them all with
the 1.5 factor (Table 4.7, 10(10)). With one arm known (Table 4.8) the other arm gets the full step.
Flaws kept on purpose: the measurement is itself wrong, the clamp estimate of eq. 3.8 is an
elementwise mean (not a rotation) computed with the uncalibrated model, and the acceptance test is the
mean translation error of Algorithm 4.
"""

from __future__ import annotations

import numpy as np

from kincal.baselines.identification import identification_jacobian
from kincal.baselines.thesis_common import BaselineResult, LoopSettings, damped_loop, eval_error, stack
from kincal.errors import DegenerateExperimentError, ModelError, ShapeError
from kincal.kinematics import (
    ArmModel,
    conform_twists,
    forward_kinematics,
    joint_array,
    kinematics,
    space_jacobian,
)
from kincal.lie import se3


def estimate_clamp(model_a: ArmModel, model_b: ArmModel, q_a, q_b) -> np.ndarray:
    """Eq. 3.8: ``T_cd`` as the elementwise mean over samples of ``T_A^-1 T_B`` (not re-orthogonalized)."""
    q_a, q_b = _readings(model_a, model_b, q_a, q_b)
    T_a = forward_kinematics(model_a, q_a)
    T_b = forward_kinematics(model_b, q_b)
    return np.mean(se3.inverse(T_a) @ T_b, axis=0)


def _readings(model_a, model_b, q_a, q_b):
    q_a = joint_array(model_a, q_a, "q_a")
    q_b = joint_array(model_b, q_b, "q_b")
    if q_a.ndim != 2 or q_b.ndim != 2 or q_a.shape[0] != q_b.shape[0]:
        raise ShapeError(f"q_a, q_b: expected (N, n) arrays with equal N, got {q_a.shape} and {q_b.shape}")
    if q_a.shape[0] < 2:
        raise DegenerateExperimentError(f"q_a: a dual-arm experiment needs at least 2 samples, got {q_a.shape[0]}")
    return q_a, q_b


def _clamp(model_a, model_b, q_a, q_b, T_toolA_toolB):
    if T_toolA_toolB is None:
        return estimate_clamp(model_a, model_b, q_a, q_b), "estimated (eq. 3.8)"
    # Not checked for orthonormality: eq. 3.8's elementwise mean is a legitimate input here.
    T = np.asarray(T_toolA_toolB, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)) or not np.allclose(T[3], [0, 0, 0, 1]):
        raise ShapeError(
            f"T_toolA_toolB: expected a finite (4, 4) transform with last row (0, 0, 0, 1), got {T.tolist()}"
        )
    return T, "given"


def _arm_names(model_a, model_b, arms):
    arms = (model_a.name, model_b.name) if arms is None else tuple(arms)
    if len(arms) != 2 or arms[0] == arms[1]:
        raise ModelError(f"arms: expected two distinct arm names, got {arms} (pass arms=('left', 'right'))")
    return arms


def _updated(arms, known):
    if known is None:
        return (0, 1)
    if known not in arms:
        raise ModelError(f"known: expected one of {arms} or None, got {known!r}")
    return (1,) if known == arms[0] else (0,)


def pose_errors(T_a, T_b, T_ab, T_ab_inv):
    """Per-arm error twists (N, 6): each arm measured by the other through the clamp."""
    return (
        se3.log(T_b @ T_ab_inv @ se3.inverse(T_a)),
        se3.log(T_a @ T_ab @ se3.inverse(T_b)),
    )


def _dual(method, models, q, T_ab, clamp_source, arms, known, share, settings, jacobian, apply, names_of, values_of):
    """The loop of Algorithms 1 and 2; ``jacobian(model, q, kin)`` (N, 6, p), ``apply(model, x)`` a new model."""
    moving = _updated(arms, known)
    T_ab_inv = np.linalg.inv(T_ab)  # eq. 3.8's estimate is not a rigid transform

    def linearize(ms):
        kins = [kinematics(m, qq) for m, qq in zip(ms, q)]
        ys = pose_errors(kins[0].tool, kins[1].tool, T_ab, T_ab_inv)
        return [stack(jacobian(ms[k], q[k], kins[k]), ys[k]) for k in moving]

    def update(ms, steps):
        ms = list(ms)
        for k, x in zip(moving, steps):
            ms[k] = apply(ms[k], share * x)
        return tuple(ms)

    def evaluate(ms):
        return eval_error(forward_kinematics(ms[0], q[0]) @ T_ab, forward_kinematics(ms[1], q[1]))

    out = damped_loop(tuple(models), linearize, update, evaluate, settings)
    final = out.params
    names = tuple(n for k in moving for n in names_of(final[k], arms[k]))
    estimate = np.concatenate([values_of(final[k]) for k in moving])
    cost = {arms[k]: (out.cost[i] if out.cost else float("nan")) for i, k in enumerate(moving)}
    return BaselineResult(
        method=method,
        models=dict(zip(arms, final)),
        offsets={a: np.array(m.offsets) for a, m in zip(arms, final)},
        parameter_names=names,
        estimate=estimate,
        iterations=out.iterations,
        accepted=out.accepted,
        history=out.history,
        damping=out.damping,
        cost=cost,
        converged=out.stopped_on_step,
        T_toolA_toolB=T_ab,
        meta={"clamp": clamp_source, "known_arm": known, "share": share, "accept_factor": settings.accept_factor},
    )


def calib_dual_offsets(
    model_a: ArmModel,
    model_b: ArmModel,
    q_a,
    q_b,
    T_toolA_toolB=None,
    *,
    known: str | None = None,
    share: float | None = None,
    settings: LoopSettings = LoopSettings(),
    arms: tuple[str, str] | None = None,
) -> BaselineResult:
    """Algorithm 2: joint offsets of both arms from a clamped dual-arm experiment.

    Parameters
    ----------
    model_a, model_b : ArmModel
        Nominal models (their offsets are the initial guess).
    q_a, q_b : ndarray (N, n)
        Joint readings of both arms at the same instants.
    T_toolA_toolB : ndarray (4, 4) or None
        Clamp transform; None estimates it with eq. 3.8 from the nominal models.
    known : str or None
        Name of an arm taken as calibrated (not updated; the other arm then gets the full step).
    share : float or None
        Fraction of each arm's step applied (default 1.0: Algorithm 2 applies the full step to both arms;
        0.5 is the Sec. 2.10 reading "error divided equally").
    settings : LoopSettings
    arms : (str, str)
        Names for A and B (default: the model names).

    Jacobian eq. 2.53 per arm; update ``o_arm += share * x_arm``.
    """
    q = _readings(model_a, model_b, q_a, q_b)
    T_ab, source = _clamp(model_a, model_b, *q, T_toolA_toolB)
    arms = _arm_names(model_a, model_b, arms)
    share = 1.0 if share is None else float(share)
    return _dual(
        "thesis.dual_offsets",
        (model_a, model_b),
        q,
        T_ab,
        source,
        arms,
        known,
        share,
        settings,
        jacobian=lambda m, qq, kin: space_jacobian(m, qq, kin),
        apply=lambda m, x: m.replace(offsets=m.offsets + x),
        names_of=lambda m, arm: [f"{arm}.{j}.offset" for j in m.joint_names],
        values_of=lambda m: np.array(m.offsets),
    )


def _apply_kinematic(model: ArmModel, x: np.ndarray) -> ArmModel:
    """Eq. 2.56 on the twists and xi_st, then conformation eq. 2.57-2.58 (the thesis' variant)."""
    n = model.dof
    screws = conform_twists(model.screws + x[: 6 * n].reshape(n, 6), model.joint_types, mode="thesis")
    return model.replace(screws=screws, home=se3.exp(model.home_twist() + x[6 * n :]))


def calib_dual_kinematic(
    model_a: ArmModel,
    model_b: ArmModel,
    q_a,
    q_b,
    T_toolA_toolB=None,
    *,
    known: str | None = None,
    share: float | None = None,
    settings: LoopSettings = LoopSettings(),
    arms: tuple[str, str] | None = None,
) -> BaselineResult:
    """Algorithm 1: joint twists and xi_st (T_st) of both arms, or of one arm with the other known (Table 4.8).

    Jacobian eq. 2.52 (``twists`` and ``home`` blocks of the identification Jacobian); update
    ``xi += share * x``, ``xi_st += share * x_st``, then the twists are conformed (eq. 2.57-2.58).
    Offsets, base and tool stay as given. Parameters as in ``calib_dual_offsets``
    (``T_toolA_toolB=None`` estimates the clamp with eq. 3.8 from the nominal models), except that
    ``share`` defaults to 0.5 ("50 % of the kinematic parameter error" to each arm), or 1.0 when one
    arm is ``known``.
    """
    q = _readings(model_a, model_b, q_a, q_b)
    T_ab, source = _clamp(model_a, model_b, *q, T_toolA_toolB)
    arms = _arm_names(model_a, model_b, arms)
    share = (0.5 if known is None else 1.0) if share is None else float(share)
    return _dual(
        "thesis.dual_kinematic",
        (model_a, model_b),
        q,
        T_ab,
        source,
        arms,
        known,
        share,
        settings,
        jacobian=lambda m, qq, kin: identification_jacobian(m, qq, kin=kin).stacked(("twists", "home"))[0],
        apply=_apply_kinematic,
        names_of=lambda m, arm: identification_jacobian(m, np.zeros(m.dof)).stacked(("twists", "home"), arm)[1],
        values_of=lambda m: np.concatenate([m.screws.reshape(-1), m.home_twist()]),
    )
