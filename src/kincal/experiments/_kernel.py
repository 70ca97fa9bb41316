"""Shared kernels: an arm's tool pose with its parameter Jacobians, and the gap between two poses or points.

Jacobians of poses are w.r.t. *left (space) increments*: ``T -> exp(d) T`` with d in world coordinates.
"""

from __future__ import annotations

import numpy as np

from kincal.kinematics import Kinematics, chain
from kincal.lie import se3, so3
from kincal.params import ArmValues

ARM_PARTS = ("offsets", "twists", "home", "base", "tool")


def arm_tool(a: ArmValues, q: np.ndarray, parts=ARM_PARTS) -> tuple[Kinematics, dict[str, np.ndarray], np.ndarray]:
    """``T_world_tool`` for q (N, n) and ``d/dparam`` of its left increment, per part: (N, 6, k).

    Parts: offsets (additive), twists (tangent coordinates, basis ``a.basis`` at the current step), home/base/tool (``exp(d) T``).
    Also returns ``J_q`` (N, 6, n), the space Jacobian w.r.t. the joint readings (equal to the offsets block).
    """
    kin = chain(a.screws, q + a.offsets, a.base, a.home, a.tool)
    Ad = se3.adjoint(kin.prefixes)  # (N, n+1, 6, 6)
    jq = np.swapaxes((Ad[..., :-1, :, :] @ a.screws[:, :, None])[..., 0], -1, -2)  # (N, 6, n)
    out = {}
    if "offsets" in parts:
        out["offsets"] = jq
    if "twists" in parts:
        # Column block of joint j: Ad(P_{j-1}) theta_j J_l(theta_j xi_j) B_j, all joints at once.
        theta = kin.theta
        B, keep = _padded_bases(a.bases)  # (n, 6, k_max)
        if se3.exact_joint_screws(a.screws):
            # theta J_l(theta xi) B = theta B + f1 ad(xi) B + f2 ad(xi)^2 B: constant matrices, scalar weights
            X = se3.ad(a.screws)
            E1 = X @ B
            f1, f2 = (f[..., None, None] for f in se3.joint_screw_jacobian_coeffs(a.screws, theta))
            y = theta[..., None, None] * B + f1 * E1 + f2 * (X @ E1)
        else:  # raw twists (e.g. a finite-difference step): the general left Jacobian
            y = theta[..., None, None] * (se3.left_jacobian(a.screws * theta[..., None]) @ B)
        tw = Ad[..., :-1, :, :] @ y  # (N, n, 6, k_max)
        tw = np.moveaxis(tw, -3, -2).reshape(theta.shape[:-1] + (6, -1))
        out["twists"] = tw[..., keep]
    if "home" in parts:
        out["home"] = Ad[..., -1, :, :]
    if "base" in parts:
        out["base"] = np.broadcast_to(np.eye(6), kin.theta.shape[:-1] + (6, 6))
    if "tool" in parts:
        out["tool"] = se3.adjoint(kin.flange)
    return kin, out, jq


def _padded_bases(bases) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint tangent bases (6, k_j) zero-padded to (n, 6, k_max), and the flat indices of real columns."""
    k_max = max(b.shape[1] for b in bases)
    B = np.zeros((len(bases), 6, k_max))
    keep = []
    for j, b in enumerate(bases):
        B[j, :, : b.shape[1]] = b
        keep += [j * k_max + c for c in range(b.shape[1])]
    return B, np.array(keep)


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
    """Rigid T minimizing sum |T src - dst|^2 (Kabsch), points (K, 3)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    U, _, Vt = np.linalg.svd((dst - cd).T @ (src - cs))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    return se3.make(R, cd - R @ cs)
