"""The tool point held in a socket, moved along its self-motion (kind ``socket``)."""

from __future__ import annotations

import numpy as np

from kincal._validate import as_array
from kincal.data import Dataset
from kincal.kinematics import Robot
from kincal.noise import Noise
from kincal.schema import LENGTH
from kincal.simulate.generators._clamped import explore_to_n, reachable_pose
from kincal.simulate.generators._tree import tip_readings, uncoupled_tip
from kincal.simulate.generators._common import (ARM, EXPLORE, WORKSPACE, Option, Progress, check_n, count_option,
                                                dataset_meta, exploration_stats, generator, known_option,
                                                noisy_readings, pick_arm, validation_set)
from kincal.simulate.ik import PositionConstraint
from kincal.simulate.truth import Truth

__all__ = ["generate_socket"]


@generator("socket", ARM, count_option(100), Option("p_world_socket", "point", LENGTH, doc="the socket (default: "
           "a point reached in many ways)"), known_option("socket"), WORKSPACE, EXPLORE)
def generate_socket(
    robot: Robot,
    arm: str | None = None,
    *,
    n: int = 100,
    rng: np.random.Generator | int | None = None,
    noise: Noise = Noise(),
    p_world_socket: np.ndarray | None = None,
    known_socket: bool = False,
    workspace: tuple | None = None,
    n_validation: int = 100,
    explore_options: dict | None = None,
    progress: Progress | None = None,
) -> tuple[Dataset, Truth, dict]:
    """The tool point (tool frame origin, e.g. a ball) held in a socket: position fixed, orientation free."""
    n, rng = check_n(n), np.random.default_rng(rng)
    arm, _ = pick_arm(robot, arm)
    model = uncoupled_tip(robot, arm, "socket")  # with the arms carrying it (a torso)
    if p_world_socket is None:
        p = reachable_pose(model, rng, workspace=workspace)[:3, 3]
    else:
        p = as_array(p_world_socket, "p_world_socket", (3,))
    options = {"momentum": 0.8, **(explore_options or {})}
    ex, pick = explore_to_n(PositionConstraint(model, p), n, rng, options, progress)
    q = ex.q[pick]
    ds = Dataset("socket", robot.name, (arm,), tip_readings(robot, arm, noisy_readings({arm: q}, noise, rng)[arm]), {},
                 {"p_world_socket": p} if known_socket else {}, "socket", dataset_meta("socket", noise))
    truth = Truth(robot, {"p_world_socket": p}, tip_readings(robot, arm, q), noise, {"generator": "socket", **exploration_stats(ex)})
    return ds, truth, validation_set(robot, (arm,), n_validation, rng)
