"""Shared kernels: an arm's tool-pose Jacobians at its current values, and the gap between two poses or points.

Jacobians of poses are w.r.t. *left (space) increments*: ``T -> exp(d) T`` with d in world coordinates.
"""

from __future__ import annotations

import numpy as np

from kincal.kinematics import Kinematics
from kincal.kinematics.jacobians import TOOL_PARTS, tool_jacobians
from kincal.lie import se3, so3
from kincal.params import ArmValues

ARM_PARTS = TOOL_PARTS


def arm_jacobians(a: ArmValues, kin: Kinematics, G: np.ndarray, parts=ARM_PARTS, with_jq: bool = True, q=None):
    """``kincal.kinematics.tool_jacobians`` for one arm's current values ``a``: ``G @ d T_world_tool / d param``
    per part (N, k, d), and ``G @ J_q`` (N, k, n) if ``with_jq``; ``q`` (N, n): the readings, which an
    angle-dependent compliance needs (``ArmValues.compliance_basis``)."""
    basis = None if q is None else a.compliance_basis(q)
    return tool_jacobians(kin, G, a.screws, a.generators, a.joint_compliance, parts, with_jq, basis)


def pose_gap(TA: np.ndarray, TB: np.ndarray):
    """r = [p_A - p_B, log(R_A R_B^T)] (N, 6) in world coordinates, and dr/d(left increment) of A and of B."""
    pA, pB = TA[..., :3, 3], TB[..., :3, 3]
    E = TA[..., :3, :3] @ np.swapaxes(TB[..., :3, :3], -1, -2)
    rw = so3.log(E)
    Ji = so3.left_jacobian_inv(rw)
    shape = TA.shape[:-2]
    GA = np.zeros(shape + (6, 6))
    GB = np.zeros(shape + (6, 6))
    GA[..., :3, :3] = np.eye(3)
    GA[..., :3, 3:] = -so3.hat(pA)
    GA[..., 3:, 3:] = Ji
    GB[..., :3, :3] = -np.eye(3)
    GB[..., :3, 3:] = so3.hat(pB)
    GB[..., 3:, 3:] = -Ji @ E
    return np.concatenate([pA - pB, rw], axis=-1), GA, GB


def pose_gap_in_b(TA: np.ndarray, TB: np.ndarray):
    """The gap of ``pose_gap(TB^-1 TA, I)``, i.e. expressed in B's frame, and its derivatives w.r.t. the world
    left increments of A and of B.

    Written in the frame of the fixed side (fixture, plate fixture, the other arm's tool), a common rigid
    motion of both sides leaves the residual unchanged even when it is not zero, so such gauges are exact
    null directions of noisy data, not residual-sized "weak" ones.
    """
    Bi = se3.inverse(TB)
    r, G, _ = pose_gap(Bi @ TA, np.eye(4))
    G = G @ se3.adjoint(Bi)
    return r, G, -G


def point_jacobian(p: np.ndarray) -> np.ndarray:
    """d p / d(left increment of the frame carrying p): [I, -hat(p)], (..., 3, 6)."""
    out = np.zeros(p.shape[:-1] + (3, 6))
    out[..., :, :3] = np.eye(3)
    out[..., :, 3:] = -so3.hat(p)
    return out


def pose_mean(T: np.ndarray) -> np.ndarray:
    """A rigid transform near the mean of T (N, 4, 4): two Gauss-Newton steps of the left log-average."""
    M = T[0]
    for _ in range(2):
        M = se3.exp(np.mean(se3.log(T @ se3.inverse(M)), axis=0)) @ M
    return M


def fit_transform(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rigid T minimizing sum |T src - dst|^2 (Kabsch): points (..., K, 3), batches broadcast (one layout
    against many rows of measured points), -> (..., 4, 4)."""
    src, dst = np.broadcast_arrays(src, dst)
    cs, cd = src.mean(axis=-2), dst.mean(axis=-2)
    U, _, Vt = np.linalg.svd(np.swapaxes(dst - cd[..., None, :], -1, -2) @ (src - cs[..., None, :]))
    U[..., :, 2] *= np.sign(np.linalg.det(U @ Vt))[..., None]  # a proper rotation even for a reflected best fit
    R = U @ Vt
    return se3.make(R, cd - np.einsum("...ij,...j->...i", R, cs))
