"""Rotation parametrizations used at the edges (files, CLI, URDF): roll-pitch-yaw and unit quaternions.

- rpy ``(r, p, y)``: ``R = Rz(y) @ Ry(p) @ Rx(r)`` (fixed axes x, then y, then z; URDF's convention).
- quaternion ``(w, x, y, z)``, scalar first, Hamilton convention; returned with ``w >= 0``.
Inside kincal rotations are matrices; these helpers only convert. Batch-first like the Lie layer.
"""

from __future__ import annotations

import numpy as np


def rpy_to_matrix(rpy) -> np.ndarray:
    """(..., 3) roll, pitch, yaw (rad) -> (..., 3, 3)."""
    rpy = np.asarray(rpy, dtype=float)
    cr, cp, cy = np.cos(rpy[..., 0]), np.cos(rpy[..., 1]), np.cos(rpy[..., 2])
    sr, sp, sy = np.sin(rpy[..., 0]), np.sin(rpy[..., 1]), np.sin(rpy[..., 2])
    R = np.empty(rpy.shape[:-1] + (3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp * sr - sy * cr
    R[..., 0, 2] = cy * sp * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp * sr + cy * cr
    R[..., 1, 2] = sy * sp * cr - cy * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def matrix_to_rpy(R) -> np.ndarray:
    """(..., 3, 3) -> (..., 3) roll, pitch, yaw with pitch in [-pi/2, pi/2].

    At gimbal lock (|pitch| = pi/2) only roll - yaw (or roll + yaw) is defined; yaw is set to 0.
    """
    R = np.asarray(R, dtype=float)
    cos_p = np.hypot(R[..., 0, 0], R[..., 1, 0])
    pitch = np.arctan2(-R[..., 2, 0], cos_p)
    lock = cos_p < 1e-12
    # at lock R = Ry(+-pi/2) Rx(r): R[0, 1] = +-sin r, R[1, 1] = cos r
    roll = np.where(
        lock, np.arctan2(np.sign(-R[..., 2, 0]) * R[..., 0, 1], R[..., 1, 1]), np.arctan2(R[..., 2, 1], R[..., 2, 2])
    )
    yaw = np.where(lock, 0.0, np.arctan2(R[..., 1, 0], R[..., 0, 0]))
    return np.stack([roll, pitch, yaw], axis=-1)


def quat_wxyz_to_matrix(q) -> np.ndarray:
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3, 3). The caller checks the norm."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def matrix_to_quat_wxyz(R) -> np.ndarray:
    """(..., 3, 3) rotations -> (..., 4) unit quaternions (w, x, y, z) with w >= 0.

    Uses the largest of the four diagonal combinations as pivot (Shepperd), so it is accurate near pi.
    """
    R = np.asarray(R, dtype=float)
    batch = R.shape[:-2]
    R = R.reshape(-1, 3, 3)
    tr = np.trace(R, axis1=-2, axis2=-1)
    k = np.argmax(np.stack([tr, R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], axis=-1), axis=-1)
    q = np.empty((len(R), 4))
    for case in range(4):
        m = k == case
        r = R[m]
        if case == 0:
            s = 2 * np.sqrt(1.0 + tr[m])
            v = [0.25 * s, (r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s, (r[:, 1, 0] - r[:, 0, 1]) / s]
        elif case == 1:
            s = 2 * np.sqrt(1.0 + r[:, 0, 0] - r[:, 1, 1] - r[:, 2, 2])
            v = [(r[:, 2, 1] - r[:, 1, 2]) / s, 0.25 * s, (r[:, 0, 1] + r[:, 1, 0]) / s, (r[:, 0, 2] + r[:, 2, 0]) / s]
        elif case == 2:
            s = 2 * np.sqrt(1.0 + r[:, 1, 1] - r[:, 0, 0] - r[:, 2, 2])
            v = [(r[:, 0, 2] - r[:, 2, 0]) / s, (r[:, 0, 1] + r[:, 1, 0]) / s, 0.25 * s, (r[:, 1, 2] + r[:, 2, 1]) / s]
        else:
            s = 2 * np.sqrt(1.0 + r[:, 2, 2] - r[:, 0, 0] - r[:, 1, 1])
            v = [(r[:, 1, 0] - r[:, 0, 1]) / s, (r[:, 0, 2] + r[:, 2, 0]) / s, (r[:, 1, 2] + r[:, 2, 1]) / s, 0.25 * s]
        q[m] = np.stack(v, axis=-1)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[:, :1] < 0, -q, q)
    return q.reshape(batch + (4,))
