"""One arm clamped at one fixture, moved along its self-motion (kind ``clamp``)."""

from __future__ import annotations

import logging

import numpy as np

from kincal.data import Dataset
from kincal.kinematics import Robot
from kincal.noise import Noise
from kincal.schema import LENGTH
from kincal.simulate.generators._clamped import explore_to_n, reachable_pose
from kincal.simulate.generators._tree import tip_readings, uncoupled_tip
from kincal.simulate.generators._common import (ARM, EXPLORE, WORKSPACE, Option, Progress, check_n, count_option,
                                                dataset_meta, exploration_stats, generator, known_option,
                                                noisy_readings, pick_arm, pose_or, validation_set)
from kincal.simulate.ik import PoseConstraint
from kincal.simulate.truth import Truth

__all__ = ["generate_clamp"]

log = logging.getLogger(__name__)


@generator("clamp", ARM, count_option(100), Option("T_world_fixture", "pose", LENGTH, doc="the fixture (default: "
           "a pose reached in many ways)"), known_option("fixture"), WORKSPACE, EXPLORE)
def generate_clamp(
    robot: Robot,
    arm: str | None = None,
    *,
    n: int = 100,
    rng: np.random.Generator | int | None = None,
    noise: Noise = Noise(),
    T_world_fixture: np.ndarray | None = None,
    known_fixture: bool = False,
    workspace: tuple | None = None,
    n_validation: int = 100,
    explore_options: dict | None = None,
    progress: Progress | None = None,
) -> tuple[Dataset, Truth, dict]:
    """One arm clamped at one fixture and moved by hand along its self-motion (thesis Sec. 3.3, one fixed point).

    ``T_world_fixture`` is the clamped tool pose; by default a pose the arm reaches in many ways
    (``reachable_pose``, tool inside the box ``workspace`` if given). ``explore_options`` go to
    ``selfmotion.explore`` (n_seeds, n_steps, step_rad, ...).
    """
    n, rng = check_n(n), np.random.default_rng(rng)
    arm, _ = pick_arm(robot, arm)
    model = uncoupled_tip(robot, arm, "clamp")  # with the arms carrying it (a torso)
    T_wf = pose_or(T_world_fixture, "T_world_fixture", lambda: reachable_pose(model, rng, workspace=workspace))
    ex, pick = explore_to_n(PoseConstraint(model, T_wf), n, rng, explore_options, progress)
    q = ex.q[pick]
    stats = exploration_stats(ex)
    log.info("clamp: %s", stats)
    ds = Dataset("clamp", robot.name, (arm,), tip_readings(robot, arm, noisy_readings({arm: q}, noise, rng)[arm]), {},
                 {"T_world_fixture": T_wf} if known_fixture else {}, "clamp", dataset_meta("clamp", noise))
    truth = Truth(robot, {"T_world_fixture": T_wf}, tip_readings(robot, arm, q), noise, {"generator": "clamp", **stats})
    return ds, truth, validation_set(robot, (arm,), n_validation, rng)
