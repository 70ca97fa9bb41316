"""Full tool poses measured by a tracker (kind ``pose``)."""

from __future__ import annotations

import numpy as np

from kincal.data import Dataset
from kincal.kinematics import Robot
from kincal.lie import se3
from kincal.noise import Noise
from kincal.schema import LENGTH
from kincal.simulate.generators._common import (ARM, WRENCH, check_n, count_option, dataset_meta, generator,
                                                known_option, noisy_readings, Option, pick_arm, pose_or,
                                                random_configurations, validation_set)
from kincal.simulate.generators._tracker import random_tracker_pose, tool_loads
from kincal.kinematics.tree import tip_model
from kincal.simulate.generators._tree import coupled_readings, hung_readings, tip_readings, true_tool_poses
from kincal.simulate.noise import tracker_poses
from kincal.simulate.truth import Truth

__all__ = ["generate_pose"]


@generator("pose", ARM, count_option(50),
           Option("T_world_tracker", "pose", LENGTH, doc="the tracker (default: random)"), known_option("tracker"),
           WRENCH)
def generate_pose(
    robot: Robot,
    arm: str | None = None,
    *,
    n: int = 50,
    rng: np.random.Generator | int | None = None,
    noise: Noise = Noise(),
    T_world_tracker: np.ndarray | None = None,
    known_tracker: bool = False,
    n_validation: int = 100,
    margin: float = 0.05,
    wrench=None,
) -> tuple[Dataset, Truth, dict]:
    """Full tool pose measured by a tracker in its own frame: measured ``T_tracker_tool`` (N, 4, 4).

    Configurations are uniform within the limits shrunk by ``margin`` of each span; the tracker is placed
    by ``random_tracker_pose`` unless given. ``wrench``: loads on the tool (see ``generate_markers``).
    """
    n, rng = check_n(n), np.random.default_rng(rng)
    arm, _ = pick_arm(robot, arm)
    model = tip_model(robot, arm)  # with the arms carrying it (a torso), whose readings the data set holds too
    T_wt = pose_or(T_world_tracker, "T_world_tracker", lambda: random_tracker_pose(robot, arm, rng))
    q = coupled_readings(model, random_configurations(model, n, rng, margin))
    loads = tool_loads(wrench, n, rng)
    others = hung_readings(robot, arm, n, lambda m, k: random_configurations(m, k, rng, margin))  # gravity on a tree
    T = se3.inverse(T_wt) @ true_tool_poses(robot, arm, model, q, loads, others)
    measured = {"T_tracker_tool": tracker_poses(T, noise, rng)}
    if loads is not None:
        measured["wrench_tool"] = loads
    readings = {**tip_readings(robot, arm, noisy_readings({arm: q}, noise, rng)[arm]), **noisy_readings(others, noise, rng)}
    ds = Dataset("pose", robot.name, (arm,), readings, measured,
                 {"T_world_tracker": T_wt} if known_tracker else {}, "pose", dataset_meta("pose", noise))
    truth = Truth(robot, {"T_world_tracker": T_wt}, {**tip_readings(robot, arm, q), **others}, noise,
                  {"generator": "pose"})
    return ds, truth, validation_set(robot, (arm,), n_validation, rng)
