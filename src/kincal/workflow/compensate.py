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

Sag (``kincal.workflow.sag``): when the calibrated model is compliant and loaded (tool wrenches, a payload, the
weights of its mass model, on an arm or a tree), the compensated readings make the *deflected* calibrated model
reach the target, with the deflection model of the solver's residuals; the intended pose of a joint program is the
nominal model's own prediction under the same loads (its rigid pose when it has no compliance). On a tree the
carriers are still held, but they deflect too: every solved arm is solved through the whole loaded chain, and
the arms whose weight loads the carriers need readings in the program. ``rigid=True`` ignores the deflection.
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
from kincal.workflow.sag import (PASSES, STILL, LoadedTip, arm_free, loaded_pose, needed, sags, tip_errors,
                                 tool_wrenches, with_payload)

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
    it, typically near a singularity), ``not converged`` (under sag on a tree: the passes over the arms did not
    settle this row), ``branch changed`` (reached, but ``BRANCH_RAD`` or more from the
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


def compensate_joints(nominal: Robot, calibrated: Robot, program: Mapping[str, np.ndarray], *, wrench=None,
                      payload=None, rigid: bool = False) -> Compensation:
    """Compensate joint programs ``{arm: (N, n) joint values}`` written for ``nominal``: each row's intended
    pose is the nominal model's tool pose there (both arms of a dual-arm program in the common world frame; a
    mounted arm's through its carriers, whose readings the program holds: module docstring). Loads (``wrench``:
    arm -> (6,) or (N, 6) tool wrench; ``payload``: arm -> (kg, centre of mass in the tool frame)) deflect a
    compliant calibrated model, and the compensation reaches the target with that deflection
    (``kincal.workflow.sag``) unless ``rigid``."""
    nominal, calibrated = with_payload(nominal, payload), with_payload(calibrated, payload)
    held, program = _held(nominal, program)
    solved = [a for a in program if a not in held]
    loads = tool_wrenches(wrench, {a: len(program[a]) for a in solved})
    if not rigid and any(sags(calibrated, a, loads[a]) for a in solved):
        _needs(calibrated, solved, program)
        targets = {a: loaded_pose(nominal, a, program, loads[a]) for a in solved}
        return _collect(_solve_loaded(calibrated, targets, program, loads, nominal), held)
    out = {}
    for arm in solved:
        line = nominal.lineage(arm)
        T = tip_pose(nominal, arm, {s: program[s] for s in line})
        out[arm] = _solve_tip(calibrated, arm, T, program, nominal)
    return _collect(out, held)


def compensate_poses(calibrated: Robot, targets: Mapping[str, np.ndarray], seeds: Mapping[str, np.ndarray],
                     nominal: Robot | None = None, *, wrench=None, payload=None, rigid: bool = False) -> Compensation:
    """Compensate Cartesian targets ``{arm: (N, 4, 4) tool poses}`` (world frame), starting each row's IK at
    ``seeds[arm]`` (N, n): the nominal joint values that reach it (which choose the branch). A mounted arm's
    carriers are held at ``seeds[carrier]`` (module docstring); loads as in ``compensate_joints``."""
    calibrated = with_payload(calibrated, payload)
    limits = nominal or calibrated
    held, seeds = _held(limits, seeds, targets)
    poses = {}
    for arm, T in targets.items():
        T = np.asarray(T, float)
        if T.ndim != 3 or T.shape[1:] != (4, 4):
            raise ShapeError(f"targets of arm '{arm}': expected (N, 4, 4) tool poses, found shape {T.shape}")
        if len(seeds[arm]) != len(T):
            raise ShapeError(f"targets of arm '{arm}': {len(T)} poses but {len(seeds[arm])} seed configurations")
        poses[arm] = T
    loads = tool_wrenches(wrench, {a: len(T) for a, T in poses.items()})
    if not rigid and any(sags(calibrated, a, loads[a]) for a in poses):
        _needs(calibrated, list(poses), seeds)
        return _collect(_solve_loaded(calibrated, poses, seeds, loads, limits), held)
    return _collect({a: _solve_tip(calibrated, a, T, seeds, limits) for a, T in poses.items()}, held)


def _needs(robot: Robot, solved, program: Mapping[str, np.ndarray]) -> None:
    """Every arm whose weight loads a solved arm's carriers has readings in the program, one per row."""
    for arm in solved:
        for other in needed(robot, arm):
            if other not in program:
                raise ModelError(f"program: the weight of arm '{other}' loads the carriers of arm '{arm}' (gravity on "
                                 f"a tree), so its compensation under sag needs '{other}' readings: give them as "
                                 f"{other}.<joint> values (or compensate rigidly)")
            if len(program[other]) != len(program[arm]):
                raise ShapeError(f"program of arm '{arm}': {len(program[arm])} rows, but arm '{other}', whose weight "
                                 f"loads its carriers, has {len(program[other])}")


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
    free = arm_free(model)
    if free < 6:  # fewer than six joints place the tool point; its orientation follows
        constraint = PositionConstraint(model, T[:, :3, 3])
    else:
        constraint = PoseConstraint(model, T)
    ik = _ik(constraint, model, seed)
    q = derive_readings(model.couplings, model.joint_names, ik.last)
    rot = so3.angle(so3.log(np.swapaxes(T[:, :3, :3], 1, 2) @ forward_kinematics(model, q)[:, :3, :3]))
    return _status(model, q, seed, ik.last_pos_err, rot, np.zeros(len(q), bool), limits)


def _ik(constraint, model: ArmModel, seed: np.ndarray):
    """Damped least squares to TOL_M / TOL_RAD (the rotation free for fewer than six joints), couplings held."""
    if model.couplings:
        constraint = _Coupled(constraint, model)
    tol_rad = np.inf if arm_free(model) < 6 else TOL_RAD
    return solve(constraint, seed, tol_m=TOL_M, tol_rad=tol_rad, max_iter=MAX_ITER)


def _status(model: ArmModel, q, seed, perr, rot, settled, limits: ArmModel):
    """(q, position error, rotation error, status, change) of one arm's rows; ``settled``: rows whose last IK
    converged (a remaining error there means the sag passes did not settle: ``not converged``)."""
    reached = (perr < 1e3 * TOL_M) & ((rot < 1e3 * TOL_RAD) | (arm_free(model) < 6))  # 1 um, 1 urad
    status = np.where(reached, "ok", np.where(settled, "not converged", "unreachable")).astype(object)
    at_limit = np.any((q <= model.lower + 1e-12) | (q >= model.upper - 1e-12), axis=1)
    status[~(status == "ok") & at_limit] = "limit"
    status[(status == "ok") & ~model.within_limits(q, 1e-12)] = "limit"  # a derived (coupled) joint past a limit
    change = np.max(np.abs(q - seed), axis=1)
    status[(status == "ok") & (change > BRANCH_RAD)] = "branch changed"
    status[~limits.within_limits(seed)] = "outside limits"
    return q, perr, rot, status, change


def _solve_loaded(calibrated: Robot, targets: Mapping[str, np.ndarray], q: Mapping[str, np.ndarray], loads,
                  limits: Robot) -> dict:
    """Every arm of ``targets`` solved for its loaded pose, in passes until no reading moves
    (``kincal.workflow.sag``); carriers and other arms at ``q``. Errors from all arms' final readings."""
    q, seeds = dict(q), {a: np.asarray(q[a], float) for a in targets}
    tips = {a: LoadedTip(calibrated, a, T, q, loads[a], arm_free(calibrated[a]) < 6) for a, T in targets.items()}
    settled = {}
    for _ in range(PASSES):
        moved = 0.0
        for a, tip in tips.items():
            m = calibrated[a]
            ik = _ik(tip, m, q[a])
            new = derive_readings(m.couplings, m.joint_names, ik.last)
            moved = max(moved, float(np.max(np.abs(new - q[a]), initial=0.0)))
            q[a], settled[a] = new, np.isin(np.arange(len(new)), ik.index)
        if moved <= STILL:
            break
    out = {}
    for a, T in targets.items():
        perr, rot = tip_errors(calibrated, a, T, q, loads[a])
        out[a] = _status(calibrated[a], q[a], seeds[a], perr, rot, settled[a], limits[a])
        line = calibrated.lineage(a)
        held_ok = np.logical_and.reduce([limits[s].within_limits(q[s]) for s in line[:-1]], initial=True)
        out[a][3][~held_ok] = "outside limits"
    return out


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
