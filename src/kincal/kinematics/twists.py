"""Joint twist conformation and minimal local parametrizations of joint axes."""

from __future__ import annotations

import math

import numpy as np

from kincal.kinematics.model import PRISMATIC, REVOLUTE
from kincal.lie import se3, so3

TWIST_COORDS = ("v_x", "v_y", "v_z", "w_x", "w_y", "w_z")  # names of a twist's coordinates, (v, w)


class Stacked(tuple):
    """A tuple of equal-shape arrays that are the rows of one array ``stack`` (an arm's tangent bases or
    generators, ``tangent_frames``): what ``np.stack`` of them gives, without the copy. Made from that array (or
    from the arrays, stacked); pickled (and copied) as a plain tuple."""

    def __new__(cls, rows):
        stack = rows if isinstance(rows, np.ndarray) else np.stack(list(rows))
        out = super().__new__(cls, stack)
        out.stack = stack
        return out

    def __reduce__(self):
        return tuple, (tuple(self),)


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
    xi = np.asarray(screws, dtype=float)  # not written: the result is a new array
    if xi.ndim == 2 and xi.shape[1] == 6 and len(xi) <= _FEW and len(joint_types) == len(xi):
        try:
            return _conform_few(xi.tolist(), joint_types, mode == "line")
        except ZeroDivisionError:  # a zero axis: numpy's inf and nan below
            pass
    bad = [k for k in joint_types if k not in (REVOLUTE, PRISMATIC)]
    if bad:
        raise ValueError(f"unknown joint type {bad[0]!r}")
    v, w = se3.split(xi)
    rev = np.array([k == REVOLUTE for k in joint_types], bool)
    out = np.zeros_like(xi)
    if rev.any():  # every revolute joint at once
        vr, wr = v[rev], w[rev]
        norm = np.sqrt(np.einsum("ij,ij->i", wr, wr))[:, None]
        v_perp = vr - (np.einsum("ij,ij->i", wr, vr) / np.einsum("ij,ij->i", wr, wr))[:, None] * wr
        out[rev] = se3.join(v_perp / norm if mode == "line" else v_perp, wr / norm)
    if not rev.all():
        vp = v[~rev]
        out[~rev, :3] = vp / np.sqrt(np.einsum("ij,ij->i", vp, vp))[:, None]
    return out


def _conform_few(rows: list, joint_types, line: bool) -> np.ndarray:
    """``conform_twists`` joint by joint on Python floats (an arm's joints): the same IEEE operations in the same
    order: ``einsum``'s sum of three products, ``0.0 + ((a_0 + a_2) + a_1)`` (its two-lane loop; onto 0.0, so
    that -0.0 sums to +0.0), checked bit for bit against it by the tests. The joint types checked on the way
    (``conform_twists``' error at the first unknown one)."""
    out = []
    for (v0, v1, v2, w0, w1, w2), kind in zip(rows, joint_types):
        if kind == REVOLUTE:
            ww = 0.0 + ((w0 * w0 + w2 * w2) + w1 * w1)
            norm = math.sqrt(ww)
            f = (0.0 + ((w0 * v0 + w2 * v2) + w1 * v1)) / ww
            p0, p1, p2 = v0 - f * w0, v1 - f * w1, v2 - f * w2
            if line:
                p0, p1, p2 = p0 / norm, p1 / norm, p2 / norm
            out += (p0, p1, p2, w0 / norm, w1 / norm, w2 / norm)
        elif kind == PRISMATIC:
            norm = math.sqrt(0.0 + ((v0 * v0 + v2 * v2) + v1 * v1))
            out += (v0 / norm, v1 / norm, v2 / norm, 0.0, 0.0, 0.0)
        else:
            raise ValueError(f"unknown joint type {kind!r}")
    return np.fromiter(out, float, len(out)).reshape(len(rows), 6)


