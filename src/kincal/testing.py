"""Helpers for checking analytic Jacobians: central differences taken through the manifold, random arms."""

from __future__ import annotations

from typing import Callable

import numpy as np

from kincal.kinematics.model import PRISMATIC, REVOLUTE, ArmModel
from kincal.lie import se3, so3


def numerical_jacobian(
    fun: Callable[[np.ndarray], np.ndarray],
    x: np.ndarray,
    step: float = 1e-6,
    minus: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    order: int = 2,
) -> np.ndarray:
    """Central-difference Jacobian of ``fun`` at ``x`` (p,), batch-first: (..., k, p).

    ``minus(a, b)`` gives local coordinates of a relative to b (default ``a - b``); for poses use
    ``pose_minus`` so the difference is the error twist ``log(a b^-1)``. ``order`` 4: the five-point stencil
    (error of order ``step^4``), for functions curved enough that ``step^2`` shows (strong deflections).
    """
    x = np.asarray(x, dtype=float)
    minus = (lambda a, b: a - b) if minus is None else minus
    f0 = fun(x)

    def diff(e):
        return minus(fun(x + e), f0) - minus(fun(x - e), f0)

    cols = []
    for k in range(x.size):
        e = np.zeros_like(x)
        e[k] = step
        d = diff(e) / (2 * step)
        cols.append(d if order == 2 else (4 * d - diff(2 * e) / (4 * step)) / 3)
    return np.stack(cols, axis=-1)


def pose_minus(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Space error twist ``log(a b^-1)`` of poses (..., 4, 4) -> (..., 6)."""
    return se3.log(a @ se3.inverse(b))


def random_pose(rng: np.random.Generator, batch: tuple[int, ...] = (), scale: float = 0.5) -> np.ndarray:
    w = rng.normal(size=batch + (3,))
    w *= rng.uniform(0, np.pi, size=batch + (1,)) / np.linalg.norm(w, axis=-1, keepdims=True)
    return se3.make(so3.exp(w), rng.uniform(-scale, scale, size=batch + (3,)))


def random_arm(rng: np.random.Generator, n: int = 6, prismatic: tuple[int, ...] = (), name: str = "arm") -> ArmModel:
    """A random arm with generic joint axes, random base, home and tool poses, and small offsets."""
    screws = np.empty((n, 6))
    for i in range(n):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        if i in prismatic:
            screws[i] = se3.join(d, np.zeros(3))
        else:
            p = rng.uniform(-0.5, 0.5, size=3)
            screws[i] = se3.join(-np.cross(d, p), d)
    types = tuple(PRISMATIC if i in prismatic else REVOLUTE for i in range(n))
    return ArmModel(
        name,
        screws,
        random_pose(rng),
        base=random_pose(rng),
        tool=random_pose(rng, scale=0.1),
        offsets=rng.uniform(-0.05, 0.05, size=n),
        joint_types=types,
    )
