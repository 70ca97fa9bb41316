"""Shared pieces of the thesis baselines: Eval_error (Algorithm 4), the mean transformation matrix,
the damped least-squares step (eq. 2.55), the accept/reject loop of Sec. 2.10 and the result record.

Reproduced as written in the thesis (and in Robotlib.jl, which its code follows), flaws included:
the acceptance test looks at the mean translation error only, the damping is multiplied or divided
by ten, and the loop stops when the norm of the proposed update is below a tolerance.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Callable, Mapping, Sequence

import numpy as np

from kincal.kinematics import ArmModel, Robot
from kincal.lie import se3, so3

log = logging.getLogger(__name__)

DAMPING_FACTOR = 10.0  # thesis Sec. 3.1 and Robotlib.jl: lambda * 10 on reject, / 10 on accept


def eval_error(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """Algorithm 4 (Eval_error): mean translation distance (m) and mean rotation angle (rad).

    T_a, T_b : (N, 4, 4) or broadcastable. Rotation error is |log(R_a^T R_b)|.
    """
    T_a, T_b = np.broadcast_arrays(np.asarray(T_a, dtype=float), np.asarray(T_b, dtype=float))
    trans = np.linalg.norm(T_a[..., :3, 3] - T_b[..., :3, 3], axis=-1)
    rot = np.linalg.norm(so3.log(np.swapaxes(T_a[..., :3, :3], -1, -2) @ T_b[..., :3, :3]), axis=-1)
    return float(np.mean(trans)), float(np.mean(rot))


def mean_transform(T: np.ndarray) -> np.ndarray:
    """The thesis' mean transformation matrix of poses (N, 4, 4) -> (4, 4).

    Mean of the translations; mean of the rotation vectors log(R), mapped back with exp; then
    orthogonalized (Algorithm 3), which only removes rounding since exp already gives a rotation.
    The mean of rotation vectors is not a proper rotation average (wrong near pi): kept as written.
    """
    T = np.asarray(T, dtype=float)
    R = so3.project(so3.exp(np.mean(so3.log(T[..., :3, :3]), axis=0)))
    return se3.make(R, np.mean(T[..., :3, 3], axis=0))


def damped_step(J: np.ndarray, y: np.ndarray, damping: float) -> np.ndarray:
    """Eq. 2.55: x = (J^T J + lambda I)^-1 J^T y for a stacked system J (m, p), y (m,)."""
    return np.linalg.solve(J.T @ J + damping * np.eye(J.shape[1]), J.T @ y)


def stack(J: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2.54: per-sample blocks J (N, 6, p), y (N, 6) -> (6N, p), (6N,)."""
    return J.reshape(-1, J.shape[-1]), y.reshape(-1)


@dataclass(frozen=True)
class LoopSettings:
    """Iteration controls of the thesis' damped least-squares loops (Sec. 2.10).

    max_iter : the iteration budget (the thesis mostly uses 10).
    accept_factor : accept a candidate whose translation error is below ``accept_factor`` times the
        current one (1.0, or 1.5 "in some implementations").
    damping : initial lambda of eq. 2.55.
    step_tol : stop when the norm of the proposed update falls below this.
    """

    max_iter: int = 10
    accept_factor: float = 1.0
    damping: float = 1.0
    step_tol: float = 1e-10

    def __post_init__(self) -> None:
        if self.max_iter < 0 or self.accept_factor <= 0 or self.damping < 0 or self.step_tol < 0:
            raise ValueError(f"invalid loop settings {self}")


@dataclass(frozen=True)
class LoopOutcome:
    params: object
    iterations: int
    accepted: int
    history: np.ndarray  # (k + 1, 2) Eval_error (trans, rot) at the current parameters
    damping: np.ndarray  # (k + 1,)
    cost: tuple[float, ...]  # eq. 4.1 per system, last linearization
    stopped_on_step: bool


def damped_loop(
    params,
    linearize: Callable[[object], Sequence[tuple[np.ndarray, np.ndarray]]],
    update: Callable[[object, Sequence[np.ndarray]], object],
    evaluate: Callable[[object], tuple[float, float]],
    settings: LoopSettings,
) -> LoopOutcome:
    """The accept/reject iteration shared by Algorithms 1-3.

    ``linearize(params)`` gives one stacked system (J, y) per updated arm, ``update(params, steps)``
    the candidate parameters, ``evaluate(params)`` Eval_error. Each system gets its own damped step.
    """
    err = evaluate(params)
    lam = settings.damping
    history, damping = [err], [lam]
    total = accepted = 0
    cost: tuple[float, ...] = ()
    stopped = False
    for _ in range(settings.max_iter):
        systems = linearize(params)
        steps = [damped_step(J, y, lam) for J, y in systems]
        cost = tuple(float(np.linalg.norm(y - J @ x)) for (J, y), x in zip(systems, steps))
        if np.linalg.norm(np.concatenate(steps)) < settings.step_tol:
            stopped = True
            break
        candidate = update(params, steps)
        new = evaluate(candidate)
        total += 1
        if new[0] < settings.accept_factor * err[0]:
            params, err = candidate, new
            accepted += 1
            lam /= DAMPING_FACTOR
        else:
            lam *= DAMPING_FACTOR
        log.debug("iteration %d: error %.3g m %.3g rad, damping %g", total, err[0], err[1], lam)
        history.append(err)
        damping.append(lam)
    return LoopOutcome(params, total, accepted, np.array(history), np.array(damping), cost, stopped)


