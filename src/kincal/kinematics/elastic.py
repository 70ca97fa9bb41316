"""Joint compliance under a known load at the tool (first-order elastostatics, seed 001 eq. 2).

Sign convention: ``wrench_tool = (f, m)`` (N, N m) is the load applied TO the tool BY the environment (a
payload hanging from the tool: ``f = m g``, pointing down), in the tool frame, acting at the tool origin.
Its torque on joint i is ``tau = J_b(theta0)^T wrench`` (``J_b`` the body Jacobian, columns (v, w), at the
unloaded configuration ``theta0 = q + o``), and each joint yields like a linear spring in the direction of
that torque::

    theta = q + o + c * tau        (c: joint compliance, rad/(N m) revolute, m/N prismatic)

so a downward force on a horizontal arm makes the tool sag. First order, as in the paper: ``tau`` is
evaluated at the unloaded configuration (the change of the lever arms by the deflection itself, of order
``c |tau|`` relative, is neglected), links are rigid and only the actuated joints are compliant.

In world coordinates ``tau_i = xi_s_i . F_s`` with ``xi_s_i = Ad(P_{i-1}) xi_i`` the current joint axis and
``F_s = Ad(T_world_tool^-1)^T wrench`` the load as a spatial wrench (the same number in any frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kincal._validate import as_array
from kincal.kinematics.fk import Kinematics, chain, joint_array
from kincal.kinematics.model import ArmModel
from kincal.lie import se3


@dataclass(frozen=True)
class LoadedKinematics(Kinematics):
    """Kinematics at the deflected joint values, with the unloaded pass that gave the load torques.

    ``unloaded``: the chain at ``theta0``; ``wrench_space`` (..., 6): ``F_s``; ``axes`` (..., n, 6): ``xi_s_i`` at
    ``theta0``; ``tau`` (..., n): load torques (N m; N for prismatic joints).
    """

    unloaded: Kinematics | None = None
    wrench_space: np.ndarray | None = None
    axes: np.ndarray | None = None
    tau: np.ndarray | None = None


def loaded_chain(screws, theta0, base, home, tool, compliance, wrench_tool) -> LoadedKinematics:
    """Unvalidated kernel on raw arrays: ``theta0`` (..., n) unloaded joint values, ``wrench_tool`` (..., 6)."""
    kin0 = chain(screws, theta0, base, home, tool)
    F_s = np.einsum("...ji,...j->...i", se3.adjoint_inv(kin0.tool), wrench_tool)  # Ad(T^-1)^T F_b
    axes = np.einsum("...kij,kj->...ki", se3.adjoint(kin0.prefixes[..., :-1, :, :]), screws)
    tau = np.einsum("...ki,...i->...k", axes, F_s)
    kin = chain(screws, kin0.theta + compliance * tau, base, home, tool)
    return LoadedKinematics(kin.theta, kin.exps, kin.prefixes, kin.flange, kin.tool, kin0, F_s, axes, tau)


def _wrench(wrench_tool, shape) -> np.ndarray:
    w = as_array(wrench_tool, "wrench_tool", (6,))
    return np.broadcast_to(w, shape + (6,))


def loaded_kinematics(model: ArmModel, q, wrench_tool) -> LoadedKinematics:
    """Forward kinematics of ``model`` at readings q (..., n) under ``wrench_tool`` (6,) or (..., 6)."""
    q = joint_array(model, q)
    w = _wrench(wrench_tool, q.shape[:-1])
    return loaded_chain(model.screws, q + model.offsets, model.base, model.home, model.tool, model.compliance, w)


def loaded_forward_kinematics(model: ArmModel, q, wrench_tool) -> np.ndarray:
    """``T_world_tool`` of the deflected arm: (..., n) readings, (6,) or (..., 6) loads -> (..., 4, 4)."""
    return loaded_kinematics(model, q, wrench_tool).tool


def load_torques(model: ArmModel, q, wrench_tool) -> np.ndarray:
    """Joint load torques ``J_b(q + o)^T wrench_tool`` (..., n) at the unloaded configuration."""
    return loaded_kinematics(model, q, wrench_tool).tau
