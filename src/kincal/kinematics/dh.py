"""Denavit-Hartenberg tables (standard and modified/Craig) -> product-of-exponentials ArmModel.

Standard DH, link i:  ``A_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``; joint i turns about z_{i-1}.
Modified DH (Craig), row i lists ``alpha_{i-1}, a_{i-1}, theta_i, d_i``:
``A_i = Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i + q_i) Tz(d_i)``; joint i turns about z_i.
For a prismatic joint q_i adds to d_i instead of theta_i.

``T_base_flange(q) = A_1(q_1) ... A_n(q_n) @ flange``. The conversion evaluates the frames at q = 0:
joint i's axis w_i and a point p_i on it give the twist ``(-w_i x p_i, w_i)`` (prismatic: ``(w_i, 0)``),
and ``home = A_1(0) ... A_n(0) @ flange``, so the POE model reproduces the DH forward kinematics exactly
(up to rounding) for every q.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kincal.errors import ModelError, ShapeError
from kincal.kinematics.model import PRISMATIC, REVOLUTE, ArmModel
from kincal.lie import se3


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return se3.make(np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), np.zeros(3))


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return se3.make(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]), np.zeros(3))


def _trans(x: float, y: float, z: float) -> np.ndarray:
    return se3.make(np.eye(3), np.array([x, y, z]))


def from_dh(
    a,
    alpha,
    d,
    theta=None,
    *,
    modified: bool = False,
    joint_types=None,
    flange=None,
    name: str = "arm",
    **model_fields,
) -> ArmModel:
    """ArmModel from a DH table (SI units: m, rad).

    Parameters
    ----------
    a, alpha, d : array_like, shape (n,)
        Link lengths, twists and offsets; for ``modified=True`` entry i holds ``a_{i-1}``, ``alpha_{i-1}``.
    theta : array_like, shape (n,), optional
        Constant joint-angle offsets of the table (default 0); for prismatic joints the fixed angle.
    modified : bool
        False: standard (distal) DH; True: modified (proximal, Craig) DH.
    joint_types : sequence of 'revolute'/'prismatic', optional (default all revolute)
    flange : (4, 4), optional
        ``T_n_flange``, the transform from the last DH frame to the flange (e.g. Panda's ``Tz(0.107)``).
    name : str
    **model_fields
        Passed on to ArmModel (base, tool, lower, upper, joint_names, gear_ratios, meta, ...).
    """
    cols = {"a": a, "alpha": alpha, "d": d}
    arrs = {k: np.asarray(v, dtype=float).reshape(-1) for k, v in cols.items()}
    n = arrs["a"].size
    arrs["theta"] = np.zeros(n) if theta is None else np.asarray(theta, dtype=float).reshape(-1)
    for k, v in arrs.items():
        if v.shape != (n,) or not np.all(np.isfinite(v)):
            raise ShapeError(f"DH column {k}: expected {n} finite values (one per joint), got {v.tolist()}")
    types = tuple(joint_types) if joint_types is not None else (REVOLUTE,) * n
    if len(types) != n or any(t not in (REVOLUTE, PRISMATIC) for t in types):
        raise ShapeError(f"joint_types: expected {n} of 'revolute'/'prismatic', got {types}")

    T = np.eye(4)  # frame {i-1} (standard) or frame {i-1} (modified) at q = 0, in the base frame
    screws = np.empty((n, 6))
    for i in range(n):
        ai, al, di, th = arrs["a"][i], arrs["alpha"][i], arrs["d"][i], arrs["theta"][i]
        if modified:
            T = T @ _rot_x(al) @ _trans(ai, 0, 0)
            joint_frame = T
            T = T @ _rot_z(th) @ _trans(0, 0, di)
        else:
            joint_frame = T
            T = T @ _rot_z(th) @ _trans(0, 0, di) @ _trans(ai, 0, 0) @ _rot_x(al)
        w, p = joint_frame[:3, 2], joint_frame[:3, 3]
        screws[i] = se3.join(w, np.zeros(3)) if types[i] == PRISMATIC else se3.join(-np.cross(w, p), w)
    home = T if flange is None else T @ np.asarray(flange, dtype=float)
    return ArmModel(name, screws, home, joint_types=types, **model_fields)


@dataclass(frozen=True)
class DHTable:
    """DH parameters of an arm (``to_dh``), with the constant transforms that close the chain:
    ``T_world_tool(q) = base @ A_1(q_1) ... A_n(q_n) @ flange @ tool`` (``from_dh`` conventions; theta and, for
    prismatic joints, d include the joint offsets). ``modified``: Craig's convention (row i holds a_{i-1},
    alpha_{i-1})."""

    a: np.ndarray
    alpha: np.ndarray
    d: np.ndarray
    theta: np.ndarray
    base: np.ndarray
    flange: np.ndarray
    tool: np.ndarray
    modified: bool
    joint_types: tuple[str, ...]
    joint_names: tuple[str, ...]

    def to_model(self, name: str = "arm", **model_fields) -> ArmModel:
        return from_dh(self.a, self.alpha, self.d, self.theta, modified=self.modified, joint_types=self.joint_types,
                       flange=self.flange, name=name, base=self.base, tool=self.tool,
                       joint_names=self.joint_names, **model_fields)


# Consecutive axes closer to parallel than this (rad) use the parallel-axes convention (d_i = 0).
PARALLEL_RAD = 1e-9


def to_dh(model: ArmModel, *, modified: bool = False, max_length: float | None = None) -> DHTable:
    """The DH table of ``model``: its joint axis lines (at zero joint angle, offsets folded into theta or d) with
    the common normals between consecutive axes as x axes, and the base and flange transforms that make it
    reproduce the model exactly. Exactly parallel axes take the usual convention (the normal through the
    previous origin). Axes nearly but not exactly parallel (a calibrated model) put the common normal far
    away; when any length exceeds ``max_length`` (default 10 x the model's reach) the table is refused as
    ill-conditioned, naming the joints."""
    lines = _axis_lines(model)
    flange_line = (model.home[:3, 3], model.home[:3, 2])
    limit = max_length if max_length is not None else 10 * max(np.linalg.norm(model.home[:3, 3]), 1.0)
    frames = _frames(lines + [flange_line], model, modified, limit)
    a, alpha, d, theta = _parameters(frames, modified)
    o = model.offsets
    prismatic = np.array([t == PRISMATIC for t in model.joint_types])
    theta = np.where(prismatic, theta, theta + o)
    d = np.where(prismatic, d + o, d)
    # frames[0] is the DH frame {0}; the chain ends at frames[n] (standard) or at frame {n} (modified)
    end = frames[-1]
    return DHTable(a, alpha, d, theta, model.base @ frames[0], se3.inverse(end) @ model.home, model.tool,
                   modified, tuple(model.joint_types), tuple(model.joint_names))


def _axis_lines(model: ArmModel) -> list[tuple[np.ndarray, np.ndarray]]:
    """(point, unit direction) of every joint axis in the base frame at zero angle (prismatic: through the
    origin; its position is free)."""
    out = []
    for s, kind in zip(model.screws, model.joint_types):
        v, w = se3.split(s)
        out.append((np.zeros(3), v / np.linalg.norm(v)) if kind == PRISMATIC else (np.cross(w, v), w))
    return out


def _frames(lines, model, modified: bool, limit: float) -> list[np.ndarray]:
    """DH frames: standard: {0}..{n}, frame {i} with z on line i+1 and x on the normal from line i to i+1;
    modified: {0} = {1} then {1}..{n}, frame {i} with z on line i and x on the normal to line i+1. The last
    line is the flange's z axis."""
    n = len(lines) - 1
    p, z = lines[0]
    x0 = perpendicular(np.array([1.0, 0, 0]), z)
    origin = p + np.dot(-p, z) * z  # the point of line 1 closest to the base origin
    frames = [axis_frame(origin, x0, z)]
    for i in range(n):
        (pa, za), (pb, zb) = lines[i], lines[i + 1]
        prev = frames[-1]
        foot_a, foot_b, x = _common_normal(pa, za, pb, zb, prev[:3, 3], prev[:3, 0], model, i, limit)
        if modified:
            frames.append(axis_frame(foot_a, x, za))
        else:
            frames.append(axis_frame(foot_b, x, zb))
    if modified:
        frames[0] = frames[1].copy()  # {0} = {1} at zero angle: alpha_0 = a_0 = 0
        frames[0][:3, 3] = frames[1][:3, 3]
    return frames


def _common_normal(pa, za, pb, zb, o_prev, x_prev, model, i, limit):
    """Feet on lines a and b of their common normal, and its unit direction from a to b."""
    c = np.cross(za, zb)
    s = np.linalg.norm(c)
    if s < PARALLEL_RAD:  # parallel: the normal through the previous origin
        foot_a = pa + np.dot(o_prev - pa, za) * za
        r = pb - foot_a
        perp = r - np.dot(r, za) * za
        dist = np.linalg.norm(perp)
        x = perp / dist if dist > 1e-12 else x_prev
        return foot_a, foot_a + perp, x
    x = c / s
    # solve pa + t za + u x = pb + v zb for t, v
    A = np.column_stack([za, -zb, x])
    t, v, _ = np.linalg.solve(A, pb - pa)
    foot_a, foot_b = pa + t * za, pb + v * zb
    if max(abs(t), abs(v)) > limit:
        names = list(model.joint_names) + ["flange"]
        raise ModelError(
            f"arm '{model.name}': axes of {names[i]} and {names[i + 1]} are {np.degrees(np.arcsin(min(s, 1))):.3g} "
            f"deg from parallel, so their common normal lies {max(abs(t), abs(v)):.3g} m away: DH parameters "
            "would be ill-conditioned there (tiny changes move them by metres); export the URDF or the POE model "
            "instead")
    r = foot_b - foot_a
    if np.dot(r, x) < 0 and np.linalg.norm(r) > 1e-12:
        x = -x
    return foot_a, foot_b, x


def perpendicular(x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The unit vector along the part of ``x`` perpendicular to the unit ``z`` (y's part where x is along z)."""
    x = x - np.dot(x, z) * z
    if np.linalg.norm(x) < 1e-6:
        x = np.array([0.0, 1.0, 0.0]) - z[1] * z
    return x / np.linalg.norm(x)


def axis_frame(origin, x, z) -> np.ndarray:
    """The frame at ``origin`` with z axis ``z`` and x axis ``x`` made perpendicular to it."""
    x = perpendicular(x, z)
    return se3.make(np.column_stack([x, np.cross(z, x), z]), origin)


def _parameters(frames, modified: bool):
    """a, alpha, d, theta between consecutive frames (geometric, offsets not folded in)."""
    n = len(frames) - 1
    a, alpha, d, theta = (np.zeros(n) for _ in range(4))
    for i in range(n):
        F, G = frames[i], frames[i + 1]
        rel = se3.inverse(F) @ G
        if modified:  # A = Rx(alpha) Tx(a) Rz(theta) Tz(d)
            alpha[i] = np.arctan2(-rel[1, 2], rel[2, 2])
            a[i] = rel[0, 3]
            theta[i] = np.arctan2(-rel[0, 1], rel[0, 0])
            ca, sa = np.cos(alpha[i]), np.sin(alpha[i])
            d[i] = -sa * rel[1, 3] + ca * rel[2, 3]
        else:  # A = Rz(theta) Tz(d) Tx(a) Rx(alpha)
            theta[i] = np.arctan2(rel[1, 0], rel[0, 0])
            alpha[i] = np.arctan2(rel[2, 1], rel[2, 2])
            d[i] = rel[2, 3]
            a[i] = np.cos(theta[i]) * rel[0, 3] + np.sin(theta[i]) * rel[1, 3]
    return a, alpha, d, theta
