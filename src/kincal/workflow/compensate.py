"""Compensated targets: the joint values the calibrated robot needs to reach the poses a program intends.

A program taught or computed on the nominal model intends, at each row, the tool pose the nominal model gives
(joint programs) or a tool pose given outright (Cartesian targets). The calibrated model reaches that pose at
other joint values: inverse kinematics on the calibrated model (``kincal.simulate.solve_ik``, damped least
squares, batched), started from the program's own joint values (or a nominal IK solution), so the branch is
kept, and for a redundant arm the minimum-norm steps keep the arm angle close to the program's. Every row gets
its remaining position and rotation error; rows that cannot reach their pose within the limits are named. An arm
with fewer than six joints is compensated for its tool point (its orientation follows from the position).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from kincal.errors import ShapeError
from kincal.kinematics import ArmModel, Robot, forward_kinematics
from kincal.lie import so3
from kincal.simulate import PositionConstraint, solve, solve_ik

# A row is compensated when the calibrated tool reaches the intended pose within these (m, rad).
TOL_M = 1e-9
TOL_RAD = 1e-9
MAX_ITER = 100
# A compensation moves joints by what calibration errors amount to (hundredths of a rad); a solution this far
# from the program's row is in another branch (elbow or wrist flipped): never silently accepted.
BRANCH_RAD = 0.5


@dataclass(frozen=True, eq=False)
class Compensation:
    """Per arm: ``q`` (N, n) compensated joint values, ``position_error`` and ``rotation_error`` (N,) of the
    calibrated tool there against the intended pose (m, rad), ``status`` (N,) of ``ok``, ``limit`` (a joint
    at its limit keeps the pose out of reach), ``unreachable`` (not in the program's branch: the pose left
    it, typically near a singularity), ``branch changed`` (reached, but ``BRANCH_RAD`` or more from the
    program's row) or ``outside limits`` (the program's own row is past a limit), and ``change`` (N,) the
    largest joint change (rad or m)."""

    q: Mapping[str, np.ndarray]
    position_error: Mapping[str, np.ndarray]
    rotation_error: Mapping[str, np.ndarray]
    status: Mapping[str, np.ndarray]
    change: Mapping[str, np.ndarray]

    def failed(self) -> list[tuple[str, int, str]]:
        """(arm, row, status) of every row not compensated."""
        return [(a, int(i), str(s[i])) for a, s in self.status.items() for i in np.flatnonzero(s != "ok")]


def compensate_joints(nominal: Robot, calibrated: Robot, program: Mapping[str, np.ndarray]) -> Compensation:
    """Compensate joint programs ``{arm: (N, n) joint values}`` written for ``nominal``: each row's intended
    pose is the nominal model's tool pose there (both arms of a dual-arm program in the common world frame)."""
    out = {}
    for arm, q in program.items():
        q = _joints(nominal[arm], q, arm)
        out[arm] = _solve(calibrated[arm], forward_kinematics(nominal[arm], q), q, nominal[arm])
    return _collect(out)


def compensate_poses(calibrated: Robot, targets: Mapping[str, np.ndarray], seeds: Mapping[str, np.ndarray],
                     nominal: Robot | None = None) -> Compensation:
    """Compensate Cartesian targets ``{arm: (N, 4, 4) tool poses}``, starting each row's IK at ``seeds[arm]``
    (N, n): the nominal joint values that reach it (which choose the branch)."""
    out = {}
    for arm, T in targets.items():
        T = np.asarray(T, float)
        if T.ndim != 3 or T.shape[1:] != (4, 4):
            raise ShapeError(f"targets of arm '{arm}': expected (N, 4, 4) tool poses, found shape {T.shape}")
        seed = _joints(calibrated[arm], seeds[arm], arm)
        if len(seed) != len(T):
            raise ShapeError(f"targets of arm '{arm}': {len(T)} poses but {len(seed)} seed configurations")
        out[arm] = _solve(calibrated[arm], T, seed, (nominal or calibrated)[arm])
    return _collect(out)


def _joints(model: ArmModel, q, arm: str) -> np.ndarray:
    q = np.asarray(q, float)
    if q.ndim != 2 or q.shape[1] != model.dof:
        raise ShapeError(f"program of arm '{arm}': expected (N, {model.dof}) joint values, found shape {q.shape}")
    if not np.all(np.isfinite(q)):
        row = int(np.argwhere(~np.isfinite(q))[0][0])
        raise ShapeError(f"program of arm '{arm}': row {row} is not finite")
    return q


def _solve(model: ArmModel, T: np.ndarray, seed: np.ndarray, limits: ArmModel):
    if model.dof < 6:  # fewer than six joints place the tool point; its orientation follows
        ik = solve(PositionConstraint(model, T[:, :3, 3]), seed, tol_m=TOL_M, tol_rad=np.inf, max_iter=MAX_ITER)
    else:
        ik = solve_ik(model, T, seed, tol_m=TOL_M, tol_rad=TOL_RAD, max_iter=MAX_ITER)
    q = ik.last
    rot = so3.angle(so3.log(np.swapaxes(T[:, :3, :3], 1, 2) @ forward_kinematics(model, q)[:, :3, :3]))
    reached = (ik.last_pos_err < 1e3 * TOL_M) & ((rot < 1e3 * TOL_RAD) | (model.dof < 6))  # 1 um, 1 urad
    status = np.where(reached, "ok", "unreachable").astype(object)
    stuck = ~(status == "ok") & np.any((q <= model.lower + 1e-12) | (q >= model.upper - 1e-12), axis=1)
    status[stuck] = "limit"
    change = np.max(np.abs(q - seed), axis=1)
    status[(status == "ok") & (change > BRANCH_RAD)] = "branch changed"
    status[~limits.within_limits(seed)] = "outside limits"
    return q, ik.last_pos_err, rot, status, change


def _collect(per_arm) -> Compensation:
    """One Compensation of the per-arm tuples (q, position error, rotation error, status, change)."""
    return Compensation(*({a: v[k] for a, v in per_arm.items()} for k in range(5)))
