"""Vectorized POE forward kinematics and geometric Jacobians.

All functions take joint readings ``q`` of shape (..., n) and broadcast over the leading dimensions.
Loops run over the n joints only, never over configurations.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from kincal._validate import as_array
from kincal.errors import ShapeError
from kincal.kinematics.model import ArmModel
from kincal.lie import se3, so3


def joint_array(model: ArmModel, q, name: str = "q") -> np.ndarray:
    """Validate joint readings: finite, last dimension equal to the arm's dof."""
    q = np.asarray(q, dtype=float) if not isinstance(q, np.ndarray) else q
    if q.ndim == 0 or q.shape[-1] != model.dof:
        raise ShapeError(
            f"{name}: arm '{model.name}' has {model.dof} joints ({', '.join(model.joint_names)}); "
            f"expected shape (..., {model.dof}), got {np.shape(q)}"
        )
    return as_array(q, name, (model.dof,))


@dataclass(frozen=True)
class Kinematics:
    """Everything forward kinematics computes for a batch of configurations.

    Attributes
    ----------
    theta : (..., n) joint values with offsets applied.
    screws : (n, 6) the joint screws the chain was computed with.
    prefixes : (..., n + 1, 4, 4) ``base @ exp_1 @ ... @ exp_i`` for i = 0..n (index 0 is ``base``).
    flange : (..., 4, 4) ``T_world_flange``.
    tool : (..., 4, 4) ``T_world_tool``.
    exps : (..., n, 4, 4) ``exp(hat(xi_i) theta_i)``, computed when first read (the chain does not need them).
    """

    theta: np.ndarray
    screws: np.ndarray
    prefixes: np.ndarray
    flange: np.ndarray
    tool: np.ndarray

    @cached_property
    def exps(self) -> np.ndarray:
        return _exponentials(self.screws, self.theta)

    @cached_property
    def turns(self) -> tuple[np.ndarray, np.ndarray]:
        """``(cos theta, sin theta)``, each (..., n) (the chain's own when it computed them)."""
        return np.cos(self.theta), np.sin(self.theta)

    @cached_property
    def moves(self) -> np.ndarray:
        """(n,): whether each joint is off zero in some sample (one at zero in every sample is the identity)."""
        return self.theta.reshape(-1, self.theta.shape[-1]).any(axis=0)

    @cached_property
    def coefficients(self) -> np.ndarray:
        """(n, N, 2): each joint's ``(a, b)`` per sample with ``exp(X t) = I + a X + b X^2`` for X the hat of an
        exact joint screw (``ad(xi)`` alike, for the adjoint): revolute ``(sin t, 1 - cos t)`` (``X^3 = -X``),
        prismatic ``(t, 1 - cos t)`` (``X^2 = 0``); theta (N, n)."""
        return self.unit_coefficients[..., :2]

    @cached_property
    def unit_coefficients(self) -> np.ndarray:
        """(n, N, 3): ``(a, b, 1)``, so that ``exp(X t)`` of every joint and sample is one product with
        ``powers(screws, basis, unit=True)`` (the identity's term added exactly, in the same product)."""
        return _coefficients(self.screws, self.theta, self.turns)

    @cached_property
    def one_base(self) -> np.ndarray | None:
        """The base (4, 4) when every sample has the same one (a chain's own: finite bases are equal), else None."""
        P0 = self.prefixes[..., 0, :, :].reshape(-1, 4, 4)
        return P0[0] if (P0 == P0[:1]).all() else None


def _exponentials(screws, theta) -> np.ndarray:
    if se3.exact_joint_screws(screws):
        return se3.exp_joint_screws(screws, theta)
    return se3.exp(screws * theta[..., None])  # raw twists (e.g. a finite-difference step): the general exponential


def kinematics(model: ArmModel, q) -> Kinematics:
    """Forward kinematics with every intermediate product; q is validated against the model."""
    q = joint_array(model, q)
    return chain(model.screws, q + model.offsets, model.base, model.home, model.tool)


