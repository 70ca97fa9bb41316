"""Compensation under sag: joint values at which the calibrated, *loaded* robot reaches a target.

A robot calibrated with joint compliances deflects under its loads: tool wrenches, the weights of its mass model
(gravity on an arm or a whole tree), about its lateral axes too. Its tool pose at readings ``q`` is the deflected
one of the solver's residuals (``kincal.kinematics.branches.tree_loaded_kinematics``: first order, the load
torques at the unloaded configuration), so the compensated readings solve ``T_loaded(q) = T_target``.

The solve is damped least squares (``kincal.simulate.solve``) on the loaded pose error with the rigid arm's body
Jacobian: the deflection's own derivative (of relative size ``c dtau/dq``, 1e-3 and below for real arms) is left
out, so each step is a quasi-Newton step and the error still falls to the tolerance (a step is only taken when it
lowers the loaded error). On a tree with gravity, another arm's readings move the carriers' deflection: the arms of
a program are solved in turn, each with the others at their latest values, until no reading moves
(``PASSES`` at most). Every row's error is then evaluated with all arms' final readings, so a row the iteration
did not settle is reported (``not converged``), never silently kept.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from kincal.errors import ModelError, ShapeError
from kincal.kinematics import ArmModel, Robot, body_jacobian
from kincal.kinematics.branches import model_loading_branches, tree_loaded_kinematics
from kincal.lie import se3, so3

# Passes over the arms of a tree program; a reading that moves less than STILL (rad or m) has settled.
PASSES = 10
STILL = 1e-13


def sags(robot: Robot, arm: str, wrench) -> bool:
    """Whether ``arm``'s tool deflects in ``robot``: some arm of its lineage is compliant (joints, compliance
    nodes or lateral) and something loads it (a tool wrench, or weights: its own or the tree's)."""
    line = robot.lineage(arm)
    compliant = any(np.any(robot[a].compliance) or robot[a].compliance_nodes
                    or (robot[a].lateral is not None and np.any(robot[a].lateral)) for a in line)
    loaded = wrench is not None or any(robot[a].has_gravity_load for a in (*line, *model_loading_branches(robot, line)))
    return bool(compliant and loaded)


def needed(robot: Robot, arm: str) -> tuple[str, ...]:
    """The arms whose readings ``arm``'s loaded pose needs: its lineage and the arms whose weight loads it."""
    line = robot.lineage(arm)
    return (*line, *model_loading_branches(robot, line))


def loaded_pose(robot: Robot, arm: str, readings: Mapping[str, np.ndarray], wrench=None) -> np.ndarray:
    """``T_world_tool`` (N, 4, 4) of ``arm`` deflected by ``wrench`` (N, 6) or None and the tree's weights."""
    return tree_loaded_kinematics(robot, arm, {a: readings[a] for a in needed(robot, arm)}, wrench).tool


def tool_wrenches(wrench, arms: Mapping[str, int]) -> dict[str, np.ndarray | None]:
    """Per arm of ``arms`` (arm -> its rows) its tool load (rows, 6) from ``wrench``: None (no load), or arm ->
    (6,) or (rows, 6) (N, N m; tool frame, applied TO the tool, as the data sets' ``wrench_tool``)."""
    out = {}
    for arm, rows in arms.items():
        w = None if wrench is None else wrench.get(arm)
        if w is None:
            out[arm] = None
            continue
        w = np.asarray(w, float)
        if w.shape not in ((6,), (rows, 6)) or not np.all(np.isfinite(w)):
            raise ShapeError(f"tool load of arm '{arm}': expected 6 finite values (fx, fy, fz, tx, ty, tz) or one "
                             f"such row per target ({rows}, 6), found shape {w.shape}")
        out[arm] = np.broadcast_to(w, (rows, 6)).copy()
    for arm in wrench or {}:
        if arm not in arms:
            raise ModelError(f"tool load of arm '{arm}': not an arm the program solves ({', '.join(arms)})")
    return out


def with_payload(robot: Robot, payload) -> Robot:
    """``robot`` with each arm of ``payload`` (arm -> (mass kg, centre of mass (3,) m, tool frame)) carrying it
    instead of its model's payload; the weight needs the model's gravity vector."""
    for arm, (mass, com) in (payload or {}).items():
        model = robot[arm]
        if model.gravity is None or not np.any(model.gravity):
            raise ModelError(f"payload of arm '{arm}': its model states no gravity vector (model field arms.{arm}."
                             "gravity), so a mass does not load it; give the load as a tool wrench instead")
        robot = robot.replace_arm(arm, model.replace(payload_mass=float(mass), payload_com=com))
    return robot


class LoadedTip:
    """IK constraint: ``arm``'s loaded tool pose (or tool point, ``position``) at its target, the other arms at
    ``readings`` (arm -> (N, n), read at each call: the passes update them)."""

    def __init__(self, robot: Robot, arm: str, T: np.ndarray, readings: Mapping[str, np.ndarray], wrench,
                 position: bool):
        self.robot, self.arm, self.model = robot, arm, robot[arm]
        self.T_inv, self.p = se3.inverse(T), T[:, :3, 3]
        self.readings, self.wrench, self.position = readings, wrench, position
        self.lower, self.upper, self.size = self.model.lower, self.model.upper, self.model.dof

    def pose(self, q: np.ndarray, idx) -> np.ndarray:
        r = {a: (q if a == self.arm else self.readings[a][idx]) for a in needed(self.robot, self.arm)}
        return loaded_pose(self.robot, self.arm, r, None if self.wrench is None else self.wrench[idx])

    def residual(self, q, idx):
        T = self.pose(q, idx)
        Jb = body_jacobian(self.model, q)  # the arm's columns of the composite's body Jacobian, rigid
        if self.position:
            e = T[:, :3, 3] - self.p[idx]
            return e, T[:, :3, :3] @ Jb[:, :3, :], np.linalg.norm(e, axis=-1), np.zeros(len(e))
        X = self.T_inv[idx] @ T
        e = se3.log(X)
        J = se3.right_jacobian_inv(e) @ Jb
        return e, J, np.linalg.norm(X[:, :3, 3], axis=-1), so3.angle(se3.split(e)[1])


def tip_errors(robot: Robot, arm: str, T: np.ndarray, readings, wrench) -> tuple[np.ndarray, np.ndarray]:
    """(position m, rotation rad) errors (N,) of ``arm``'s loaded tool at ``readings`` against targets T."""
    X = se3.inverse(T) @ loaded_pose(robot, arm, readings, wrench)
    return np.linalg.norm(X[:, :3, 3], axis=-1), so3.angle(so3.log(X[:, :3, :3]))


def arm_free(model: ArmModel) -> int:
    """Joints the inverse kinematics moves (the coupled ones follow)."""
    return model.dof - len(model.couplings)
