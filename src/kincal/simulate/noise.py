"""Simulated measurement noise (``kincal.noise.Noise``): joint encoders (with optional backlash) and trackers.

Backlash is a dead band of width ``b`` between motor and link: the encoder sits on the motor, and the link
lags it by ``b / 2`` against the direction of motion, so the reading is ``link + sign(motion) b / 2``.
The direction of a joint is the sign of its last non-zero move along the path the samples were taken in
(a joint that does not move keeps its previous direction; before the first move it is drawn at random).
"""

from __future__ import annotations

import numpy as np

from kincal.lie import se3, so3
from kincal.noise import NONE, Noise


NO_NOISE = NONE


def backlash_offsets(q_path: np.ndarray, width: float, rng: np.random.Generator) -> np.ndarray:
    """Reading minus link position, ``+-width/2`` per sample and joint, from the motion along ``q_path`` (N, n)."""
    N, n = q_path.shape
    step = np.sign(np.diff(q_path, axis=0))
    start = rng.choice([-1.0, 1.0], size=(1, n))
    moves = np.concatenate([start, step], axis=0)
    # carry the last non-zero direction forward (vectorized forward fill)
    idx = np.where(moves != 0, np.arange(N)[:, None], 0)
    np.maximum.accumulate(idx, axis=0, out=idx)
    return 0.5 * width * np.take_along_axis(moves, idx, axis=0)


def joint_readings(q_true_readings: np.ndarray, noise: Noise, rng: np.random.Generator) -> np.ndarray:
    """What the controller reports for noise-free readings (N, n) taken in path order."""
    q = np.array(q_true_readings, dtype=float)
    if noise.backlash:
        q += backlash_offsets(q, noise.backlash, rng)
    if noise.joint:
        q += rng.normal(0.0, noise.joint, q.shape)
    return q


def tracker_points(p: np.ndarray, noise: Noise, rng: np.random.Generator) -> np.ndarray:
    """Tracker positions (..., 3) with isotropic Gaussian noise of ``position`` per axis."""
    return p + rng.normal(0.0, noise.position, p.shape) if noise.position else np.array(p, dtype=float)


def tracker_poses(T: np.ndarray, noise: Noise, rng: np.random.Generator) -> np.ndarray:
    """Full poses (N, 4, 4): position noise ``position`` per axis; rotation ``exp(w) R``, w ~ N(0, tracker_rad^2 I)."""
    T = np.array(T, dtype=float)
    if noise.orientation:
        T[..., :3, :3] = so3.exp(rng.normal(0.0, noise.orientation, T.shape[:-2] + (3,))) @ T[..., :3, :3]
    if noise.position:
        T[..., :3, 3] += rng.normal(0.0, noise.position, T.shape[:-2] + (3,))
    return se3.make(T[..., :3, :3], T[..., :3, 3])
