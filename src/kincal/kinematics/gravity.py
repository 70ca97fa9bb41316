"""Joint torques from the arm's own weight (a mass model), and their exact derivatives w.r.t. the geometry.

Link j (the body moved by joint j) has mass ``m_j`` and centre of mass ``c_j^0`` in the arm base frame at
q = 0, so at the unloaded configuration ``theta0`` its centre of mass is ``c_j = P_{j+1} c_j^0`` (``P_k`` the
chain prefixes, ``P_0 = base``); a payload ``m_p`` at ``c_p`` in the tool frame sits at ``T_world_tool c_p``.
Its weight is the world-fixed force ``f_j = m_j g`` (``g`` the gravity vector in the world frame) acting at
``c_j``: the spatial wrench ``(f_j, c_j x f_j)``, applied TO the robot like the tool loads of
``kincal.kinematics.elastic``. Joint i carries everything beyond it, so with the mass beyond ``M_l = sum_{j >= l}
m_j + m_p`` and its first moment ``S_l = sum_{j >= l} m_j c_j + m_p c_p`` (world)::

    tau_i = xi_s_i . (W_i + F_s),    W_l = (M_l g, S_l x g)

(``F_s``: a tool load given by the data, as a spatial wrench). Deflection is first order at ``theta0`` as in
``elastic``: ``theta = theta0 + c tau``.

Derivatives. A parameter acts as a world twist ``zeta = (v, w)`` inserted in the chain: it moves rigidly the
axes from some index ``a`` on and the links (centres of mass) from some index ``l`` on, and always the payload
and the tool load. Unlike a tool load, the weights do not turn with the arm: a moved weight changes by the
rigid motion *minus* the turn of its force, ``-ad(zeta)^T F - (w x f, c x (w x f))``. Hence

* a moved axis i (i >= a), which carries all it transmits: ``dtau_i = Q_{i,i} . zeta``;
* an unmoved axis i (i < a): ``dtau_i = (ad(xi_s_i)^T (W_l + F_s) + Q_{i,l}) . zeta``

with ``Q_{i,l} = (0, M_l v_i x g + (w_i x S_l) x g)`` (``xi_s_i = (v_i, w_i)``). Offset j inserts ``xi_s_j`` with
(a, l) = (j + 1, j); twist j inserts ``Ad(P_j) G_j`` at (j, j) and ``-Ad(P_{j+1}) G_j`` at (j + 1, j); home
``Ad(P_n)`` and tool ``Ad(T_world_flange)`` at (n, n) (payload and tool load only); the base ``I`` at (0, 0):
the base now matters, as it turns the arm relative to gravity. Without masses this reduces to ``elastic``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kincal.kinematics.model import ArmModel
from kincal.lie import se3, so3


@dataclass(frozen=True)
class GravityLoad:
    """An arm's weights: ``masses`` (n,) kg, ``coms`` (n, 3) m (arm base frame at q = 0), the payload's
    ``payload_mass`` kg and ``payload_com`` (3,) (tool frame), and ``g`` (3,) m/s^2 (world frame)."""

    masses: np.ndarray
    coms: np.ndarray
    payload_mass: float
    payload_com: np.ndarray
    g: np.ndarray


def gravity_load(model: ArmModel) -> GravityLoad | None:
    """The model's weights, or None when gravity loads nothing (no gravity vector or no mass)."""
    if not model.has_gravity_load:
        return None
    return GravityLoad(model.link_masses, model.link_coms, model.payload_mass, model.payload_com, model.gravity)


def mass_beyond(load: GravityLoad, prefixes: np.ndarray, tool: np.ndarray, hung=()) -> tuple[np.ndarray, np.ndarray]:
    """``M_l`` (n + 1,) and ``S_l`` (..., n + 1, 3) for l = 0..n, from the chain's ``prefixes`` (..., n + 1, 4, 4)
    and ``T_world_tool`` (..., 4, 4); index n holds the payload alone. ``hung``: (m, mass, first moment (..., 3)
    world) of weights carried by link m - 1 beyond the chain (other branches of a tree), m > 0."""
    P = prefixes[..., 1:, :, :]
    c = np.einsum("...kij,kj->...ki", P[..., :3, :3], load.coms) + P[..., :3, 3]  # (..., n, 3) link centres
    cp = tool[..., :3, :3] @ load.payload_com + tool[..., :3, 3]  # (..., 3) payload centre
    moments = np.concatenate([c * load.masses[:, None], (load.payload_mass * cp)[..., None, :]], axis=-2)
    masses = np.append(load.masses, load.payload_mass)
    for m, mass, moment in hung:
        moments = np.broadcast_to(moments, np.broadcast_shapes(moments.shape, moment.shape[:-1] + (1, 3))).copy()
        moments[..., m - 1, :] += moment
        masses[m - 1] += mass
    S = np.flip(np.cumsum(np.flip(moments, -2), axis=-2), -2)
    M = np.flip(np.cumsum(np.flip(masses)))
    return M, S


