"""A calibrated pinhole camera sees one point on the tool at random configurations (kind ``camera``).

A mounted arm (``Robot.mounts``) is simulated through its composite chain (``kincal.kinematics.tree.tip_model``):
its carriers (a torso) move too, their readings are in the data set, and on a tree with gravity the tool sags
under the whole tree's weight (``_tree.true_tool_poses``)."""

from __future__ import annotations

import numpy as np

from kincal._validate import as_array
from kincal.data import Dataset
from kincal.errors import DegenerateExperimentError
from kincal.experiments.camera import project
from kincal.kinematics import Robot, forward_kinematics
from kincal.kinematics.tree import tip_model
from kincal.lie import se3
from kincal.noise import PIXEL, Noise
from kincal.schema import LENGTH, NONE
from kincal.simulate.generators._common import (ARM, Option, check_n, count_option, dataset_meta, generator,
                                                known_option, noisy_readings, pick_arm, pose_or,
                                                random_configurations)
from kincal.simulate.generators._tracker import random_markers, random_tracker_pose
from kincal.simulate.generators._tree import coupled_readings, hung_readings, tip_readings, true_tool_poses
from kincal.simulate.truth import Truth

__all__ = ["CAMERA_INTRINSICS", "generate_camera"]

CAMERA_INTRINSICS = (800.0, 800.0, 640.0, 480.0)  # fx, fy, cx, cy (px) of a 1280 x 960 image, 77 deg across
_MIN_DEPTH_M = 0.1


@generator("camera", ARM, count_option(60),
           Option("T_world_camera", "pose", LENGTH, doc="the camera, z along the optical axis (default: 2.5 m from "
                  "the arm's base, looking at it)"), known_option("camera"),
           Option("p_tool_point", "point", LENGTH, doc="the point, tool frame (default: random within 0.1 m)"),
           known_option("point"),
           Option("intrinsics", "vector", NONE, CAMERA_INTRINSICS, size=4, doc="[fx, fy, cx, cy] (px)"),
           Option("image", "vector", NONE, (1280.0, 960.0), size=2, doc="image width and height (px)"))
def generate_camera(
    robot: Robot,
    arm: str | None = None,
    *,
    n: int = 60,
    rng: np.random.Generator | int | None = None,
    noise: Noise = Noise(),
    T_world_camera: np.ndarray | None = None,
    known_camera: bool = False,
    p_tool_point: np.ndarray | None = None,
    known_point: bool = False,
    intrinsics=CAMERA_INTRINSICS,
    image=(1280.0, 960.0),
    n_validation: int = 100,
    margin: float = 0.05,
) -> tuple[Dataset, Truth, dict]:
    """Pixels (N, 2) of ``p_tool_point`` seen by a camera at ``T_world_camera`` with known ``intrinsics``, at
    random configurations (limits shrunk by ``margin``) that put the point in front of the camera and inside
    the image (``image`` = width, height in px). Pixel noise: ``noise.other["pixel"]`` (px)."""
    n, rng = check_n(n), np.random.default_rng(rng)
    arm, _ = pick_arm(robot, arm)
    model = tip_model(robot, arm)  # with the arms carrying it (a torso), whose readings the data set holds too
    K = as_array(intrinsics, "intrinsics", (4,))
    C = pose_or(T_world_camera, "T_world_camera", lambda: random_tracker_pose(robot, arm, rng))
    x = random_markers(1, rng)[0] if p_tool_point is None else as_array(p_tool_point, "p_tool_point", (3,))
    draw = lambda m, k: random_configurations(m, k, rng, margin)  # noqa: E731
    q = _views(model, n, rng, margin, C, x, K, np.asarray(image, dtype=float))
    others = hung_readings(robot, arm, len(q), draw)  # the other arms loading the carriers (gravity on a tree)
    uv = _pixels(robot, arm, model, q, others, C, x, K)
    sigma = noise.sigma(PIXEL)
    if sigma:
        uv = uv + rng.normal(0.0, sigma, uv.shape)
    known = {"intrinsics": K}
    if known_camera:
        known["T_world_camera"] = C
    if known_point:
        known["p_tool_point"] = x
    readings = {**tip_readings(robot, arm, noisy_readings({arm: q}, noise, rng)[arm]), **noisy_readings(others, noise, rng)}
    ds = Dataset("camera", robot.name, (arm,), readings, {"pixel": uv}, known, "camera", dataset_meta("camera", noise))
    truth = Truth(robot, {"T_world_camera": C, "p_tool_point": x}, {**tip_readings(robot, arm, q), **others}, noise,
                  {"generator": "camera"})
    # Validate what this experiment observes: noise-free pixels at fresh configurations, camera and point left
    # unknown (refitted); one point says nothing about the tool's orientation, which a pose set would score.
    qv = _views(model, n_validation, rng, margin, C, x, K, np.asarray(image, dtype=float))
    ov = hung_readings(robot, arm, len(qv), draw)
    validation = {arm: Dataset("camera", robot.name, (arm,), {**tip_readings(robot, arm, qv), **ov},
                               {"pixel": _pixels(robot, arm, model, qv, ov, C, x, K)},
                               {"intrinsics": K}, f"validation-{arm}",
                               {"noise_free": True, "noise": {"pixel_px": 0.0}})}
    return ds, truth, validation


def _pixels(robot, arm, model, q, others, C, x, K) -> np.ndarray:
    """Pixels of the point at the tip readings q (N, m) of ``model`` (the arm's tip model), the true tool poses
    sagging under the tree's weight where it has gravity (the other arms at ``others``)."""
    T = true_tool_poses(robot, arm, model, q, None, others)
    return project(se3.transform_points(se3.inverse(C) @ T, x), K)[0]


def _views(model, n, rng, margin, C, x, K, image) -> np.ndarray:
    """n random configurations whose point the camera sees (in front, inside the image)."""
    found = []
    for _ in range(50):
        q = coupled_readings(model, random_configurations(model, 4 * n, rng, margin))
        c = se3.transform_points(se3.inverse(C) @ forward_kinematics(model, q), x)
        uv = project(np.where(c[:, 2:] > _MIN_DEPTH_M, c, 1.0), K)[0]
        seen = (c[:, 2] > _MIN_DEPTH_M) & np.all((uv >= 0) & (uv <= image), axis=-1)
        found.append(q[seen])
        if sum(len(f) for f in found) >= n:
            return np.concatenate(found)[:n]
    raise DegenerateExperimentError(f"camera: the point is in view in {sum(len(f) for f in found)} of "
                                    f"{200 * n} random configurations, {n} asked; place the camera to see the arm")
