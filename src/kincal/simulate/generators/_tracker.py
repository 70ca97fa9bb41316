"""Shared parts of the tracker generators (pose, markers): tracker placement, markers, loads on the tool."""

from __future__ import annotations

import numpy as np

from kincal._validate import as_array
from kincal.errors import ModelError
from kincal.kinematics import ArmModel, Robot, loaded_forward_kinematics
from kincal.kinematics.couplings import derive_readings
from kincal.kinematics.tree import tip_pose
from kincal.lie import se3, so3


def random_tracker_pose(robot: Robot, arm: str, rng: np.random.Generator, distance_m: float = 2.5) -> np.ndarray:
    """A tracker ``distance_m`` from the arm base (in the world: a mounted arm's through its carriers at their
    zero readings), roughly level with it, looking at it (z towards the arm)."""
    base = base_in_world(robot, arm)[:3, 3]
    az = rng.uniform(-np.pi, np.pi)
    p = base + np.array([distance_m * np.cos(az), distance_m * np.sin(az), rng.uniform(-0.2, 0.5)])
    z = (base - p) / np.linalg.norm(base - p)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z], axis=-1)
    return se3.make(so3.exp(rng.normal(0, 0.05, 3)) @ R, p)


def base_in_world(robot: Robot, arm: str) -> np.ndarray:
    """``T_world_base`` of ``arm``: its ``base``, or for a mounted arm its base through its carriers at their zero
    readings (clipped into their limits, couplings derived)."""
    line = robot.lineage(arm)
    if len(line) == 1:
        return robot[arm].base
    zeros = {a: derive_readings(robot[a].couplings, robot[a].joint_names,
                                np.clip(np.zeros((1, robot[a].dof)), robot[a].lower, robot[a].upper))
             for a in line[:-1]}
    return tip_pose(robot, line[-2], zeros)[0] @ robot[arm].base


def random_markers(m: int, rng: np.random.Generator, radius_m: float = 0.1) -> np.ndarray:
    """m marker positions on the tool (m, 3), spread on a sphere of ``radius_m`` around the tool origin."""
    d = rng.normal(size=(m, 3))
    return radius_m * d / np.linalg.norm(d, axis=-1, keepdims=True)


def random_wrenches(n: int, magnitude: float, rng: np.random.Generator, lever_m: float = 0.2) -> np.ndarray:
    """n loads on the tool (n, 6): a force of ``magnitude`` N in a uniformly random direction acting at a random
    point within ``lever_m`` of the tool origin, as (force, torque = r x force) in the tool frame."""
    d = rng.normal(size=(n, 3))
    f = magnitude * d / np.linalg.norm(d, axis=-1, keepdims=True)
    r = rng.uniform(-lever_m, lever_m, (n, 3))
    return np.concatenate([f, np.cross(r, f)], axis=-1)


def tool_loads(wrench, n: int, rng) -> np.ndarray | None:
    """``wrench`` (None, a magnitude in N, a constant (6,) or per-sample (n, 6)) as (n, 6) loads, or None."""
    if wrench is None:
        return None
    if np.ndim(wrench) == 0:
        if not (np.isfinite(wrench) and wrench > 0):
            raise ModelError(f"wrench: expected a load magnitude > 0 (N), a (6,) or an (n, 6) array, got {wrench!r}")
        return random_wrenches(n, float(wrench), rng)
    w = as_array(wrench, "wrench", (6,))
    if w.shape not in ((6,), (n, 6)):
        raise ModelError(f"wrench: expected shape (6,) or ({n}, 6) (force N, torque N m, tool frame), got {w.shape}")
    return np.array(np.broadcast_to(w, (n, 6)))


def validation_loads(wrench, loads, n: int, rng) -> np.ndarray | None:
    """Loads for validation samples: fresh random ones of the same magnitude, the constant, or rows of the given."""
    if loads is None:
        return None
    if np.ndim(wrench) == 0 or np.shape(wrench) == (6,):
        return tool_loads(wrench, n, rng)
    return loads[rng.integers(0, len(loads), n)]


def tool_poses(model: ArmModel, q, loads) -> np.ndarray:
    """True tool poses: deflected by the loads and the arm's own weight (with the model's compliance) when there
    are loads or the model has a mass model and gravity."""
    return loaded_forward_kinematics(model, q, loads)
