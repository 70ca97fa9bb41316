"""Shared kernels: an arm's tool pose with its parameter Jacobians, and the gap between two poses or points.

Jacobians of poses are w.r.t. *left (space) increments*: ``T -> exp(d) T`` with d in world coordinates.
"""

from __future__ import annotations

import numpy as np

from kincal.experiments._elastic import add_compliance
from kincal.kinematics import Kinematics, LoadedKinematics
from kincal.lie import se3, so3
from kincal.params import ArmValues

ARM_PARTS = ("offsets", "twists", "home", "base", "tool", "compliance")


def arm_jacobians(a: ArmValues, kin: Kinematics, G: np.ndarray, parts=ARM_PARTS, with_jq: bool = True):
    """``G @ d T_world_tool / d param`` per part (N, k, d), and ``G @ J_q`` (N, k, n) if ``with_jq``.

    ``G`` (N, k, 6) is the residual's derivative w.r.t. the left increment of ``T_world_tool``. Parts: offsets
    (additive), twists (tangent coordinates of ``a.bases``), home/base/tool (``exp(d) T``). Projecting first is
    what makes this fast: ``M_j = G Ad(P_j)`` (N, k, 6) for the prefixes ``P_j = base E_1 .. E_j``, then

    * offset / joint reading j: ``M_{j-1} xi_j``;
    * twist coordinates of joint j: ``(M_{j-1} - M_j) G_j``. The twist basis is ``B_j = -ad(xi_j) G_j`` with
      ``G_j`` the rigid-motion generators of the axis (``a.generators``), and
      ``theta J_l(theta xi) ad(xi) = Ad(exp(theta xi)) - I``, so ``Ad(P_{j-1}) theta J_l(theta xi_j) B_j =
      Ad(P_{j-1}) G_j - Ad(P_j) G_j``: moving a joint axis rigidly inserts the motion before the joint and
      its inverse after it. No per-sample weights, and it holds for raw (unconformed) twists too;
    * home: ``M_n``; base: ``G``; tool: ``G Ad(T_world_flange)``;
    * compliance (``kin`` a ``LoadedKinematics``: the data set applies loads): ``J_q tau``, and every other
      block gets the load torques' own dependence on it (``experiments._elastic``). Without loads the
      compliance block is zero: compliance does not affect the residual.
    """
    N, k = G.shape[:2]
    n = a.dof
    loaded = isinstance(kin, LoadedKinematics) and (with_jq or any(p != "base" for p in parts))
    joints = with_jq or "offsets" in parts or loaded
    twists = "twists" in parts
    idx = [*range(n + 1)] if twists else ([*range(n)] if joints else []) + ([n] if "home" in parts else [])
    out: dict[str, np.ndarray] = {}
    jq = None
    if idx:
        M = _project_prefixes(G, kin.prefixes[:, idx])  # (len(idx), N*k, 6)
    if joints or twists:
        jq = np.moveaxis((M[:n] @ a.screws[:, :, None])[..., 0].reshape(n, N, k), 0, -1)
        if "offsets" in parts:
            out["offsets"] = jq
    if twists:
        Gen, keep = _padded_bases(a.generators)  # (n, 6, t)
        tw = (M[:n] - M[1: n + 1]) @ Gen  # (n, N*k, t): one product per joint
        out["twists"] = np.moveaxis(tw.reshape(n, N, k, -1), 0, 2).reshape(N, k, -1)[..., keep]
    if "home" in parts:
        out["home"] = M[-1].reshape(N, k, 6)
    if "base" in parts:
        out["base"] = G
    if "tool" in parts:
        out["tool"] = G @ se3.adjoint(kin.flange)
    if loaded:
        jq = add_compliance(a, kin, jq, out, parts)
    elif "compliance" in parts:
        out["compliance"] = np.zeros((N, k, n))
    return out, (jq if with_jq else None)


def _project_prefixes(G: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``G Ad(P_j)`` for G (N, k, 6) and poses P (N, m, 4, 4): (m, N*k, 6), with
    ``G Ad(T) = [G_v R, (G_v hat(p) + G_w) R]`` and row-wise ``g^T hat(p) = (g x p)^T``."""
    N, k = G.shape[:2]
    R = np.moveaxis(P[..., :3, :3], 1, 0)  # (m, N, 3, 3)
    p = np.moveaxis(P[..., None, :3, 3], 1, 0)  # (m, N, 1, 3)
    gv, gw = G[..., :3], G[..., 3:]
    x, y, z = gv[..., 0], gv[..., 1], gv[..., 2]
    px, py, pz = p[..., 0], p[..., 1], p[..., 2]
    H = np.empty((P.shape[1], N, k, 3))
    H[..., 0] = y * pz - z * py + gw[..., 0]
    H[..., 1] = z * px - x * pz + gw[..., 1]
    H[..., 2] = x * py - y * px + gw[..., 2]
    M = np.empty((P.shape[1], N, k, 6))
    M[..., :3] = gv @ R
    M[..., 3:] = H @ R
    return M.reshape(P.shape[1], N * k, 6)


def _padded_bases(bases) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint matrices (6, k_j) zero-padded to (n, 6, k_max), and the flat indices of real columns."""
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
