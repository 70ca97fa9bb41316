"""Joint twist conformation and minimal local parametrizations of joint axes."""

from __future__ import annotations

import numpy as np

from kincal.kinematics.model import PRISMATIC, REVOLUTE
from kincal.lie import se3, so3

TWIST_COORDS = ("v_x", "v_y", "v_z", "w_x", "w_y", "w_z")  # names of a twist's coordinates, (v, w)


def conform_twists(screws: np.ndarray, joint_types, mode: str = "line") -> np.ndarray:
    """Project joint twists (n, 6) onto valid joint screws.

    Revolute joints get a unit axis and zero pitch (thesis eq. 2.57-2.58, Yang et al. 2014):
    ``w_c = w / |w|`` and the pitch component ``(w.v / w.w) w`` removed from v. With ``mode="line"``
    (default) v is also divided by |w| so the joint axis stays on the same line; ``mode="thesis"``
    keeps v's length as the thesis does (the line then moves by a factor |w|, negligible for |w| ~ 1).
    Prismatic joints get w = 0 and a unit v.
    """
    if mode not in ("line", "thesis"):
        raise ValueError(f"mode must be 'line' or 'thesis', got {mode!r}")
    xi = np.array(screws, dtype=float)
    v, w = se3.split(xi)
    out = np.empty_like(xi)
    for i, kind in enumerate(joint_types):
        if kind == REVOLUTE:
            norm = np.linalg.norm(w[i])
            v_perp = v[i] - (w[i] @ v[i]) / (w[i] @ w[i]) * w[i]
            out[i] = se3.join(v_perp / norm if mode == "line" else v_perp, w[i] / norm)
        elif kind == PRISMATIC:
            out[i] = se3.join(v[i] / np.linalg.norm(v[i]), np.zeros(3))
        else:
            raise ValueError(f"unknown joint type {kind!r}")
    return out


def _perpendicular_pair(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.eye(3)[np.argmin(np.abs(d))]
    u1 = so3.cross(d, a)
    u1 /= np.linalg.norm(u1)
    return u1, so3.cross(d, u1)


def tangent_basis(screw: np.ndarray, kind: str) -> np.ndarray:
    """Orthonormal-ish basis (6, k) of admissible twist changes of one joint screw.

    Revolute (k = 4): shift the axis line along u1, u2 and tilt it about u1, u2 through its point
    nearest the origin (u1, u2 perpendicular to the axis). Prismatic (k = 2): tilt the direction.
    Moving along any column keeps |w| = 1 and zero pitch to first order.
    """
    v, w = se3.split(np.asarray(screw, dtype=float))
    if kind == REVOLUTE:
        p = so3.cross(w, v)  # point on the axis nearest the origin
        u1, u2 = _perpendicular_pair(w)
        cols = [se3.join(-so3.cross(w, u), np.zeros(3)) for u in (u1, u2)]
        cols += [se3.join(-so3.cross(u, p), u) for u in (u1, u2)]
        return np.stack(cols, axis=-1)
    if kind == PRISMATIC:
        u1, u2 = _perpendicular_pair(v)
        return np.stack([se3.join(u, np.zeros(3)) for u in (u1, u2)], axis=-1)
    raise ValueError(f"unknown joint type {kind!r}")


def tangent_generators(screw: np.ndarray, kind: str) -> np.ndarray:
    """Rigid-motion generators G (6, k) with ``-ad(xi) G = tangent_basis(xi)``.

    ``Ad(exp(G d)) xi`` moves the joint screw along the tangent basis to first order and stays an exact
    unit, zero-pitch (or unit prismatic) screw for any d: an exact retraction of joint axes.
    Shifts are translations along u_k; tilts are rotations about w x u_k through the axis point p
    (prismatic: rotations about v x u_k through the origin).
    """
    v, w = se3.split(np.asarray(screw, dtype=float))
    if kind == REVOLUTE:
        p = so3.cross(w, v)
        u1, u2 = _perpendicular_pair(w)
        cols = [se3.join(u, np.zeros(3)) for u in (u1, u2)]
        cols += [se3.join(-so3.cross(so3.cross(w, u), p), so3.cross(w, u)) for u in (u1, u2)]
        return np.stack(cols, axis=-1)
    if kind == PRISMATIC:
        u1, u2 = _perpendicular_pair(v)
        return np.stack([se3.join(np.zeros(3), so3.cross(v, u)) for u in (u1, u2)], axis=-1)
    raise ValueError(f"unknown joint type {kind!r}")
