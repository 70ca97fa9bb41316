"""The tool pose's Jacobians w.r.t. every arm parameter, projected through the residual's derivative.

``tool_jacobians`` is the one Jacobian of ``T_world_tool`` that calibration uses (experiments' residuals,
predicted accuracy). Poses are differentiated w.r.t. *left (space) increments*: ``T -> exp(d) T`` with d in
world coordinates. Parameters, per part:

* ``offsets``: additive, ``theta = q + o``;
* ``twists``: tangent coordinates of each joint screw, moving the axis rigidly by ``exp(G_j d)`` with ``G_j``
  the axis' rigid-motion generators (``kincal.kinematics.tangent_generators``);
* ``home``, ``base``, ``tool``: left increments ``exp(d) T``;
* ``compliance``: joint compliances, with the load torques' own dependence on the geometry (below).

The thesis' closed form (He et al. 2010, additive twist coordinates) is a baseline and lives in
``kincal.baselines.identification``.

Compliance (``kin`` a ``LoadedKinematics``): with ``theta = theta0 + c * tau(p, theta0)`` and ``Jq = G dT/dtheta``
at the deflected theta, the compliance block is ``Jq[..., i] tau_i`` and every other part p (and the joint
readings) gets ``Jq (dtheta0/dp + c * dtau/dp)``. A parameter acts as a world twist ``zeta`` inserted at some
position k of the chain (after the prefix ``P_k``); it moves the axes after it and the tool, so
``dtau_i = [i <= k] h_i . zeta`` with ``h_i = F_s^T ad(xi_s_i)``: only the axes the parameter does not carry see
the load turn. Offset j inserts ``xi_s_j`` at k = j (0-based: rows i < j), a twist tangent ``+Ad(P_j) G_j``
before joint j and ``-Ad(P_{j+1}) G_j`` after it, home ``Ad(P_n)`` and tool ``Ad(T_world_flange)`` after every
joint; the base moves everything (no change). The arm's own weight does not turn with the arm: its torques'
derivatives (the base's too) are in ``kincal.kinematics.gravity``.

Angle-dependent compliance (``kincal.kinematics.elastic``): with ``c(q) = W(q) k`` the block is w.r.t. the
coefficients k, ``sum_i Jq[..., i] tau_i W[i, :]``, and a joint reading also moves its own compliance:
``dtheta_j/dq_j`` gains ``(S k)_j tau_j`` (``S = dW/dq_j``, zero beyond the end nodes).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from kincal.kinematics.elastic import LoadedKinematics, compliance_columns, deflection_map
from kincal.kinematics.fk import Kinematics, powers
from kincal.kinematics.gravity import _Projected, gravity_torque_derivatives
from kincal.lie import se3

TOOL_PARTS = ("offsets", "twists", "home", "base", "tool", "compliance")
_CORRECTED = ("offsets", "twists", "home", "tool")  # the parts whose load torques depend on them


def tool_jacobians(kin: Kinematics, G: np.ndarray, screws: np.ndarray, generators: Sequence[np.ndarray],
                   compliance: np.ndarray | None = None, parts: Sequence[str] = TOOL_PARTS,
                   with_jq: bool = True, basis: tuple[np.ndarray, np.ndarray] | None = None, step: int = 1,
                   projected: np.ndarray | None = None) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    """``G @ d T_world_tool / d param`` per part (N, k, d), and ``G @ J_q`` (N, k, n) if ``with_jq``.

    ``kin``: the chain at the data's joint values (``chain`` or ``loaded_chain``); ``G`` (N, k, 6): the residual's
    derivative w.r.t. the left increment of ``T_world_tool`` (identity (N, 6, 6) for the pose itself);
    ``screws`` (n, 6) and ``generators`` (per joint (6, k_j)): the joint twists and their rigid-motion generators;
    ``compliance`` (n,): joint compliances (None: zero), or with ``basis = (W, S)`` (``elastic.compliance_basis``
    at the readings) the compliance coefficients (p,). Projecting first is what makes this fast:
    ``M_j = G Ad(P_j)`` (N, k, 6) for the prefixes ``P_j = base E_1 .. E_j``, then

    * offset / joint reading j: ``M_{j-1} xi_j``;
    * twist coordinates of joint j: ``(M_{j-1} - M_j) G_j``, since ``theta J_l(theta xi) ad(xi) = Ad(exp(theta xi))
      - I``: moving a joint axis rigidly inserts the motion before the joint and its inverse after it (no
      per-sample weights; it holds for raw, unconformed twists too);
    * home: ``M_n``; base: ``G``; tool: ``G Ad(T_world_flange)``;
    * compliance: see the module docstring; without loads the compliance block is zero.

    ``step``: the chain's joints come in groups of ``step`` consecutive screws (``kincal.kinematics.lateral``'s
    expanded chain: a joint and its two lateral axes), ``generators`` one per group moving all its screws, and
    offsets and readings are the groups' first joints': the twist columns are then ``(M_a - M_b) G_j`` over the
    group ``[a, b)`` (the group's per-screw columns summed) and ``G @ J_q`` (N, k, n / step). Compliance stays
    per screw. ``projected``: ``prefix_projections(kin, G)`` when the caller has them.
    """
    N, k = G.shape[:2]
    n = screws.shape[0]
    loaded = isinstance(kin, LoadedKinematics) and (with_jq or any(p != "base" for p in parts)
                                                     or kin.gravity is not None)  # weights: the base matters
    joints = with_jq or "offsets" in parts or loaded
    twists = "twists" in parts
    out: dict[str, np.ndarray] = {}
    jq = None
    if projected is None and (joints or twists):
        projected = prefix_projections(kin, G)  # readings, twists and home at once
    if projected is not None:
        jq = _along_screws(projected[:n], screws, N, k)
        home = projected[n]
    elif "home" in parts:
        home = _project_prefixes(G, kin.prefixes[:, [n]])[0]
    if "offsets" in parts:
        out["offsets"] = jq[..., ::step]
    if twists:
        out["twists"] = _twist_columns(projected, generators, step, N, k)
    if "home" in parts:
        out["home"] = home.reshape(N, k, 6)
    if "base" in parts:
        out["base"] = G
    if "tool" in parts:
        out["tool"] = G @ se3.adjoint(kin.flange)
    if loaded:
        jq = _add_compliance(kin, generators, _coefficients(compliance, n), basis, jq, out, parts, step)
        return out, (jq if with_jq else None)
    if "compliance" in parts:
        out["compliance"] = np.zeros((N, k, len(_coefficients(compliance, n))))
    return out, (jq[..., ::step] if with_jq else None)


def _coefficients(compliance, n: int) -> np.ndarray:
    """``tool_jacobians``' compliance coefficients: zeros (n,) for None (read only where a block needs them)."""
    return np.zeros(n) if compliance is None else np.asarray(compliance, float)


def torque_derivatives(kin: LoadedKinematics, generators: Sequence[np.ndarray], parts, step: int = 1,
                       C: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """``dtau/dp`` (N, n, d) for the parts in ``parts`` among offsets, twists, home, tool (unloaded chain); with
    weights (``kincal.kinematics.gravity``) also base. ``step``: joints in groups (``tool_jacobians``); ``C``
    (N, k, n): ``C @ dtau/dp`` instead."""
    if kin.gravity is not None:
        return gravity_torque_derivatives(kin, generators, parts, step, C)
    if C is not None:
        return {p: C @ D for p, D in torque_derivatives(kin, generators, parts, step).items()}
    k0 = kin.unloaded
    n = kin.axes.shape[1]
    H = np.einsum("Ni,Nkij->Nkj", kin.wrench_space, se3.ad(kin.axes))  # (N, n, 6): h_i
    out = {}
    rows = np.arange(n)
    if "offsets" in parts:
        out["offsets"] = np.einsum("Nik,Njk->Nij", H, kin.axes[:, ::step]) * (rows[:, None] < rows[None, ::step])
    Ad = se3.adjoint(k0.prefixes) if ("twists" in parts or "home" in parts) else None
    if "twists" in parts:
        cols = []
        for j, Gj in enumerate(generators):  # loop over joints, batched over samples
            a, b = step * j, step * (j + 1)  # the group's screws
            before = H * (rows < a)[None, :, None]
            upto = H * (rows < b)[None, :, None]
            cols.append(before @ (Ad[:, a] @ Gj) - upto @ (Ad[:, b] @ Gj))
        out["twists"] = np.concatenate(cols, axis=-1)
    if "home" in parts:
        out["home"] = H @ Ad[:, n]
    if "tool" in parts:
        out["tool"] = H @ se3.adjoint(k0.flange)
    return out


def insertion_jacobians(kin: Kinematics, G: np.ndarray, screws: np.ndarray, at, compliance=None,
                        basis=None, moved=None, projected=None) -> list[np.ndarray]:
    """``G @ d T_world_tool / d X_i`` (N, k, 6) per rigid transform ``X_i`` inserted in the chain: ``at`` lists
    (m, F) with the transform at ``P_m F`` (prefix after m joints, F a constant), perturbed on the left there
    (``F -> exp(d) F``, as ``home`` is at m = n). Under a load the torques of the joints before the insertion
    change too (``insertion_torques``); ``compliance``/``basis`` as in ``tool_jacobians``; ``moved`` (per
    insertion, a sequence of hung weights ``(m, mass, moment)`` it moves, ``kincal.kinematics.branches``);
    ``projected``: ``prefix_projections(kin, G)`` when the caller has them."""
    N, k = G.shape[:2]
    P = np.stack([kin.prefixes[:, m] @ F for m, F in at], axis=1)
    out = list(_project_prefixes(G, P).reshape(len(at), N, k, 6))
    if not isinstance(kin, LoadedKinematics) or compliance is None:
        return out
    c = compliance if basis is None else basis[0] @ compliance
    if not np.any(c):
        return out
    cjq = deflection_map(joint_jacobian(kin, G, screws, projected), c, kin.coupling)
    moved = moved or [()] * len(at)
    if kin.gravity is not None:  # the weights' projection once for every insertion
        cjq = kin.inserter.project(cjq)
    return [J + insertion_torques(kin, m, F, w, cjq) for J, (m, F), w in zip(out, at, moved)]


def joint_jacobian(kin: Kinematics, G: np.ndarray, screws: np.ndarray, projected: np.ndarray | None = None
                   ) -> np.ndarray:
    """``G dT/dtheta`` (N, k, n) at the chain's joint values (deflected ones for a loaded chain); ``projected``:
    ``prefix_projections(kin, G)`` when the caller has them."""
    n = screws.shape[0]
    M = _project_prefixes(G, kin.prefixes[:, :n]) if projected is None else projected[:n]
    return _along_screws(M, screws, *G.shape[:2])


def prefix_projections(kin: Kinematics, G: np.ndarray) -> np.ndarray:
    """``G Ad(P_j)`` (n + 1, N*k, 6) for every prefix of the chain: what its Jacobians share. Exact joint screws
    go joint by joint through each sample's joint adjoint (``_sample_projections``), other twists and loaded
    chains (whose numbers stay those of the products of exponentials, ``fk.chain``) project every prefix."""
    if (G.ndim == 3 and kin.theta.shape == G.shape[:1] + kin.screws.shape[:1] and not isinstance(kin, LoadedKinematics)
            and se3.exact_joint_screws(kin.screws)):
        return _sample_projections(kin, G)
    return _project_prefixes(G, kin.prefixes)


def _sample_projections(kin: Kinematics, G: np.ndarray) -> np.ndarray:
    """``prefix_projections`` of exact joint screws: ``G Ad(P_{i+1}) = (G Ad(P_i)) Ad(exp(xi_i t))`` with
    ``Ad(exp(xi t)) = I + a ad(xi) + b ad(xi)^2`` (``Kinematics.coefficients``; every joint and sample in one
    product), then one product per joint over all samples; a joint at zero in every sample is the identity.
    The numbers of the joint frames' projections (``G Ad(P_i) Ad(C_i) Ad(Z_i) Ad(C_i^-1)``, two products and a turn
    per joint, what it replaced) to round-off."""
    N, k = G.shape[:2]
    n = kin.theta.shape[1]
    A = (kin.unit_coefficients @ powers(kin.screws, _AD_BASIS, unit=True)).reshape(n, N, 6, 6)  # I + a ad + b ad^2
    M = np.empty((n + 1, N, k, 6))
    if kin.one_base is not None:  # one base for every sample (a chain's own): one 2-d product
        np.matmul(G.reshape(N * k, 6), se3.remembered(se3.adjoint, kin.one_base), out=M[0].reshape(N * k, 6))
    else:
        M[0] = _project_prefixes(G, kin.prefixes[:, :1])[0].reshape(N, k, 6)
    moves = kin.moves
    for i in range(n):
        if moves[i]:
            np.matmul(M[i], A[i], out=M[i + 1])
        else:
            M[i + 1] = M[i]
    return M.reshape(n + 1, N * k, 6)


_AD_BASIS = se3.ad(np.eye(6)).reshape(6, 36)  # ad of the unit twists: ad(xi) = xi @ _AD_BASIS


def _twist_columns(M: np.ndarray, generators, step: int, N: int, k: int) -> np.ndarray:
    """``(M_a - M_b) G_j`` (N, k, sum of the k_j) for the joints' groups ``[a, b)`` of ``step`` screws, written
    joint by joint into the result's columns; joints of one width (an arm of one joint type) in one product."""
    widths = {g.shape[1] for g in generators}
    if len(widths) == 1:
        n, t = len(generators), widths.pop()
        D = M[0: step * n: step] - M[step: step * (n + 1): step]  # (n, N*k, 6)
        out = np.empty((N, k, n * t))  # the product written in place in the result's columns: no transposed copy
        np.matmul(D, np.array(generators), out=out.reshape(N * k, n, t).transpose(1, 0, 2))
        return out
    out = np.empty((N, k, sum(g.shape[1] for g in generators)))
    c = 0
    for j, Gj in enumerate(generators):
        a, t = step * j, Gj.shape[1]
        out[:, :, c: c + t] = ((M[a] - M[a + step]) @ Gj).reshape(N, k, t)
        c += t
    return out


def _along_screws(M: np.ndarray, screws: np.ndarray, N: int, k: int) -> np.ndarray:
    """``M_j xi_j`` (N, k, n) for projected prefixes M (n, N*k, 6) (``_project_prefixes``)."""
    return (M @ screws[:, :, None])[..., 0].reshape(len(screws), N, k).transpose(1, 2, 0)


def insertion_torques(kin: LoadedKinematics, m: int, F: np.ndarray, moved=(), C: np.ndarray | None = None
                      ) -> np.ndarray:
    """``dtau/dd`` (N, n, 6) for a rigid transform at ``P_m F`` of the unloaded chain moved by ``exp(d)``: the
    joints after it move with the tool (no change), those before it see the load turn (``h_i Ad(P_m F)``);
    with weights (``kincal.kinematics.gravity``) the links from m on move too, and the hung weights ``moved``.
    ``C`` (N, k, n): ``C @ dtau/dd`` (N, k, 6) instead (with weights, C may be ``kin.inserter.project(C)``)."""
    Z = se3.adjoint(kin.unloaded.prefixes[:, m] @ F)
    if kin.gravity is not None:
        ins = C if isinstance(C, _Projected) else kin.inserter.project(C)
        return ins.columns(m, m, Z) + sum((ins.moved_weight(mb, mass, S, Z) for mb, mass, S in moved), 0.0)
    else:
        H = np.einsum("Ni,Nkij->Nkj", kin.wrench_space, se3.ad(kin.axes))  # (N, n, 6): h_i
        D = (H * (np.arange(H.shape[1]) < m)[None, :, None]) @ Z
    return D if C is None else C @ D


def _add_compliance(kin: LoadedKinematics, generators, k_c: np.ndarray, basis, jq: np.ndarray, out: dict,
                    parts, step: int = 1) -> np.ndarray:
    """Add the compliance block and the ``c * dtau/dp`` terms to ``out`` (in place); returns the corrected
    derivative w.r.t. the joint readings (the groups' first joints, ``tool_jacobians``). ``jq`` (N, k, n):
    ``G dT/dtheta`` at the deflected theta."""
    jt = compliance_columns(jq, kin.tau, kin.coupling)
    if "compliance" in parts:
        out["compliance"] = jt if basis is None else jt @ basis[0]
    corrected = _CORRECTED + (("base",) if kin.gravity is not None else ())
    want = [p for p in corrected if p in parts] + ([] if "offsets" in parts else ["offsets"])
    c = k_c if basis is None else basis[0] @ k_c  # (n,) or per sample (N, n)
    if not np.any(c):
        return jq[..., ::step]
    cjq = deflection_map(jq, c, kin.coupling)
    D = torque_derivatives(kin, generators, want, step, cjq)
    for p in corrected:
        if p in parts:
            out[p] = out[p] + D[p]
    own = 0.0 if basis is None else (jt * (basis[1] @ k_c)[:, None, :])[..., ::step]  # a reading moves its compliance
    return jq[..., ::step] + D["offsets"] + own


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
