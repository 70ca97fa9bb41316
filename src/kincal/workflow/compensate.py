"""Compensated targets: the joint values the calibrated robot needs to reach the poses a program intends.

A program taught or computed on the nominal model intends, at each row, the tool pose the nominal model gives
(joint programs) or a tool pose given outright (Cartesian targets). The calibrated model reaches that pose at
other joint values: inverse kinematics on the calibrated model (``kincal.simulate.solve``, damped least
squares, batched), started from the program's own joint values (or a nominal IK solution), so the branch is
kept, and for a redundant arm the minimum-norm steps keep the arm angle close to the program's. Every row gets
its remaining position and rotation error; rows that cannot reach their pose within the limits are named. An arm
with fewer than six joints is compensated for its tool point (its orientation follows from the position).

Tree-structured robots (``Robot.mounts``): a mounted arm's target is its tool's world pose through its carriers
(the composite chain, ``kincal.kinematics.tree``). The carriers' joints are shared by every arm on them, so their
readings are **held** as the program gives them (an arm of the program that carries another arm of the program
is held, never solved), and the mounted arm alone is solved for the target seen from the calibrated carrier's
tool at those readings: ``T_carriertool_target = T_world_carriertool(calibrated, q_carriers)^-1 T_world_target``.
Coupled joints (``ArmModel.couplings``) are derived from the joints they follow, never solved: the inverse
kinematics runs over the free joints (``_Coupled``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from kincal.errors import ModelError, ShapeError
from kincal.kinematics import ArmModel, Robot, forward_kinematics
from kincal.kinematics.couplings import coupling_map, derive_readings
from kincal.kinematics.tree import tip_pose
from kincal.lie import se3, so3
from kincal.simulate import PoseConstraint, PositionConstraint, solve

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
    largest joint change (rad or m). ``held``: the readings of the carriers of a tree (a torso), kept as the
    program gives them (coupled joints derived)."""

    q: Mapping[str, np.ndarray]
    position_error: Mapping[str, np.ndarray]
    rotation_error: Mapping[str, np.ndarray]
    status: Mapping[str, np.ndarray]
    change: Mapping[str, np.ndarray]
    held: Mapping[str, np.ndarray] = field(default_factory=dict)

    def failed(self) -> list[tuple[str, int, str]]:
        """(arm, row, status) of every row not compensated."""
        return [(a, int(i), str(s[i])) for a, s in self.status.items() for i in np.flatnonzero(s != "ok")]


def compensate_joints(nominal: Robot, calibrated: Robot, program: Mapping[str, np.ndarray]) -> Compensation:
    """Compensate joint programs ``{arm: (N, n) joint values}`` written for ``nominal``: each row's intended
    pose is the nominal model's tool pose there (both arms of a dual-arm program in the common world frame; a
    mounted arm's through its carriers, whose readings the program holds: module docstring)."""
    held, program = _held(nominal, program)
    out = {}
    for arm, q in program.items():
        if arm not in held:
            line = nominal.lineage(arm)
            T = tip_pose(nominal, arm, {s: program[s] for s in line})
            out[arm] = _solve_tip(calibrated, arm, T, program, nominal)
    return _collect(out, held)


def compensate_poses(calibrated: Robot, targets: Mapping[str, np.ndarray], seeds: Mapping[str, np.ndarray],
                     nominal: Robot | None = None) -> Compensation:
    """Compensate Cartesian targets ``{arm: (N, 4, 4) tool poses}`` (world frame), starting each row's IK at
    ``seeds[arm]`` (N, n): the nominal joint values that reach it (which choose the branch). A mounted arm's
    carriers are held at ``seeds[carrier]`` (module docstring)."""
    limits = nominal or calibrated
    held, seeds = _held(limits, seeds, targets)
    out = {}
    for arm, T in targets.items():
        T = np.asarray(T, float)
        if T.ndim != 3 or T.shape[1:] != (4, 4):
            raise ShapeError(f"targets of arm '{arm}': expected (N, 4, 4) tool poses, found shape {T.shape}")
        if len(seeds[arm]) != len(T):
            raise ShapeError(f"targets of arm '{arm}': {len(T)} poses but {len(seeds[arm])} seed configurations")
        out[arm] = _solve_tip(calibrated, arm, T, seeds, limits)
    return _collect(out, held)