def _perpendicular_pairs(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit u1 (m, 3) normal to each direction d (m, 3), and u2 = d x u1."""
    a = np.eye(3)[np.argmin(np.abs(d), axis=-1)]
    u1 = so3.cross(d, a)
    u1 /= np.linalg.norm(u1, axis=-1, keepdims=True)
    return u1, so3.cross(d, u1)


def tangent_basis(screw: np.ndarray, kind: str) -> np.ndarray:
    """Orthonormal-ish basis (6, k) of admissible twist changes of one joint screw (``tangent_frames``).

    Revolute (k = 4): shift the axis line along u1, u2 and tilt it about u1, u2 through its point
    nearest the origin (u1, u2 perpendicular to the axis). Prismatic (k = 2): tilt the direction.
    Moving along any column keeps |w| = 1 and zero pitch to first order.
    """
    return tangent_frames(np.asarray(screw, dtype=float)[None], (kind,))[0][0]


def tangent_generators(screw: np.ndarray, kind: str) -> np.ndarray:
    """Rigid-motion generators G (6, k) with ``-ad(xi) G = tangent_basis(xi)`` (``tangent_frames``).

    ``Ad(exp(G d)) xi`` moves the joint screw along the tangent basis to first order and stays an exact
    unit, zero-pitch (or unit prismatic) screw for any d: an exact retraction of joint axes.
    Shifts are translations along u_k; tilts are rotations about w x u_k through the axis point p
    (prismatic: rotations about v x u_k through the origin).
    """
    return tangent_frames(np.asarray(screw, dtype=float)[None], (kind,))[1][0]


def tangent_frames(screws: np.ndarray, joint_types) -> tuple[tuple, tuple]:
    """``tangent_basis`` and ``tangent_generators`` of every joint of an arm, each joint type in one batch:
    (bases, generators), each a tuple of (6, k) per joint. Up to ``_FEW`` revolute joints and no prismatic one
    (an arm's), joint by joint on Python floats (``_frame_entries``): the same IEEE operations, the bases and the
    generators each the rows of one (n, 6, 4) array (``Stacked``)."""
    xi, types = np.asarray(screws, dtype=float), tuple(joint_types)
    n = len(xi)
    if n <= _FEW and types.count(REVOLUTE) == len(types):  # every joint revolute
        flat = []
        for x in xi.tolist():
            flat += _frame_entries(x)  # joined by ``list``'s own extend, not element by element
        E = np.fromiter(flat, float, len(flat)).reshape(n, 18)
        # B's and G's laid out from the entries, each one contiguous (n, 6, 4) array as ``np.stack`` would give
        BG = np.concatenate((E, -E, _ZEROS[:n]), axis=1).ravel()[_FRAME_TAKES[n]]
        return Stacked(BG[0]), Stacked(BG[1])
    bases, gens = [None] * len(xi), [None] * len(xi)
    for kind, frames in ((REVOLUTE, _revolute_frames), (PRISMATIC, _prismatic_frames)):
        idx = [i for i, t in enumerate(joint_types) if t == kind]
        if idx:
            B, G = frames(*se3.split(xi[idx]))
            for k, i in enumerate(idx):
                bases[i], gens[i] = B[k], G[k]
    bad = [t for t in joint_types if t not in (REVOLUTE, PRISMATIC)]
    if bad:
        raise ValueError(f"unknown joint type {bad[0]!r}")
    return tuple(bases), tuple(gens)


def _revolute_frames(v: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p = so3.cross(w, v)  # points on the axes nearest the origin
    us = _perpendicular_pairs(w)
    zero = np.zeros_like(w)
    wus = [so3.cross(w, u) for u in us]
    B = np.stack([se3.join(-wu, zero) for wu in wus] + [se3.join(-so3.cross(u, p), u) for u in us], axis=-1)
    G = np.stack([se3.join(u, zero) for u in us] + [se3.join(-so3.cross(wu, p), wu) for wu in wus], axis=-1)
    return B, G


_FEW = 16  # joints up to which ``tangent_frames`` goes joint by joint on Python floats


def _revolute_frame(v, w) -> list:
    """``_revolute_frames`` of one joint (v, w lists of floats) with the same operations: B's then G's entries, row
    by row (``_frame_entries`` laid out)."""
    e = _frame_entries([*v, *w])
    e += (*(-x for x in e), 0.0)
    return [e[i] for i in _FRAME_INDEX]


def _frame_entries(xi) -> tuple:
    """The 18 values ``_revolute_frames`` lays out for one joint (xi its 6 floats), u1, u2, w x u2, u1 x p, u2 x p
    and (w x u2) x p, with its operations (``argmin`` keeps the first of equal magnitudes, the norm sums the
    squares in order; the cross products written out, as ``so3.cross_tuple``)."""
    v0, v1, v2, w0, w1, w2 = xi
    p0, p1, p2 = w1 * v2 - w2 * v1, w2 * v0 - w0 * v2, w0 * v1 - w1 * v0  # w x v
    x, y, z = abs(w0), abs(w1), abs(w2)
    a0, a1, a2 = (1.0, 0.0, 0.0) if x <= y and x <= z else (0.0, 1.0, 0.0) if y <= z else (0.0, 0.0, 1.0)
    c0, c1, c2 = w1 * a2 - w2 * a1, w2 * a0 - w0 * a2, w0 * a1 - w1 * a0  # w x a
    n = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    u0, u1, u2 = c0 / n, c1 / n, c2 / n  # u1
    s0, s1, s2 = w1 * u2 - w2 * u1, w2 * u0 - w0 * u2, w0 * u1 - w1 * u0  # u2 = w x u1 (= wu1)
    t0, t1, t2 = w1 * s2 - w2 * s1, w2 * s0 - w0 * s2, w0 * s1 - w1 * s0  # wu2 = w x u2
    return (u0, u1, u2, s0, s1, s2, t0, t1, t2,
            u1 * p2 - u2 * p1, u2 * p0 - u0 * p2, u0 * p1 - u1 * p0,  # u1 x p
            s1 * p2 - s2 * p1, s2 * p0 - s0 * p2, s0 * p1 - s1 * p0,  # u2 x p (= wu1 x p)
            t1 * p2 - t2 * p1, t2 * p0 - t0 * p2, t0 * p1 - t1 * p0)  # wu2 x p


def _frame_index() -> list:
    """Where each of B's then G's 48 entries (row by row) comes from in a joint's ``_frame_entries`` followed by
    their negatives (18 on) and a zero (36): B = [[-wu1, -wu2, -(u1 x p), -(u2 x p)], [0, 0, u1, u2]] and
    G = [[u1, u2, -(wu1 x p), -(wu2 x p)], [0, 0, wu1, wu2]] (``_revolute_frames``; wu1 = u2)."""
    at = {name: 3 * k for k, name in enumerate(("u", "s", "t", "d", "e", "h"))}  # u1, u2, wu2, u1 x p, ...

    def place(name: str, r: int) -> int:  # "0": the zero; "-x": x's negative; "x": x itself (row r of it)
        if name == "0":
            return 36
        return 18 + at[name[1:]] + r if name[0] == "-" else at[name] + r

    rows = ((("-s", "-t", "-d", "-e"), ("0", "0", "u", "s")), (("u", "s", "-e", "-h"), ("0", "0", "s", "t")))
    return [place(name, r) for top, bottom in rows for half in (top, bottom) for r in range(3) for name in half]


_FRAME_INDEX = _frame_index()
# per joint count n <= _FEW: the flat indices into the joints' entries, negatives and zero (n, 37) of B's and G's
# entries (2, n, 6, 4)
_FRAME_TAKES = tuple((np.arange(n)[None, :, None] * 37 + np.reshape(_FRAME_INDEX, (2, 1, 24))).reshape(2, n, 6, 4)
                     for n in range(_FEW + 1))
_ZEROS = np.zeros((_FEW, 1))
for _a in (*_FRAME_TAKES, _ZEROS):
    _a.flags.writeable = False


def _prismatic_frames(v: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    us = _perpendicular_pairs(v)
    zero = np.zeros_like(v)
    B = np.stack([se3.join(u, zero) for u in us], axis=-1)
    G = np.stack([se3.join(zero, so3.cross(v, u)) for u in us], axis=-1)
    return B, G


def padded_bases(bases) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint matrices (6, k_j) zero-padded to (n, 6, k_max), and the flat indices of real columns."""
    k_max = max(b.shape[1] for b in bases)
    B = np.zeros((len(bases), 6, k_max))
    keep = []
    for j, b in enumerate(bases):
        B[j, :, : b.shape[1]] = b
        keep += [j * k_max + c for c in range(b.shape[1])]
    return B, np.array(keep)
