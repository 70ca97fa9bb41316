"""Two arms clamped tool to tool, moved along the self-motion of the closed chain (kind ``dual``)."""

from __future__ import annotations

import numpy as np

from kincal._validate import check_transform
from kincal.data import Dataset
from kincal.errors import DegenerateExperimentError
from kincal.kinematics import Robot, forward_kinematics
from kincal.lie import se3, so3
from kincal.noise import Noise
from kincal.schema import LENGTH
from kincal.simulate.generators._common import (EXPLORE, WORKSPACE, Option, Progress, check_n, count_option,
                                                dataset_meta, exploration_stats, generator, known_option,
                                                noisy_readings, validation_set)
from kincal.simulate.generators._tree import SharedClosedChain, split, with_couplings
from kincal.simulate.selfmotion import explore, pick_evenly
from kincal.simulate.truth import Truth

__all__ = ["BRACKET_90", "generate_dual"]


# Thesis Figure 3.5: two tool changers on a 90-degree L-bracket. Arm B's tool frame sits 0.10 m along
# x and 0.10 m along z of arm A's tool frame, turned -90 degrees about y, so z_B = -x_A (each tool's z
# axis points into its own face of the bracket) and y_B = y_A.
BRACKET_90 = se3.make(so3.exp(np.array([0.0, -np.pi / 2, 0.0])), np.array([0.10, 0.0, 0.10]))


@generator("dual", Option("arms", "arms", default=("left", "right"), doc="arm A and arm B"), count_option(200),
           Option("clamp", "pose", LENGTH, doc="T_toolA_toolB (default: BRACKET_90)"), known_option("clamp", True),
           WORKSPACE, EXPLORE)
def generate_dual(
    robot: Robot,
    arms: tuple[str, str] = ("left", "right"),
    *,
    n: int = 200,
    rng: np.random.Generator | int | None = None,
    noise: Noise = Noise(),
    clamp: np.ndarray | None = None,
    known_clamp: bool = True,
    workspace: tuple | None = None,
    n_validation: int = 100,
    explore_options: dict | None = None,
    progress: Progress | None = None,
) -> tuple[Dataset, Truth, dict]:
    """Two arms clamped tool to tool by ``clamp`` = ``T_toolA_toolB`` (default ``BRACKET_90``), moved by hand.

    Both arms are solved jointly (``ClosedChainConstraint``) and walked along the 8-dimensional (7+7 DOF)
    self-motion of the closed chain; arms mounted on a torso (``Robot.mounts``) move it too (its readings are
    in the data set). ``workspace = (lower (3,), upper (3,))`` optionally keeps arm A's tool
    inside a box in the world frame (e.g. in front of the robot).
    """
    n, rng = check_n(n), np.random.default_rng(rng)
    a, b = arms
    C = BRACKET_90 if clamp is None else check_transform(clamp, "clamp", 1e-6)
    constraint = SharedClosedChain(robot, a, b, C)  # arms on a torso: the torso moves with them
    accept = None
    if workspace is not None:
        lo, hi = (np.asarray(w, dtype=float) for w in workspace)

        def accept(qq):
            p = forward_kinematics(constraint.inner.model_a, constraint.tip_a(qq))[:, :3, 3]
            return np.all((p >= lo) & (p <= hi), axis=-1)

    # a workspace rejects most random starts: try more of them
    opts = {"n_seeds": 64 if accept is None else 192, "n_steps": max(40, 3 * n // 64), "momentum": 0.8,
            "accept": accept, **(explore_options or {})}
    ex = explore(constraint, rng, progress=progress, **opts)
    if ex.q.shape[0] < n:
        raise DegenerateExperimentError(
            f"dual: self-motion gave {ex.q.shape[0]} distinct configurations, {n} asked; raise n_seeds or n_steps"
        )
    q = ex.q[pick_evenly(ex.q.shape[0], n)]
    q_clean = split(robot, constraint.names, q)
    stats = exploration_stats(ex)
    ds = Dataset("dual", robot.name, (a, b), with_couplings(robot, noisy_readings(q_clean, noise, rng)), {},
                 {"T_toolA_toolB": C} if known_clamp else {}, "dual", dataset_meta("dual", noise))
    truth = Truth(robot, {"T_toolA_toolB": C}, q_clean, noise, {"generator": "dual", **stats})
    return ds, truth, validation_set(robot, (a, b), n_validation, rng)