@dataclass(frozen=True)
class BaselineEstimate:
    """One estimated parameter of a baseline: its stable name and value (rad, m; no standard deviation: the
    thesis' methods have none)."""

    name: str
    value: float


@dataclass(frozen=True)
class BaselineResult:
    """What a thesis baseline returns. It reports, it never raises on poor convergence.

    Attributes
    ----------
    method : str
        ``"thesis.single_offsets"``, ``"thesis.several_points"``, ``"thesis.dual_offsets"`` or
        ``"thesis.dual_kinematic"``.
    models : mapping arm -> ArmModel
        The estimated models (offsets, or twists and home, replaced; everything else as given).
    offsets : mapping arm -> ndarray (n,)
        Estimated joint offsets (rad), ``theta = q + offset`` as in ``ArmModel``.
    parameter_names : tuple of str
        Stable names of the estimated parameters (``left.j3.offset``, ``right.j2.xi.w_x``, ``right.home.v_z``).
    estimate : ndarray (p,)
        Their values, in the order of ``parameter_names``.
    iterations, accepted : int
        The thesis' "x(y)": iterations run and iterations whose update was applied.
    history : ndarray (k + 1, 2)
        Eval_error (mean translation m, mean rotation rad) at the current parameters, initial first.
        For BFGS it is recorded at every BFGS iteration.
    damping : ndarray (k + 1,)
        Lambda of eq. 2.55 after each iteration (empty for BFGS).
    cost : mapping str -> float
        The thesis' reported cost: eq. 4.1 ``|y - A x|`` per arm for the least-squares loops, eq. 3.6 for BFGS.
    converged : bool
        The loop stopped on the step tolerance (or BFGS reported success), not on the iteration budget.
    T_world_fixture : ndarray (4, 4) or None
        Fixture pose used at the end (known, the final mean pose, or BFGS' T_twist).
    T_toolA_toolB : ndarray (4, 4) or None
        Clamp transform used by the dual-arm methods (given or estimated by eq. 3.8).
    validation : tuple of ``kincal.estimation.ValidationStats``
        Errors on held-out data sets before and after (``with_validation``); empty unless validated.

    ``status`` and ``estimates`` read as a kincal ``Result``'s, so both are written by
    ``kincal.io.results.write_results``.
    """

    method: str
    models: Mapping[str, ArmModel]
    offsets: Mapping[str, np.ndarray]
    parameter_names: tuple[str, ...]
    estimate: np.ndarray
    iterations: int
    accepted: int
    history: np.ndarray
    damping: np.ndarray
    cost: Mapping[str, float]
    converged: bool
    T_world_fixture: np.ndarray | None = None
    T_toolA_toolB: np.ndarray | None = None
    meta: Mapping = field(default_factory=dict)
    validation: tuple = ()

    def __post_init__(self) -> None:
        for key in ("models", "offsets", "cost", "meta"):
            object.__setattr__(self, key, MappingProxyType(dict(getattr(self, key))))

    @property
    def status(self) -> str:
        """``converged`` (stopped on the step tolerance, or BFGS' success) or ``not converged``."""
        return "converged" if self.converged else "not converged"

    @property
    def estimates(self) -> tuple["BaselineEstimate", ...]:
        """The estimated parameters as entries, in the order of ``parameter_names``."""
        return tuple(BaselineEstimate(n, float(v)) for n, v in zip(self.parameter_names, self.estimate))

    def calibrated(self, robot: Robot) -> Robot:
        """``robot`` with the estimated arm models in place."""
        for arm, model in self.models.items():
            robot = robot.replace_arm(arm, model)
        return robot

    @property
    def iterations_label(self) -> str:
        """The thesis' notation: total(accepted), e.g. ``10(2)``."""
        return f"{self.iterations}({self.accepted})"

    @property
    def initial_error(self) -> tuple[float, float]:
        return float(self.history[0, 0]), float(self.history[0, 1])

    @property
    def final_error(self) -> tuple[float, float]:
        return float(self.history[-1, 0]), float(self.history[-1, 1])