def chain(screws, theta, base, home, tool, frames: bool = True) -> Kinematics:
    """Unvalidated POE kernel on raw arrays (screws need not be conformed): theta (..., n).

    Exact joint screws (``se3.exact_joint_screws``) go through their joint frames (``se3.joint_frames``):
    ``P_i = (P_{i-1} C_i) Z_i(theta_i) C_i^-1``, two products with constants over all samples at once and a
    change of two columns per joint; a joint at zero in every sample is the identity (its prefix is the last).
    ``frames`` False: the products of the joints' exponentials (a loaded chain's, ``elastic.loaded_chain``).
    ``sample_chain``: the same to round-off with fewer operations (the experiments' unloaded arms)."""
    theta = np.asarray(theta, dtype=float)
    screws = np.asarray(screws, dtype=float)
    known = {}
    if frames and se3.exact_joint_screws(screws):
        known["turns"] = turns = np.cos(theta), np.sin(theta)
        prefixes, known["moves"] = _frame_prefixes(screws, theta, base, turns)
    else:
        prefixes = _product_prefixes(screws, theta, base)
    base = np.asarray(base)
    if base.ndim == 2 and np.isfinite(base).all():  # every sample's prefix 0 is a copy of it
        known["one_base"] = prefixes[(0,) * (prefixes.ndim - 2)]  # sample 0, prefix 0
    flange = _times(prefixes[..., -1, :, :], home)
    kin = Kinematics(theta, screws, prefixes, flange, _times(flange, tool))
    kin.__dict__.update(known)  # the cached properties' values: the Jacobians turn by the same
    return kin


def sample_chain(screws, theta, base, home, tool, turns=None) -> Kinematics:
    """``chain`` with one product per joint over all samples, of the joints' exponentials in closed form
    (``Kinematics.coefficients``: ``I + a X + b X^2``, every joint and sample in one product): the numbers of
    ``chain`` to round-off (``chain``'s joint frames take two products and a turn per joint). For exact joint
    screws, theta (N, n) and one finite base (4, 4); else ``chain``. A joint at zero in every sample is the
    identity. ``turns``: ``(cos theta, sin theta)`` when the caller has them (``shifted_turns``)."""
    theta = np.asarray(theta, dtype=float)
    screws = np.asarray(screws, dtype=float)
    base = np.asarray(base, dtype=float)
    if theta.ndim != 2 or base.shape != (4, 4) or not np.isfinite(base).all() or not se3.exact_joint_screws(screws):
        return chain(screws, theta, base, home, tool)
    N, n = theta.shape
    turns = (np.cos(theta), np.sin(theta)) if turns is None else turns
    ab = _coefficients(screws, theta, turns)
    moves = theta.any(axis=0)
    E = (ab @ powers(screws, _HAT_BASIS, unit=True)).reshape(n, N, 4, 4)  # I + a X + b X^2
    P = np.empty((n + 1, N, 4, 4))
    P[0] = base
    for i in range(n):
        if moves[i]:
            np.matmul(P[i], E[i], out=P[i + 1])
        else:  # exp(0) = I
            P[i + 1] = P[i]
    flange = _times(P[n], home)
    prefixes = P.transpose(1, 0, 2, 3)
    kin = Kinematics(theta, screws, prefixes, flange, _times(flange, tool))
    kin.__dict__.update(turns=turns, moves=moves, coefficients=ab[..., :2], unit_coefficients=ab,
                        one_base=prefixes[0, 0])
    return kin


