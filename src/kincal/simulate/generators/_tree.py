"""Generators on tree-structured robots (``Robot.mounts``): readings of every arm carrying the data set's arms,
joint couplings applied, and the closed chain of two tips sharing their ancestors (a torso moved with them)."""

from __future__ import annotations

import numpy as np

from kincal.errors import ModelError
from kincal.kinematics import Robot, loaded_forward_kinematics
from kincal.kinematics.branches import model_loading_branches, tree_loaded_kinematics
from kincal.kinematics.couplings import coupling_map
from kincal.kinematics.tree import tip_model
from kincal.simulate.ik import ClosedChainConstraint, _PoseResidual


def carriers(robot: Robot, arms) -> tuple[str, ...]:
    """Every arm whose readings the data of ``arms`` needs: their lineages, root first, each once."""
    out: list[str] = []
    for arm in arms:
        out += [a for a in robot.lineage(arm) if a not in out]
    return tuple(out)


def with_couplings(robot: Robot, q: dict) -> dict:
    """Readings per arm with each coupled joint's entry derived from the others (``ArmModel.couplings``)."""
    out = {}
    for a, qa in q.items():
        m = robot[a]
        if m.couplings:
            A, b = coupling_map(m.couplings, m.joint_names)
            qa = np.asarray(qa, dtype=float) @ A.T + b
        out[a] = qa
    return out


def blocks(robot: Robot, names) -> dict[str, np.ndarray]:
    """Column indices of each arm's readings when the arms ``names`` are stacked side by side."""
    sizes = [robot[a].dof for a in names]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    return {a: np.arange(starts[i], starts[i + 1]) for i, a in enumerate(names)}


def split(robot: Robot, names, q: np.ndarray) -> dict[str, np.ndarray]:
    """Stacked readings (N, m) of the arms ``names`` back to a mapping arm -> (N, n), couplings applied."""
    return with_couplings(robot, {a: q[:, idx] for a, idx in blocks(robot, names).items()})


class SharedClosedChain(_PoseResidual):
    """Two tips clamped tool to tool (``ClosedChainConstraint`` on their composite chains) whose common
    ancestors (a torso) are one set of variables: q stacks the readings of ``carriers(robot, (a, b))``.

    Coupled joints' columns are zero (they follow the joints they depend on), so IK never moves them; read the
    result through ``split``."""

    def __init__(self, robot: Robot, a: str, b: str, T_toolA_toolB: np.ndarray):
        self.names = carriers(robot, (a, b))
        idx = blocks(robot, self.names)
        self.ia = np.concatenate([idx[s] for s in robot.lineage(a)])
        self.ib = np.concatenate([idx[s] for s in robot.lineage(b)])
        self.inner = ClosedChainConstraint(tip_model(robot, a), tip_model(robot, b), T_toolA_toolB)
        self.lower = np.concatenate([robot[s].lower for s in self.names])
        self.upper = np.concatenate([robot[s].upper for s in self.names])
        self.size = len(self.lower)
        maps = [coupling_map(robot[s].couplings, robot[s].joint_names) for s in self.names]
        self.A = _block_diag([A for A, _ in maps])
        self.b = np.concatenate([b for _, b in maps])

    def pose_error(self, q, idx):
        full = q @ self.A.T + self.b
        X, J = self.inner.pose_error(np.concatenate([full[:, self.ia], full[:, self.ib]], axis=1), idx)
        out = np.zeros(J.shape[:-1] + (self.size,))
        out[..., self.ia] += J[..., : len(self.ia)]
        out[..., self.ib] += J[..., len(self.ia):]
        return X, out @ self.A

    def tip_a(self, q: np.ndarray) -> np.ndarray:
        """Readings of arm A's composite chain from the stacked q."""
        return (q @ self.A.T + self.b)[:, self.ia]


def _block_diag(mats) -> np.ndarray:
    n = sum(m.shape[0] for m in mats)
    out, r = np.zeros((n, n)), 0
    for m in mats:
        out[r: r + len(m), r: r + len(m)] = m
        r += len(m)
    return out


def tip_readings(robot: Robot, arm: str, q: np.ndarray) -> dict[str, np.ndarray]:
    """Readings (N, m) of ``tip_model(robot, arm)`` as arm -> (N, n) over ``arm``'s lineage, couplings applied."""
    return split(robot, robot.lineage(arm), q)


def coupled_readings(model, q: np.ndarray) -> np.ndarray:
    """Readings (N, n) of ``model`` with its coupled joints' entries derived (``ArmModel.couplings``)."""
    if not model.couplings:
        return q
    A, b = coupling_map(model.couplings, model.joint_names)
    return q @ A.T + b


def uncoupled_tip(robot: Robot, arm: str, kind: str):
    """``tip_model(robot, arm)`` for the generators whose inverse kinematics does not hold couplings (clamp,
    plate, socket); ModelError when the arm or a carrier has couplings."""
    model = tip_model(robot, arm)
    if model.couplings:
        raise ModelError(f"{kind}: arm '{arm}' has joint couplings ({', '.join(model.couplings)}); the {kind} "
                         "generator does not hold them: simulate with dual, pose or markers data")
    return model


def hung_readings(robot: Robot, arm: str, n: int, draw) -> dict[str, np.ndarray]:
    """Readings (couplings applied) of the other arms whose weight loads ``arm``'s carriers (gravity on a tree,
    ``kincal.kinematics.branches``), drawn by ``draw(model, n)``; {} when there are none (no draws)."""
    return with_couplings(robot, {o: draw(robot[o], n) for o in model_loading_branches(robot, robot.lineage(arm))})


def true_tool_poses(robot: Robot, arm: str, model, q: np.ndarray, loads, others: dict) -> np.ndarray:
    """True tool poses of ``arm`` (``model``: its tip model) at the tip readings ``q`` (N, m), deflected by the
    loads and, on a tree with gravity, by the weights of the whole tree (the other arms at ``others``)."""
    if not tree_has_gravity(robot, arm):
        return loaded_forward_kinematics(model, q, loads)
    return tree_loaded_kinematics(robot, arm, {**tip_readings(robot, arm, q), **others}, loads).tool


def tree_has_gravity(robot: Robot, arm: str) -> bool:
    """Whether ``arm`` belongs to a tree of several arms with gravity (``kincal.kinematics.branches``)."""
    members = [a for a in robot.arms if robot.lineage(a)[0] == robot.lineage(arm)[0]]
    return len(members) > 1 and any(robot[a].gravity is not None for a in members)
