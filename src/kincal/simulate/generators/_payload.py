"""Fixed configurations and a payload hung on the tool, measured before and after loading (seed 001 Sec. V).

The paper's elastostatic experiment: at each configuration the markers are measured twice, without and with a
250 kg payload on the tool, at the same joint readings (the controller holds the motors; the joints yield).
Loads are the payload's weight, ``m g`` pointing down the world z axis, acting at its centre of mass ``c``
(tool frame): ``wrench_tool = (f, c x f)`` with ``f = R_world_tool^T (0, 0, -m g)`` at the unloaded pose, as a
known load is stated in the data (``kincal.kinematics.elastic``: applied TO the tool, at the tool origin).
"""

from __future__ import annotations

import numpy as np

from kincal.errors import ModelError
from kincal.kinematics import ArmModel, forward_kinematics

GRAVITY = 9.80665  # m/s^2, along -z of the world frame


def payload_wrenches(model: ArmModel, q: np.ndarray, mass_kg: float, com_tool: np.ndarray) -> np.ndarray:
    """(n, 6) tool-frame loads of a payload of ``mass_kg`` at ``com_tool`` (m) under gravity at readings q."""
    R = forward_kinematics(model, q)[:, :3, :3]
    f = np.einsum("nji,j->ni", R, np.array([0.0, 0.0, -mass_kg * GRAVITY]))
    return np.concatenate([f, np.cross(np.asarray(com_tool, dtype=float), f)], axis=-1)


def fixed_configurations(model: ArmModel, q) -> np.ndarray:
    """The given readings (n, dof), checked against the model's joint limits."""
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != model.dof or len(q) < 1:
        raise ModelError(f"configurations: expected rows of {model.dof} joint values, got shape {q.shape}")
    bad = np.flatnonzero(~model.within_limits(q, 1e-9))
    if bad.size:
        raise ModelError(f"configurations[{bad[0]}]: outside the joint limits of '{model.name}'")
    return q


def before_and_after(q: np.ndarray, loads: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each configuration twice, unloaded then loaded: readings (2n, dof) and loads (2n, 6)."""
    return np.repeat(q, 2, axis=0), np.stack([np.zeros_like(loads), loads], axis=1).reshape(-1, 6)