def shifted_turns(cos: np.ndarray, sin: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(cos, sin)`` of ``q + offsets`` from those of q (N, n) and the offsets (n,) by the angle sum: the turns
    of the rounded ``q + offsets`` to round-off (q's own at zero offsets), without a sine per sample (the
    readings' are the data's, computed once: ``Experiment._turns``)."""
    return paired_shifted_turns(np.stack([cos, sin]), offsets)


def paired_shifted_turns(turns: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``shifted_turns`` of ``turns``, (cos, sin) stacked (2, N, n): each offset's cosine and sine multiplies both
    at once, the same products and sums."""
    co, so = np.cos(offsets), np.sin(offsets)
    by_cos, by_sin = turns * co, turns * so
    return by_cos[0] - by_sin[1], by_cos[1] + by_sin[0]


def _coefficients(screws: np.ndarray, theta: np.ndarray, turns) -> np.ndarray:
    """``Kinematics.unit_coefficients``."""
    cos, sin = turns
    ab = np.empty((3,) + cos.shape[::-1])
    ab[0] = sin.T
    np.subtract(1.0, cos.T, out=ab[1])
    ab[2] = 1.0
    prismatic = [j for j, x in enumerate(screws.tolist()) if x[3] * x[3] + x[4] * x[4] + x[5] * x[5] <= 0.5]
    if prismatic:
        ab[0, prismatic] = theta.T[prismatic]
    return ab.transpose(1, 2, 0)


def powers(screws: np.ndarray, basis: np.ndarray, unit: bool = False) -> np.ndarray:
    """``(X, X^2)`` flattened, (n, 2, d * d), of the matrices ``X = sum_k xi_k basis_k`` of each twist (n, 6) for a
    linear map ``basis`` (6, d * d) of twists to d x d matrices (``hat`` or ``ad`` of the unit twists): the
    entries are the twist's coordinates, their signs or zero (one product over all twists). ``unit``: the
    identity as a third, (n, 3, d * d) (``Kinematics.unit_coefficients``' partner)."""
    n, dd = screws.shape[0], basis.shape[1]
    d = int(round(dd ** 0.5))
    out = np.empty((n, 2 + unit, d, d))
    np.matmul(screws, basis, out=out[:, 0].reshape(n, dd))
    np.matmul(out[:, 0], out[:, 0], out=out[:, 1])
    if unit:
        out[:, 2] = _EYES[d] if d in _EYES else np.eye(d)
    return out.reshape(n, 2 + unit, dd)


_EYES = {4: np.eye(4), 6: np.eye(6)}


_HAT_BASIS = se3.hat(np.eye(6)).reshape(6, 16)  # hat of the unit twists: hat(xi) = xi @ _HAT_BASIS


def _times(T: np.ndarray, X) -> np.ndarray:
    """``T @ X`` for poses T (..., 4, 4) and X; one product over all samples for a constant X and contiguous T."""
    X = np.asarray(X, dtype=float)
    if X.ndim == 2 and T.ndim > 2 and T.flags.c_contiguous:
        return (T.reshape(-1, 4) @ X).reshape(T.shape)
    return T @ X


def _product_prefixes(screws, theta, base) -> np.ndarray:
    """The prefixes as products of the joints' exponentials (any twists)."""
    exps = _exponentials(screws, theta)
    n = theta.shape[-1]
    prefixes = np.empty(theta.shape[:-1] + (n + 1, 4, 4))
    prefixes[..., 0, :, :] = base
    for i in range(n):
        prefixes[..., i + 1, :, :] = prefixes[..., i, :, :] @ exps[..., i, :, :]
    return prefixes


def _frame_prefixes(screws, theta, base, turns) -> tuple[np.ndarray, np.ndarray]:
    """The prefixes of exact joint screws through their joint frames (``chain``), computed joint by joint in one
    buffer (joint first) and returned as its (..., n + 1, 4, 4) view, with which joints move (``Kinematics.moves``).
    ``X = P_i C_i`` is held transposed (column, sample, row), so that a revolute turn of its columns 0 and 1 is
    three operations on contiguous rows (``turn_pairs``); the products are numpy's on transposed views, the same
    numbers."""
    C, Ci, revolute, _, _ = se3.joint_frames(screws)
    n = theta.shape[-1]
    batch = theta.shape[:-1]
    flat = theta.reshape(-1, n)
    N = flat.shape[0]
    P = np.empty((n + 1, N, 4, 4))
    P[0] = base if np.ndim(base) == 2 else np.broadcast_to(base, batch + (4, 4)).reshape(N, 4, 4)
    moves = flat.any(axis=0)
    c2, s2 = turn_factors(*(t.reshape(-1, n) for t in turns), 4, pose=True)  # per joint (1 or 2, 4 N)
    XT = np.empty((4, N, 4))
    XT2, P2 = XT.reshape(4, 4 * N), P.reshape(n + 1, 4 * N, 4)  # the products' views, made once
    for i in range(n):
        if not moves[i]:  # exp(0) = I
            P[i + 1] = P[i]
            continue
        np.matmul(C[i].T, P2[i].T, out=XT2)
        if revolute[i]:  # X Rz(t): columns 0 and 1 turn (c x0 + s x1, c x1 - s x0)
            turn_pairs(XT2[:2], c2[i], s2[i])
        else:  # X Tz(t): the origin moves along z
            XT[3, :, :3] += flat[:, i, None] * XT[2, :, :3]
        np.matmul(XT2.T, Ci[i], out=P2[i + 1])
    return P.transpose(1, 0, 2, 3).reshape(batch + (n + 1, 4, 4)), moves


def turn_factors(cos: np.ndarray, sin: np.ndarray, rows: int, pose: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``turn_pairs``' factors per joint from cos, sin (N, n): ``c`` (n, 1, N * rows) and ``(s, -s)``
    (n, 2, N * rows), each sample's value repeated over ``rows``; ``pose`` (rows 4): a pose's last row gets 1 and
    0, so that its +0.0 entries stay +0.0 (``1 x + 0 y``)."""
    n, N = cos.shape[1], cos.shape[0]
    c = np.repeat(cos.T, rows, axis=1)
    s2 = np.repeat(sin.T[:, None, :] * _SIGNS, rows, axis=2)
    if pose:
        c.reshape(n, N, 4)[..., 3] = 1.0
        s2.reshape(n, 2, N, 4)[..., 3] = 0.0
    return c.reshape(n, 1, N * rows), s2


_SIGNS = np.array([[1.0], [-1.0]])  # (s, -s): a product by -1 is the negation


def turn_pairs(Z: np.ndarray, c: np.ndarray, s2: np.ndarray) -> None:
    """``Z[..., 0, :], Z[..., 1, :] = c z0 + s z1, c z1 - s z0`` in place with ``c`` and ``s2 = (s, -s)`` stacked
    likewise: each a sum of two rounded products (``c z1 + (-s) z0`` is ``c z1 - s z0`` exactly)."""
    np.add(c * Z, s2 * Z[..., ::-1, :], out=Z)


def expanded_chain(screws, theta, base, home, tool, frames: bool = True) -> Kinematics:
    """``chain`` of the joints ``screws`` (n, 6) at ``theta`` (..., n) seen as a chain of 3n joints whose every
    second and third joint stays at zero (``kincal.kinematics.lateral``'s expanded chain at its unloaded values):
    the same numbers as that chain's ``chain``, without multiplying by its identities. Its ``screws`` repeat each
    joint's three times (a joint at zero is the identity whatever its screw)."""
    compact = chain(screws, theta, base, home, tool, frames)
    n = compact.theta.shape[-1]
    prefixes = compact.prefixes[..., np.repeat(np.arange(n + 1), [1] + [3] * n), :, :]
    theta3 = np.zeros(compact.theta.shape[:-1] + (3 * n,))
    theta3[..., 0::3] = compact.theta
    return Kinematics(theta3, np.repeat(compact.screws, 3, axis=0), prefixes, compact.flange, compact.tool)


def space_axes(prefixes: np.ndarray, screws: np.ndarray) -> np.ndarray:
    """The joint axes in the world, ``Ad(P_{i-1}) xi_i`` (..., n, 6), for prefixes (..., n + 1, 4, 4) and screws
    (n, 6): ``(R v + p x R w, R w)`` without forming the adjoints."""
    R, p = prefixes[..., :-1, :3, :3], prefixes[..., :-1, :3, 3]
    vw = R @ np.stack([screws[:, :3], screws[:, 3:]], axis=-1)  # (..., n, 3, 2): R v, R w
    out = np.empty(vw.shape[:-2] + (6,))
    out[..., 3:] = vw[..., 1]
    out[..., :3] = vw[..., 0] + so3.cross(p, out[..., 3:])
    return out


def forward_kinematics(model: ArmModel, q) -> np.ndarray:
    """``T_world_tool`` for joint readings q: (..., n) -> (..., 4, 4)."""
    return kinematics(model, q).tool


def space_jacobian(model: ArmModel, q, kin: Kinematics | None = None) -> np.ndarray:
    """Geometric Jacobian in the world frame: (Tdot T^-1)^vee = J_s qdot; (..., n) -> (..., 6, n).

    Column i is ``Ad(prefix_{i-1}) xi_i``; it does not depend on the tool.
    """
    kin = kinematics(model, q) if kin is None else kin
    Ad = se3.adjoint(kin.prefixes[..., :-1, :, :])  # (..., n, 6, 6)
    return np.swapaxes(np.einsum("...kij,kj->...ki", Ad, model.screws), -1, -2)


def body_jacobian(model: ArmModel, q, kin: Kinematics | None = None) -> np.ndarray:
    """Geometric Jacobian in the tool frame: (T^-1 Tdot)^vee = J_b qdot; (..., n) -> (..., 6, n)."""
    kin = kinematics(model, q) if kin is None else kin
    return se3.adjoint_inv(kin.tool) @ space_jacobian(model, q, kin)


def joint_axes(model: ArmModel, q) -> tuple[np.ndarray, np.ndarray]:
    """Current joint axes in the world frame: (points (..., n, 3), unit directions (..., n, 3)).

    For a prismatic joint the point is the origin of its preceding frame.
    """
    kin = kinematics(model, q)
    xi = np.einsum("...kij,kj->...ki", se3.adjoint(kin.prefixes[..., :-1, :, :]), model.screws)
    v, w = se3.split(xi)
    ww = np.sum(w * w, axis=-1, keepdims=True)
    revolute = ww > 0.25
    point = np.where(revolute, np.cross(w, v) / np.where(revolute, ww, 1.0), kin.prefixes[..., :-1, :3, 3])
    direction = np.where(revolute, w, v)
    return point, direction / np.linalg.norm(direction, axis=-1, keepdims=True)
