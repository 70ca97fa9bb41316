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

import numpy as np

from kincal.errors import ShapeError
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