def _held(robot: Robot, program: Mapping[str, np.ndarray], solved=None) -> tuple[dict, dict]:
    """(held carriers' readings, every arm's readings checked, couplings derived). ``solved``: the arms to
    solve (default: every arm of ``program`` that carries no other arm of it); each needs its carriers."""
    for arm in program:
        if arm not in robot.arms:
            raise ModelError(f"program: no arm '{arm}' in robot '{robot.name}' (arms: {', '.join(robot.arms)})")
    carriers = {c for a in program for c in robot.lineage(a)[:-1]}
    solved = [a for a in program if a not in carriers] if solved is None else list(solved)
    for arm in solved:
        if arm not in program:
            raise ShapeError(f"targets of arm '{arm}': no seed configurations (its nominal joint values)")
        missing = [c for c in robot.lineage(arm) if c not in program]
        if missing:
            raise ModelError(f"program: arm '{arm}' is mounted on '{missing[0]}', whose readings its targets need "
                             f"(held fixed while '{arm}' is solved); give them as {missing[0]}.<joint> values")
        rows = {c: len(program[c]) for c in robot.lineage(arm)}
        if len(set(rows.values())) > 1:
            raise ShapeError(f"program of arm '{arm}': its carriers' readings need one row per target; rows: "
                             + ", ".join(f"{c} {n}" for c, n in rows.items()))
    q = {a: derive_readings(robot[a].couplings, robot[a].joint_names, _joints(robot[a], v, a))
         for a, v in program.items()}
    return {a: v for a, v in q.items() if a not in solved}, q


def _solve_tip(calibrated: Robot, arm: str, T: np.ndarray, q: Mapping[str, np.ndarray], limits: Robot):
    """Solve ``arm`` for world targets T with its carriers held at ``q``: the targets seen from the calibrated
    carrier's tool, on the arm's own chain (whose base is given in that tool frame)."""
    line = calibrated.lineage(arm)
    if len(line) > 1:
        carrier = tip_pose(calibrated, line[-2], {s: q[s] for s in line[:-1]})
        T = se3.inverse(carrier) @ T
    out = _solve(calibrated[arm], T, q[arm], limits[arm])
    held_ok = np.logical_and.reduce([limits[s].within_limits(q[s]) for s in line[:-1]], initial=True)
    out[3][~held_ok] = "outside limits"
    return out


def _joints(model: ArmModel, q, arm: str) -> np.ndarray:
    q = np.asarray(q, float)
    if q.ndim != 2 or q.shape[1] != model.dof:
        raise ShapeError(f"program of arm '{arm}': expected (N, {model.dof}) joint values, found shape {q.shape}")
    if not np.all(np.isfinite(q)):
        row = int(np.argwhere(~np.isfinite(q))[0][0])
        raise ShapeError(f"program of arm '{arm}': row {row} is not finite")
    return q


def _solve(model: ArmModel, T: np.ndarray, seed: np.ndarray, limits: ArmModel):
    free = model.dof - len(model.couplings)
    if free < 6:  # fewer than six joints place the tool point; its orientation follows
        constraint = PositionConstraint(model, T[:, :3, 3])
        tol_rad = np.inf
    else:
        constraint, tol_rad = PoseConstraint(model, T), TOL_RAD
    if model.couplings:
        constraint = _Coupled(constraint, model)
    ik = solve(constraint, seed, tol_m=TOL_M, tol_rad=tol_rad, max_iter=MAX_ITER)
    q = derive_readings(model.couplings, model.joint_names, ik.last)
    rot = so3.angle(so3.log(np.swapaxes(T[:, :3, :3], 1, 2) @ forward_kinematics(model, q)[:, :3, :3]))
    reached = (ik.last_pos_err < 1e3 * TOL_M) & ((rot < 1e3 * TOL_RAD) | (free < 6))  # 1 um, 1 urad
    status = np.where(reached, "ok", "unreachable").astype(object)
    at_limit = np.any((q <= model.lower + 1e-12) | (q >= model.upper - 1e-12), axis=1)
    status[~(status == "ok") & at_limit] = "limit"
    status[(status == "ok") & ~model.within_limits(q, 1e-12)] = "limit"  # a derived (coupled) joint past a limit
    change = np.max(np.abs(q - seed), axis=1)
    status[(status == "ok") & (change > BRANCH_RAD)] = "branch changed"
    status[~limits.within_limits(seed)] = "outside limits"
    return q, ik.last_pos_err, rot, status, change


def _collect(per_arm, held=None) -> Compensation:
    """One Compensation of the per-arm tuples (q, position error, rotation error, status, change)."""
    return Compensation(*({a: v[k] for a, v in per_arm.items()} for k in range(5)), held=dict(held or {}))


class _Coupled:
    """An IK constraint over an arm's readings whose coupled joints follow the others (``q_full = q A^T + b``,
    ``kincal.kinematics.couplings``): their Jacobian columns are zero, so the solver never moves them."""

    def __init__(self, inner, model: ArmModel):
        self.inner = inner
        self.A, self.b = coupling_map(model.couplings, model.joint_names)
        self.lower, self.upper, self.size = inner.lower, inner.upper, inner.size

    def residual(self, q, idx):
        e, J, perr, rerr = self.inner.residual(q @ self.A.T + self.b, idx)
        return e, J @ self.A, perr, rerr
