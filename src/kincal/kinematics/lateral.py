"""Lateral compliance: each joint also bends about the two axes normal to its own axis (issue 14, the Justin
paper's kappa_alpha, kappa_beta).

Model. Joint i's two *lateral axes* are screws ``eta_i1, eta_i2`` (world frame of the arm base at q = 0)
through the point of its axis nearest the arm base origin, with directions ``x, y`` such that ``(x, y, w)`` is
right-handed (``w`` the joint axis): ``x`` is the unit projection, normal to ``w``, of the base-frame coordinate
axis least aligned with ``w`` (x before y before z on ties), ``y = w x x``. They are computed once, from the
nominal model, and then carried rigidly by the joint's motion: exactly as its screw, ``eta`` sits right after
joint i in the chain (it turns with link i), and a twist step ``Ad(exp(g)) xi_i`` moves them by the same
``Ad(exp(g))``, so the names ``arm.j2.lateral_x`` / ``lateral_y`` keep their meaning while the twist is calibrated.
Each bends by ``c * (eta_s . W_i)`` (``W_i`` the load joint i transmits: tool wrench plus the weight beyond it),
first order at the unloaded configuration, like the joint compliance itself.

Kinematics as an *expanded chain*: joint i becomes three joints ``xi_i, eta_i1, eta_i2`` (unloaded values
``theta0_i, 0, 0``, compliances ``c_i, l_i1, l_i2``), link i's mass rides on the third. The unchanged loaded
chain and its Jacobians (``kincal.kinematics.jacobians``, ``gravity``) then hold on it; a joint's twist
coordinates move its three screws with the same generator (their columns add up), its offset and reading are
the first column, the lateral compliances the compliance columns of the virtual joints.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kincal.lie import se3

LATERAL_COORDS = ("lateral_x", "lateral_y")


def lateral_axes(screws: np.ndarray) -> np.ndarray:
    """The nominal lateral axes (n, 2, 6) of joint screws (n, 6) (module docstring); a prismatic joint's
    (``w = 0``) are normal to its direction of motion, through the base origin."""
    screws = np.asarray(screws, dtype=float)
    v, w = screws[:, :3], screws[:, 3:]
    prismatic = np.linalg.norm(w, axis=1) < 0.5
    d = np.where(prismatic[:, None], v, w)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    p = np.where(prismatic[:, None], 0.0, np.cross(w, v))  # nearest the origin for unit w, zero pitch
    e = np.eye(3)[np.argmin(np.abs(d), axis=1)]
    x = e - np.sum(e * d, axis=1, keepdims=True) * d
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(d, x)
    n = np.stack([x, y], axis=1)  # (n, 2, 3)
    return np.concatenate([np.cross(p[:, None, :], n), n], axis=-1)


def expand_screws(screws: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """The expanded chain's screws (3n, 6): ``xi_i, eta_i1, eta_i2`` per joint."""
    return np.concatenate([np.asarray(screws)[:, None, :], np.asarray(axes)], axis=1).reshape(-1, 6)


def expand_values(real: np.ndarray, lateral: np.ndarray | float) -> np.ndarray:
    """Per-joint values (..., n) and per-lateral values (..., n, 2) (or a scalar) interleaved to (..., 3n)."""
    real = np.asarray(real, dtype=float)
    lat = np.broadcast_to(np.asarray(lateral, dtype=float), real.shape + (2,))
    shape = np.broadcast_shapes(real.shape, lat.shape[:-1])
    out = np.concatenate([np.broadcast_to(real, shape)[..., None], np.broadcast_to(lat, shape + (2,))], axis=-1)
    return out.reshape(shape[:-1] + (3 * shape[-1],))


def expand_coupling(A: np.ndarray | None) -> np.ndarray | None:
    """A chain's coupling map (n, n) on the expanded chain (3n, 3n): the real joints' entries, the lateral joints
    free (no lateral joint is coupled)."""
    if A is None:
        return None
    n = len(A)
    out = np.eye(3 * n)
    out[0::3, 0::3] = A
    return out


def expand_load(load):
    """The weights (``gravity.GravityLoad`` or None) on the expanded chain: link i's on the last of its three
    joints."""
    if load is None:
        return None
    n = len(load.masses)
    masses, coms = np.zeros(3 * n), np.zeros((3 * n, 3))
    masses[2::3], coms[2::3] = load.masses, load.coms
    return replace(load, masses=masses, coms=coms)


def real_columns(J: np.ndarray) -> np.ndarray:
    """The real joints' columns of an expanded (..., 3n) array."""
    return J[..., 0::3]


def lateral_columns(J: np.ndarray) -> np.ndarray:
    """The lateral columns (..., 2n) of an expanded (..., 3n) array, ``x, y`` per joint."""
    shape = J.shape[:-1]
    return J.reshape(shape + (-1, 3))[..., 1:].reshape(shape + (-1,))


def expand_basis(basis, n: int, N: int):
    """The compliance basis ``(W, S)`` (N, n, p) or None of the real joints, for the expanded chain with the
    coefficients ``(k, lateral)`` (p + 2n): lateral coefficients map one to one onto the virtual joints."""
    W0, S0 = basis if basis is not None else (np.broadcast_to(np.eye(n), (N, n, n)), np.zeros((N, n, n)))
    p = W0.shape[-1]
    W, S = np.zeros((N, 3 * n, p + 2 * n)), np.zeros((N, 3 * n, p + 2 * n))
    W[:, 0::3, :p], S[:, 0::3, :p] = W0, S0
    idx = np.arange(2 * n)
    W[:, 3 * (idx // 2) + 1 + idx % 2, p + idx] = 1.0
    return W, S


def chain_lateral(segments, frames) -> tuple[np.ndarray, np.ndarray] | None:
    """(lateral axes (n, 2, 6), lateral compliances (n, 2)) of a composite chain of ``segments`` (anything with
    ``lateral``, ``lateral_axes``, ``screws``) whose frames are ``frames`` (``tree.Composite.frames``): each axis
    mapped by ``Ad(M_k)`` like the screws; zeros for a segment without lateral compliance; None when none has."""
    if all(getattr(s, "lateral", None) is None for s in segments):
        return None
    axes, lat = [], []
    for s, M in zip(segments, frames):
        n = s.screws.shape[0]
        if s.lateral is None:
            axes.append(np.zeros((n, 2, 6)))
            lat.append(np.zeros((n, 2)))
        else:
            axes.append(np.asarray(s.lateral_axes) @ se3.adjoint(M).T)
            lat.append(np.asarray(s.lateral, dtype=float))
    return np.concatenate(axes), np.concatenate(lat)