def weight_wrenches(M: np.ndarray, S: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``W_l = (M_l g, S_l x g)`` (..., n + 1, 6): the weight beyond each joint as a spatial wrench."""
    return np.concatenate([np.broadcast_to(M[:, None] * g, S.shape), np.cross(S, g)], axis=-1)


def _q_rows(axes: np.ndarray, M, S: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``Q = (0, M v x g + (w x S) x g)`` (N, k, 6) for axes (N, k, 6) against the weight (M, S) beyond."""
    v, w = axes[..., :3], axes[..., 3:]
    M = np.asarray(M, dtype=float)
    out = np.zeros(axes.shape)
    out[..., 3:] = so3.cross(M[..., None] * v + so3.cross(w, S), g)
    return out


class _Inserter:
    """``dtau/dp`` for world twists inserted in the chain (module docstring), on the unloaded pass ``kin``.

    Batched over inserted twists (columns): an unmoved axis' row ``ad(xi_i)^T W_l + Q_{i,l}`` equals (Jacobi
    identity, ``W_l = (M_l g, S_l x g) + F_s``) ``(M_l u_i, S_l x u_i) + ad(xi_i)^T F_s`` with ``u_i = g x w_i``,
    so against a twist ``z = (z_v, z_w)`` it is ``r_i . [M_l z_v + z_w x S_l, z]`` with ``r_i = [u_i,
    ad(xi_i)^T F_s]``: one product of (N, n, 9) rows by (N, 9, columns) for every column at once, whatever its
    ``l``; a moved axis' row is ``Q_{i,i} . z``."""

    def __init__(self, kin):
        self.X = kin.axes  # (N, n, 6)
        self.M, self.S, self.g = kin.masses_beyond, kin.moments_beyond, kin.gravity
        n = self.X.shape[1]
        self.own = _q_rows(self.X, self.M[:n], self.S[:, :n], self.g)[..., 3:]  # Q_{i,i}, its non-zero half
        v, w = self.X[..., :3], self.X[..., 3:]
        F = kin.wrench_space[:, None, :]  # (N, 1, 6)
        self.rows = np.concatenate([so3.cross(self.g, w), so3.cross(F[..., :3], w),
                                    so3.cross(F[..., :3], v) + so3.cross(F[..., 3:], w)], axis=-1)  # (N, n, 9)

    def __call__(self, a, l, Z: np.ndarray) -> np.ndarray:
        """dtau (N, n, c) for the twists Z (N, 6, c), column c moving axes >= a[c] and links >= l[c] (arrays (c,)
        or scalars)."""
        l = np.broadcast_to(l, Z.shape[-1:])
        unmoved = self.rows @ np.concatenate([_lever(self.M[l], self.S[:, l], Z), Z], axis=1)  # (N, n, c)
        idx = np.arange(self.X.shape[1])[:, None]
        if np.all(idx < a):
            return unmoved
        return np.where(idx < a, unmoved, self.own @ Z[:, 3:])

    def moved_weight(self, m: int, mass: float, moment: np.ndarray, Z: np.ndarray) -> np.ndarray:
        """dtau (N, n, d) from a weight (``mass``, first ``moment`` (N, 3)) beyond the chain moved by the twists
        Z (N, 6, d) while the axes before ``m`` stay (the unmoved rows, with this weight alone)."""
        out = np.zeros(self.X.shape[:2] + Z.shape[-1:])
        out[:, :m] = self.rows[:, :m, :3] @ _lever(float(mass), np.asarray(moment)[:, None, :], Z)
        return out


def _lever(mass, moment: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """``M z_v + z_w x S`` (N, 3, c) for twists Z (N, 6, c) against weights of mass (c,) (or a scalar) and first
    moments (N, c, 3) (or (N, 1, 3))."""
    return mass * Z[:, :3] + np.swapaxes(so3.cross(np.swapaxes(Z[:, 3:], -1, -2), moment), -1, -2)


def gravity_torque_derivatives(kin, generators, parts, step: int = 1, C: np.ndarray | None = None
                               ) -> dict[str, np.ndarray]:
    """``C @ dtau/dp`` (N, k, d) (``C`` (N, k, n); None: ``dtau/dp`` (N, n, d)) for the parts in ``parts`` among
    offsets, twists, home, tool, base, for a ``LoadedKinematics`` with weights (``kin.gravity`` set). ``step``: the
    joints come in groups of ``step`` screws moved by one generator, offsets being the first's
    (``jacobians.tool_jacobians``); a group's links before its last screw are massless (``lateral.expand_load``),
    so its twist columns telescope to the insertion before its first screw minus the one after its last."""
    k0 = kin.unloaded
    n = kin.axes.shape[1]
    ins = kin.inserter
    out = {}
    j = np.arange(0, n, step)
    if "offsets" in parts:
        out["offsets"] = ins(j + 1, j, np.swapaxes(kin.axes[:, ::step], -1, -2))
    Ad = se3.adjoint(k0.prefixes) if ("twists" in parts or "home" in parts) else None
    if "twists" in parts:
        G = np.concatenate(generators, axis=1)  # (6, t)
        a = np.repeat(j, [Gj.shape[1] for Gj in generators])  # each column's group: screws [a, a + step)
        before = np.einsum("Ncab,bc->Nac", Ad[:, a], G)
        after = np.einsum("Ncab,bc->Nac", Ad[:, a + step], G)
        out["twists"] = ins(a, a, before) - ins(a + step, a + step - 1, after)
    if "home" in parts:
        out["home"] = ins(n, n, Ad[:, n])
    if "tool" in parts:
        out["tool"] = ins(n, n, se3.adjoint(k0.flange))
    if "base" in parts:
        out["base"] = ins(0, 0, np.broadcast_to(np.eye(6), (len(kin.axes), 6, 6)))
    return out if C is None else {p: C @ D for p, D in out.items()}
