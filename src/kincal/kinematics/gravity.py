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
from kincal.kinematics.twists import padded_bases
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
    c = (P[..., :3, :3] @ load.coms[:, :, None])[..., 0] + P[..., :3, 3]  # (..., n, 3) link centres
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

    An unmoved axis' row ``ad(xi_i)^T W_l + Q_{i,l}`` equals (Jacobi identity, ``W_l = (M_l g, S_l x g) + F_s``)
    ``(M_l u_i, S_l x u_i) + ad(xi_i)^T F_s`` with ``u_i = g x w_i``: against a twist ``z = (z_v, z_w)`` it is
    ``r_i . y_l(z)`` with ``r_i = [u_i, ad(xi_i)^T F_s]`` and ``y_l(z) = [M_l z_v + z_w x S_l, z]``, and a moved
    axis' row is ``Q_{i,i} . z``. The Jacobians use the derivatives projected, ``C @ dtau`` (``C`` (N, k, n): the
    compliance-weighted ``G dT/dtheta``), so ``project(C)`` sums ``C_i r_i`` over the axes before each insertion
    and ``C_i Q_{i,i}`` over those after it once: an inserted twist then costs (N, k, 9) numbers, not (N, n, 9)."""

    def __init__(self, kin):
        self.X = kin.axes  # (N, n, 6)
        self.M, self.S, self.g = kin.masses_beyond, kin.moments_beyond, kin.gravity
        n = self.X.shape[1]
        self.own = _q_rows(self.X, self.M[:n], self.S[:, :n], self.g)[..., 3:]  # Q_{i,i}, its non-zero half
        v, w = self.X[..., :3], self.X[..., 3:]
        F = kin.wrench_space[:, None, :]  # (N, 1, 6)
        self.rows = np.concatenate([so3.cross(self.g, w), so3.cross(F[..., :3], w),
                                    so3.cross(F[..., :3], v) + so3.cross(F[..., 3:], w)], axis=-1)  # (N, n, 9)
        self._last = None  # (C, its projection): the chain's parts and its insertions share one C

    def project(self, C: np.ndarray | None = None) -> "_Projected":
        """``C @ dtau`` for C (N, k, n); None: ``dtau`` itself (C the identity)."""
        if C is not None and self._last is not None and np.array_equal(self._last[0], C):
            return self._last[1]
        N, n = self.X.shape[:2]
        Ct = np.broadcast_to(np.eye(n), (N, n, n)) if C is None else np.swapaxes(C, -1, -2)  # (N, n, k)
        sums = np.zeros((N, n + 1) + Ct.shape[2:] + (12,))  # at a: over the axes i < a (9), i >= a (3)
        np.cumsum(Ct[..., None] * self.rows[:, :, None], axis=1, out=sums[:, 1:, :, :9])
        sums[:, :n, :, 9:] = np.flip(np.cumsum(np.flip(Ct[..., None] * self.own[:, :, None], 1), axis=1), 1)
        out = _Projected(self.M, self.S, sums)
        if C is not None:
            self._last = (C, out)
        return out


class _Projected:
    """``C @ dtau`` of an ``_Inserter`` (``_Inserter.project``)."""

    def __init__(self, M: np.ndarray, S: np.ndarray, sums: np.ndarray):
        self.M, self.S, self.sums = M, S, sums  # sums (N, n + 1, k, 12): [C_i r_i over i < a, C_i Q_ii over i >= a]

    def __call__(self, a, l, Z: np.ndarray) -> np.ndarray:
        """(N, k, g, d) for groups of twists Z (N, g, 6, d), group j moving the axes >= a[j] and the links >= l[j]
        (int arrays (g,))."""
        zw = np.swapaxes(Z[:, :, 3:], -1, -2)  # (N, g, d, 3)
        lever = self.M[l][:, None, None] * Z[:, :, :3] + np.swapaxes(so3.cross(zw, self.S[:, l, None]), -1, -2)
        return np.moveaxis(self.sums[:, a] @ np.concatenate([lever, Z, Z[:, :, 3:]], axis=2), 1, 2)

    def columns(self, a: int, l: int, Z: np.ndarray) -> np.ndarray:
        """(N, k, d) for one group of twists Z (N, 6, d)."""
        return self(np.array([a]), np.array([l]), Z[:, None])[:, :, 0]

    def moved_weight(self, m: int, mass: float, moment: np.ndarray, Z: np.ndarray) -> np.ndarray:
        """(N, k, d) from a weight (``mass``, first ``moment`` (N, 3)) beyond the chain moved by the twists Z
        (N, 6, d) while the axes before ``m`` stay (the unmoved rows, with this weight alone)."""
        return self.sums[:, m, :, :3] @ weight_levers(float(mass), moment[:, None], Z)


def weight_levers(mass, moment: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """``M z_v + z_w x S`` (N, 3, c) for twists Z (N, 6, c) moving weights of mass (c,) (or a scalar) and first
    moment (N, c, 3) (or (N, 1, 3)): a fixed axis' torque changes by ``(g x w) .`` that (``_Inserter``)."""
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
    ins = kin.inserter.project(C)
    out = {}
    j = np.arange(0, n, step)
    if "offsets" in parts:
        out["offsets"] = ins(j + 1, j, kin.axes[:, ::step, :, None])[..., 0]
    Ad = se3.adjoint(k0.prefixes[:, ::step]) if ("twists" in parts or "home" in parts) else None  # groups' bounds
    if "twists" in parts:
        Gen, keep = padded_bases(generators)  # (groups, 6, d)
        ends = ins(np.r_[j, j + step], np.r_[j, j + step - 1], np.concatenate([Ad[:, :-1], Ad[:, 1:]], 1) @ np.concatenate([Gen, Gen]))
        tw = ends[:, :, : len(j)] - ends[:, :, len(j):]  # (N, k, groups, d): before the group minus after it
        out["twists"] = tw.reshape(tw.shape[:2] + (-1,))[..., keep]
    if "home" in parts:
        out["home"] = ins.columns(n, n, Ad[:, -1])
    if "tool" in parts:
        out["tool"] = ins.columns(n, n, se3.adjoint(k0.flange))
    if "base" in parts:
        out["base"] = ins.columns(0, 0, np.broadcast_to(np.eye(6), (len(kin.axes), 6, 6)))
    return out
