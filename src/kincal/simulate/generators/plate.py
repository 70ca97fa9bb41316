"""One arm clamped in turn at the fixtures of a plate (kind ``plate``)."""

from __future__ import annotations

import numpy as np

from kincal._validate import check_transform
from kincal.data import Dataset
from kincal.errors import DegenerateExperimentError
from kincal.kinematics import Robot
from kincal.lie import se3, so3
from kincal.noise import Noise
from kincal.schema import LENGTH
from kincal.simulate.generators._clamped import candidate_poses, explore_to_n
from kincal.simulate.generators._tree import tip_readings, uncoupled_tip
from kincal.simulate.generators._common import (ARM, EXPLORE, WORKSPACE, Option, Progress, check_n, count_option,
                                                dataset_meta, exploration_stats, generator, known_option,
                                                noisy_readings, pick_arm, pose_or, random_configurations,
                                                validation_set)
from kincal.simulate.ik import PoseConstraint, solve
from kincal.simulate.truth import Truth

__all__ = ["generate_plate", "plate_layout"]


def plate_layout(spacing_m: float = 0.2, tilt_rad: float = np.deg2rad(15.0)) -> np.ndarray:
    """Four fixtures at the corners of a square plate (side ``spacing_m``), ``T_plate_fixture`` (4, 4, 4).

    Plate frame: centre of the plate, z along its normal. Each fixture is a tool-changer on a block that
    turns it by k * 90 deg about the normal and tilts it by ``tilt_rad``, with the tool's z axis pointing into
    the plate; different orientations make offsets of the first and last joints identifiable (thesis Sec. 3.3).
    """
    h = spacing_m / 2
    corners = np.array([[h, h, 0.0], [-h, h, 0.0], [-h, -h, 0.0], [h, -h, 0.0]])
    flip = so3.exp(np.array([np.pi, 0.0, 0.0]))
    R = np.stack(
        [so3.exp(np.array([0, 0, k * np.pi / 2])) @ so3.exp(np.array([0, tilt_rad, 0])) @ flip for k in range(4)]
    )
    return se3.make(R, corners)


@generator("plate", ARM, count_option(160), Option("T_plate_fixture", "poses", LENGTH, doc="the fixtures "
           "(default: plate_layout())"), Option("T_world_plate", "pose", LENGTH, doc="the plate (default: placed "
           "where every fixture is reached in many ways)"), known_option("plate"), WORKSPACE, EXPLORE)
def generate_plate(
    robot: Robot,
    arm: str | None = None,
    *,
    n: int = 160,
    rng: np.random.Generator | int | None = None,
    noise: Noise = Noise(),
    T_plate_fixture: np.ndarray | None = None,
    T_world_plate: np.ndarray | None = None,
    known_plate: bool = False,
    workspace: tuple | None = None,
    n_validation: int = 100,
    explore_options: dict | None = None,
    progress: Progress | None = None,
    candidates: int = 30,
) -> tuple[Dataset, Truth, dict]:
    """One arm clamped in turn at K fixtures of a rigid plate with known ``T_plate_fixture`` (K, 4, 4).

    Default layout: ``plate_layout()`` (4 fixtures). Without ``T_world_plate`` the plate is placed where the
    arm reaches every fixture in several ways within its limits (best of ``candidates`` placements, first
    fixture inside the box ``workspace`` if given).
    Samples are split evenly over the fixtures, fixture by fixture; ``measured["fixture"]`` holds the index.
    """
    n, rng = check_n(n), np.random.default_rng(rng)
    arm, _ = pick_arm(robot, arm)
    model = uncoupled_tip(robot, arm, "plate")  # with the arms carrying it (a torso)
    T_pf = plate_layout() if T_plate_fixture is None else check_transform(T_plate_fixture, "T_plate_fixture", 1e-6)
    if T_pf.ndim != 3 or len(T_pf) < 1:
        raise DegenerateExperimentError(f"T_plate_fixture: expected (K, 4, 4) with K >= 1, got {T_pf.shape}")
    K = len(T_pf)
    if n < K:
        raise DegenerateExperimentError(f"n: {K} fixtures need at least {K} samples, got {n}")
    T_wp = pose_or(T_world_plate, "T_world_plate", lambda: _place_plate(model, T_pf, rng, candidates, workspace))
    counts = np.full(K, n // K)
    counts[: n % K] += 1
    qs, fixture, stats = [], [], []
    for k in range(K):
        ex, pick = explore_to_n(PoseConstraint(model, T_wp @ T_pf[k]), int(counts[k]), rng, explore_options, progress)
        qs.append(ex.q[pick])
        fixture.append(np.full(len(pick), k))
        stats.append(exploration_stats(ex))
    q = np.concatenate(qs)
    known = {"T_plate_fixture": T_pf}
    if known_plate:
        known["T_world_plate"] = T_wp
    ds = Dataset("plate", robot.name, (arm,), tip_readings(robot, arm, noisy_readings({arm: q}, noise, rng)[arm]),
                 {"fixture": np.concatenate(fixture)}, known, "plate", dataset_meta("plate", noise))
    truth = Truth(robot, {"T_world_plate": T_wp, "T_plate_fixture": T_pf}, tip_readings(robot, arm, q), noise,
                  {"generator": "plate", "fixtures": stats})
    return ds, truth, validation_set(robot, (arm,), n_validation, rng)


def _place_plate(model, T_pf, rng, candidates, workspace):
    """Plate pose maximizing the fewest distinct IK solutions over its fixtures."""
    best, best_score = None, -1
    for T0 in candidate_poses(model, candidates, rng, 0.2, workspace):
        T_wp = T0 @ se3.inverse(T_pf[0])
        score = np.inf
        for T_pk in T_pf:
            res = solve(PoseConstraint(model, T_wp @ T_pk), random_configurations(model, 24, rng), max_iter=60)
            score = min(score, np.unique(np.round(res.q, 2), axis=0).shape[0])
            if score <= best_score:
                break
        if score > best_score:
            best, best_score = T_wp, score
        if best_score >= 6:
            break
    if best_score < 1:
        raise DegenerateExperimentError("plate: found no placement where the arm reaches every fixture")
    return best
