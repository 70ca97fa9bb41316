"""Shared kernels: an arm's tool-pose Jacobians at its current values, and the gap between two poses or points.

Jacobians of poses are w.r.t. *left (space) increments*: ``T -> exp(d) T`` with d in world coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kincal._validate import det3
from kincal.kinematics import Kinematics
from kincal.kinematics.branches import branch_torque_derivatives, loaded_tree
from kincal.kinematics.elastic import LoadedKinematics, deflection_map
from kincal.kinematics.jacobians import (TOOL_PARTS, insertion_jacobians, joint_jacobian, prefix_projections,
                                         tool_jacobians)
from kincal.kinematics.lateral import (chain_lateral, expand_basis, expand_screws, expand_values, lateral_columns,
                                      real_columns)
from kincal.kinematics.tree import composite, insertion_points
from kincal.lie import se3, so3
from kincal.params import ArmValues

ARM_PARTS = TOOL_PARTS + ("lateral",)
BRANCH_PARTS = ("offsets", "twists", "home", "base", "tool")  # another branch's parts its weight depends on


def arm_jacobians(a: ArmValues, kin: Kinematics, G: np.ndarray, parts=ARM_PARTS, with_jq: bool = True, q=None):
    """``kincal.kinematics.tool_jacobians`` for one arm's current values ``a``: ``G @ d T_world_tool / d param``
    per part (N, k, d), and ``G @ J_q`` (N, k, n) if ``with_jq``; ``q`` (N, n): the readings, which an
    angle-dependent compliance needs (``ArmValues.compliance_basis``)."""
    basis = None if q is None else a.compliance_basis(q)
    # ``a.compliance`` None is ``joint_compliance``'s zeros there, made only where a block reads them
    return tool_jacobians(kin, G, a.screws, a.generators, a.compliance, parts, with_jq, basis)


def coupled(a: ArmValues, gq: np.ndarray) -> np.ndarray:
    """``G @ J_q`` w.r.t. the arm's free readings: through its couplings (coupled joints' columns zero)."""
    return gq if a.coupling is None else gq @ a.coupling


def tree_kin(state, line, q, w=None) -> Kinematics:
    """Kinematics of the composite chain of the arms ``line`` (root first, ``kincal.kinematics.tree``) at readings
    ``q`` (arm -> (N, n)), deflected by the tool loads ``w`` (N, 6) if given and by the weights of the tree
    (``kincal.kinematics.branches``: every segment's links, the tip's payload, the other branches' weights)."""
    return loaded_tree(state.arms, {a: v.weights for a, v in state.arms.items()},
                       {s: state.arms[s].compliance_at(q[s]) for s in line}, state.mounts, line, q, w)


def _tree_compliance(segs, qs):
    """The composite chain's compliance coefficients and basis (block diagonal; None when no joint has nodes)."""
    coeffs = np.concatenate([a.joint_compliance for a in segs])
    if not any(a.compliance_nodes for a in segs):
        return coeffs, None
    N = len(qs[0])
    parts = [a.compliance_basis(q) or (np.broadcast_to(np.eye(a.dof), (N, a.dof, a.dof)), np.zeros((N, a.dof, a.dof)))
             for a, q in zip(segs, qs)]
    W = np.zeros((N, sum(a.dof for a in segs), len(coeffs)))
    S = np.zeros_like(W)
    r = c = 0
    for Wk, Sk in parts:
        W[:, r: r + Wk.shape[1], c: c + Wk.shape[2]] = Wk
        S[:, r: r + Wk.shape[1], c: c + Wk.shape[2]] = Sk
        r, c = r + Wk.shape[1], c + Wk.shape[2]
    return coeffs, (W, S)


def _add(out: dict, key: str, J: np.ndarray) -> None:
    out[key] = out[key] + J if key in out else J


@dataclass(frozen=True)
class _Chain:
    """The chain the Jacobians run on: the composite's own, or its expanded chain when the tip is loaded and some
    segment has lateral compliance (``kincal.kinematics.lateral``: ``step`` 3 joints per joint). ``coeffs`` and
    ``basis``: its compliance coefficients (joints' then, expanded with nodes, the lateral ones) and basis."""

    screws: np.ndarray
    coeffs: np.ndarray
    basis: tuple | None
    step: int
    lateral: tuple | None  # (axes, compliances) of the composite, None when no segment has lateral compliance


def _chain(segs, comp, kin, q) -> _Chain:
    coeffs, basis = _tree_compliance(segs, q)
    lat = chain_lateral(segs, comp.frames)
    if lat is None or not isinstance(kin, LoadedKinematics):
        return _Chain(comp.screws, coeffs, basis, 1, lat)
    screws = expand_screws(comp.screws, lat[0])
    if basis is None:
        return _Chain(screws, expand_values(coeffs, lat[1]), None, 3, lat)
    n = comp.screws.shape[0]
    return _Chain(screws, np.concatenate([coeffs, lat[1].ravel()]), expand_basis(basis, n, len(q[0])), 3, lat)


def _split_compliance(ch: _Chain, blocks: dict) -> None:
    """The expanded chain's compliance block split into the joints' and the lateral ones (in place; offsets,
    readings and twists come per joint from ``tool_jacobians``' ``step``)."""
    if ch.step == 1 or "compliance" not in blocks:
        return
    J = blocks["compliance"]
    p = len(ch.coeffs) - 2 * len(ch.lateral[1])
    blocks["compliance"], blocks["lateral"] = ((real_columns(J), lateral_columns(J)) if ch.basis is None
                                               else (J[..., :p], J[..., p:]))


def tree_jacobians(state, line, q, kin, G, parts, jq: bool, out: dict, jqs: dict) -> None:
    """Blocks of every arm of ``line`` (root first; ``parts[arm]``: the wanted parts) for the tip's left
    increment derivative G at readings ``q`` (arm -> (N, n)), added to ``out``; ``G @ J_q`` per arm added to
    ``jqs`` (if ``jq``). Under gravity, the other arms whose weight loads the lineage (``parts`` may list
    them) add their blocks and readings too. Lateral compliance runs on the expanded chain (``_Chain``)."""
    segs = [state.arms[s] for s in line]
    comp = composite(segs)
    ch = _chain(segs, comp, kin, [q[s] for s in line])
    branches = kin.branches if isinstance(kin, LoadedKinematics) else ()  # weighed once, by tree_kin
    wanted = set().union(*(parts.get(s, ()) for s in line))
    cparts = [p for p in ("offsets", "twists") if p in wanted] + ["compliance"] * bool({"compliance", "lateral"} & wanted)
    cparts += ["base"] * ("base" in parts[line[0]])
    if not branches:  # else the tip's home and tool are insertions too, which may move weights hung at n
        cparts += [p for p in ("home", "tool") if p in parts[line[-1]]]
    gens = comp.generators([a.generators for a in segs])
    M = prefix_projections(kin, G)  # shared by the chain's blocks, its insertions and branches
    blocks, gq = tool_jacobians(kin, G, ch.screws, gens, ch.coeffs, cparts, jq, ch.basis, ch.step, M)
    _split_compliance(ch, blocks)
    _lateral_blocks(ch, segs, line, parts, blocks, G, out)
    widths = {"offsets": None, "twists": [sum(g.shape[1] for g in a.generators) for a in segs],
              "compliance": [len(a.joint_compliance) for a in segs]}
    for p, w in widths.items():
        if p in blocks:
            for s, J in zip(line, comp.split(blocks[p], w)):
                if p in parts[s]:
                    _add(out, f"{s}.{p}", J)
    if "base" in blocks:
        _add(out, f"{line[0]}.base", blocks["base"])
    if "tool" in blocks:
        _add(out, f"{line[-1]}.tool", blocks["tool"])
    if "home" in blocks:
        _add(out, f"{line[-1]}.home", blocks["home"] @ se3.adjoint(comp.frames[-1]))
    _insertions(kin, G, comp, segs, line, parts, ch, branches, M, out)
    if jq:
        for s, a, J in zip(line, segs, comp.split(gq)):
            _add(jqs, s, coupled(a, J))
    if branches:
        _branch_blocks(state, ch, branches, parts, jq, joint_jacobian(kin, G, ch.screws, M), kin, out, jqs)


def _lateral_blocks(ch: _Chain, segs, line, parts, blocks, G, out) -> None:
    """Each segment's lateral block (zero when nothing loads the chain)."""
    if ch.lateral is None:
        return
    J = blocks.get("lateral")
    if J is None:
        J = np.zeros(G.shape[:2] + (2 * len(ch.lateral[1]),))
    for s, a, Js in zip(line, segs, np.split(J, 2 * np.cumsum([a.dof for a in segs])[:-1], axis=-1)):
        if a.lateral is not None and "lateral" in parts[s]:
            _add(out, f"{s}.lateral", Js)


def _insertions(kin, G, comp, segs, line, parts, ch, branches, projected, out) -> None:
    """The blocks of the rigid transforms inside the composite chain (``tree.insertion_points``; with branches
    the tip's home and tool too), each with the hung weights it carries (segment index <= the branch's)."""
    pts = insertion_points(comp, segs)
    if branches:
        K, n = len(segs) - 1, int(comp.starts[-1])
        pts += [(K, "home", n, comp.frames[-1]), (K, "tool", n, comp.frames[-1] @ segs[-1].home)]
    pts = [(k, p, m, X) for k, p, m, X in pts if p in parts[line[k]]]
    if not pts:
        return
    x = ch.step
    moved = [[(x * b.m, *b.hung[1:]) for b in branches if b.m == m and k <= b.k] for k, _, m, _ in pts]
    Js = insertion_jacobians(kin, G, ch.screws, [(x * m, X) for _, _, m, X in pts], ch.coeffs, ch.basis, moved,
                             projected)
    for (k, p, _, _), J in zip(pts, Js):
        _add(out, f"{line[k]}.{p}", J)


def _branch_blocks(state, ch, branches, parts, jq, dtheta, kin, out, jqs) -> None:
    """The blocks and readings of the other arms whose weight loads the lineage (through the carriers'
    deflection; ``kincal.kinematics.branches``); ``dtheta``: ``G dT/dtheta`` of the chain."""
    c = ch.coeffs if ch.basis is None else ch.basis[0] @ ch.coeffs
    cjq = deflection_map(dtheta, c, kin.coupling)
    for b in branches:
        a = state.arms[b.arm]
        want = [p for p in parts.get(b.arm, ()) if p in BRANCH_PARTS] + ["readings"] * jq
        if not want:
            continue
        m = ch.step * b.m
        D = branch_torque_derivatives(kin.axes[:, :m], kin.gravity, b, a.generators, a.base, want, cjq[..., :m])
        for p, J in D.items():
            if p not in want:
                continue
            if p == "readings":
                _add(jqs, b.arm, coupled(a, J))
            else:
                _add(out, f"{b.arm}.{p}", J)


def pose_gap(TA: np.ndarray, TB: np.ndarray, of_b: bool = True, jacobians: bool = True):
    """r = [p_A - p_B, log(R_A R_B^T)] (N, 6) in world coordinates, and dr/d(left increment) of A and of B
    (None with ``of_b`` False: a fixed B, the measured pose; both None with ``jacobians`` False)."""
    pA, pB = TA[..., :3, 3], TB[..., :3, 3]
    E = TA[..., :3, :3] @ np.swapaxes(TB[..., :3, :3], -1, -2)
    rw = so3.log(E)
    if not jacobians:
        return np.concatenate([pA - pB, rw], axis=-1), None, None
    Ji = so3.left_jacobian_inv(rw)
    shape = TA.shape[:-2]
    GA = np.zeros(shape + (6, 6))
    GA[..., :3, :3] = np.eye(3)
    GA[..., :3, 3:] = -so3.hat(pA)
    GA[..., 3:, 3:] = Ji
    GB = None
    if of_b:
        GB = np.zeros(shape + (6, 6))
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
    r, G, _ = pose_gap(Bi @ TA, np.eye(4), of_b=False)
    G = G @ se3.adjoint(Bi)
    return r, G, -G


def point_jacobian(p: np.ndarray) -> np.ndarray:
    """d p / d(left increment of the frame carrying p): [I, -hat(p)], (..., 3, 6); each entry taken from the
    point, its negation or a constant (``-hat``'s diagonal is -0.0, as negating ``so3.hat`` gives)."""
    p = np.asarray(p, dtype=float)
    flat = p.reshape(-1, 3)
    terms = np.empty((9, len(flat)))  # rows p, -p, then the constants 0.0, 1.0, -0.0: each entry one whole row
    terms[:3] = flat.T
    np.negative(terms[:3], out=terms[3:6])
    terms[6:] = _POINT_CONSTANTS[:, None]
    return np.ascontiguousarray(terms.take(_POINT_TAKE, axis=0).T).reshape(p.shape[:-1] + (3, 6))


# [I, -hat(p)] flattened row by row (3 x 6) as indices into ``terms`` (p_0..p_2, -p_0..-p_2, 0.0, 1.0, -0.0):
# -hat(p) = [[-0, z, -y], [-z, -0, x], [y, -x, -0]].
_POINT_CONSTANTS = np.array([0.0, 1.0, -0.0])
_POINT_TAKE = np.array([7, 6, 6, 8, 2, 4,
                        6, 7, 6, 5, 8, 0,
                        6, 6, 7, 1, 3, 8])


def _det_sign(Q: np.ndarray) -> np.ndarray:
    """``np.sign(np.linalg.det(Q))`` of orthogonal matrices (determinant +-1, far from zero: any rounding gives
    the same sign); one 3 x 3 by its triple product on Python floats."""
    return np.sign(np.linalg.det(Q)) if Q.shape != (3, 3) else np.sign(np.float64(det3(Q)))


def pose_mean(T: np.ndarray) -> np.ndarray:
    """A rigid transform near the mean of T (N, 4, 4): two Gauss-Newton steps of the left log-average."""
    M = T[0]
    for _ in range(2):
        M = se3.exp(np.mean(se3.log(T @ se3.inverse(M)), axis=0)) @ M
    return M


def fit_transform(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rigid T minimizing sum |T src - dst|^2 (Kabsch): points (..., K, 3), batches broadcast (one layout
    against many rows of measured points), -> (..., 4, 4)."""
    if src.ndim == 2 and src.shape == dst.shape:
        return _fit_one(src, dst)
    if src.shape != dst.shape:
        src, dst = np.broadcast_arrays(src, dst)
    K = src.shape[-2]
    cs, cd = np.add.reduce(src, axis=-2) / K, np.add.reduce(dst, axis=-2) / K  # ``mean``'s sum and division
    U, _, Vt = np.linalg.svd((dst - cd[..., None, :]).swapaxes(-1, -2) @ (src - cs[..., None, :]))
    R = U @ Vt
    sign = _det_sign(R)
    if U.ndim > 2 or sign != 1:  # a proper rotation even for a reflected best fit (one proper already: x * 1 is x)
        U[..., :, 2] *= sign[..., None]
        R = U @ Vt
    return se3.make(R, cd - np.einsum("...ij,...j->...i", R, cs))


def _fit_one(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """``fit_transform`` of one set of points (K, 3): the same operations without the batch axes' handling."""
    # both sets side by side (K, 6): one sum and one subtraction (a sum over rows adds row by row either way)
    X = np.concatenate((dst, src), axis=1)
    c = np.add.reduce(X, axis=0) / len(X)
    X -= c
    cd, cs = c[:3], c[3:]
    U, _, Vt = np.linalg.svd(X[:, :3].T @ X[:, 3:])
    R = U @ Vt
    d = det3(R)
    if not d > 0:  # a reflected best fit (or nan): ``np.sign`` as the batch path
        U[:, 2] *= np.sign(np.float64(d))
        R = U @ Vt
    T = np.zeros((4, 4))
    T[:3, :3] = R
    T[:3, 3] = cd - np.einsum("ij,j->i", R, cs)
    T[3, 3] = 1.0
    return T
