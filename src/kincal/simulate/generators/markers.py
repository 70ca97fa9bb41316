"""Marker positions on the tool measured by a tracker (kind ``markers``)."""

from __future__ import annotations

import numpy as np

from kincal._validate import as_array
from kincal.data import Dataset
from kincal.errors import DegenerateExperimentError
from kincal.kinematics import Robot
from kincal.lie import se3
from kincal.noise import Noise
from kincal.schema import LENGTH
from kincal.simulate.generators._common import (ARM, NOISE_FREE, WRENCH, Option, check_n, count_option,
                                                dataset_meta, generator, known_option, noisy_readings, pick_arm,
                                                pose_or, random_configurations)
from kincal.simulate.generators._payload import before_and_after, fixed_configurations, payload_wrenches
from kincal.simulate.generators._tracker import (random_markers, random_tracker_pose, tool_loads,
                                                 validation_loads)
from kincal.kinematics.tree import tip_model
from kincal.simulate.generators._tree import coupled_readings, hung_readings, tip_readings, true_tool_poses
from kincal.simulate.noise import tracker_points
from kincal.simulate.truth import Truth

__all__ = ["generate_markers"]


@generator("markers", ARM, count_option(50), count_option(3, "markers", "number of random markers"),
           Option("p_tool_marker", "points", LENGTH, argument="markers", doc="the markers, tool frame"),
           known_option("markers"), Option("T_world_tracker", "pose", LENGTH, doc="the tracker (default: random)"),
           known_option("tracker"), WRENCH,
           Option("configurations", "configurations", doc="fixed joint readings (replace the random draw and n)"),
           Option("payload", "payload", doc="a payload on the tool, each configuration measured before and after"))
def generate_markers(
    robot: Robot,
    arm: str | None = None,
    *,
    n: int = 50,
    rng: np.random.Generator | int | None = None,
    noise: Noise = Noise(),
    markers: int | np.ndarray = 3,
    known_markers: bool = False,
    T_world_tracker: np.ndarray | None = None,
    known_tracker: bool = False,
    n_validation: int = 100,
    margin: float = 0.05,
    wrench=None,
    configurations=None,
    payload: tuple[float, np.ndarray] | None = None,
) -> tuple[Dataset, Truth, dict]:
    """Positions of markers on the tool seen by a tracker (partial pose): ``p_tracker_marker`` (N, m, 3).

    ``markers`` is a count (random offsets within 0.1 m of the tool origin) or ``p_tool_marker`` (m, 3).
    ``wrench``: loads on the tool (``wrench_tool``, applied to the tool by the environment, tool frame): a
    constant (6,) (force N, torque N m), one per sample (n, 6), or a magnitude in N for random loads
    (``random_wrenches``); the true poses are deflected with the true robot's compliance
    (``kincal.kinematics.elastic``) and the validation set carries loads too. Without it the draws, and so
    the outputs for a seed, are those of earlier versions.
    ``configurations`` (n, dof): these readings instead of random ones. ``payload`` ``(mass kg, centre of mass
    (3,) m, tool frame)``: each configuration measured twice at the same readings, unloaded then loaded by the
    payload's weight (``_payload``, seed 001 Sec. V); not with ``wrench``.
    """
    n, rng = check_n(n), np.random.default_rng(rng)
    arm, _ = pick_arm(robot, arm)
    model = tip_model(robot, arm)  # with the arms carrying it (a torso), whose readings the data set holds too
    p_tm = random_markers(int(markers), rng) if np.ndim(markers) == 0 else as_array(markers, "markers", (3,))
    if p_tm.ndim != 2 or len(p_tm) < 1:
        raise DegenerateExperimentError(f"markers: expected a count >= 1 or an (m, 3) array, got {markers!r}")
    T_wt = pose_or(T_world_tracker, "T_world_tracker", lambda: random_tracker_pose(robot, arm, rng))
    q = coupled_readings(model, random_configurations(model, n, rng, margin)) if configurations is None else \
        fixed_configurations(model, configurations)
    if payload is not None and wrench is not None:
        raise DegenerateExperimentError("payload and wrench_N: give one way of loading the tool")
    loads = tool_loads(wrench, len(q), rng) if payload is None else payload_wrenches(model, q, *payload)
    configs = q
    draw = lambda m, k: random_configurations(m, k, rng, margin)  # noqa: E731
    others = hung_readings(robot, arm, len(q), draw)  # the other arms loading the carriers (gravity on a tree)
    if payload is not None:
        q, loads = before_and_after(q, loads)
        others = {o: np.repeat(v, 2, axis=0) for o, v in others.items()}
    T = se3.inverse(T_wt) @ true_tool_poses(robot, arm, model, q, loads, others)
    p = se3.transform_points(T[:, None], p_tm[None])
    known = {}
    if known_tracker:
        known["T_world_tracker"] = T_wt
    if known_markers:
        known["p_tool_marker"] = p_tm
    measured = {"p_tracker_marker": tracker_points(p, noise, rng)}
    if loads is not None:
        measured["wrench_tool"] = loads
    readings = noisy_readings({arm: configs}, noise, rng)  # a configuration's two measurements share its readings
    if payload is not None:
        readings = {arm: np.repeat(readings[arm], 2, axis=0)}
    readings = {**tip_readings(robot, arm, readings[arm]), **noisy_readings(others, noise, rng)}
    ds = Dataset("markers", robot.name, (arm,), readings, measured, known, "markers",
                 dataset_meta("markers", noise))
    truth = Truth(robot, {"T_world_tracker": T_wt, "p_tool_marker": p_tm}, {**tip_readings(robot, arm, q), **others},
                  noise, {"generator": "markers"})
    # Validate what this experiment observes: marker positions at fresh configurations, noise-free, with the
    # tracker frame and marker offsets left unknown (refitted), not the world-frame tool pose (which a partial
    # pose measurement does not determine: the tracker gauge, and with one marker the tool orientation).
    qv = coupled_readings(model, random_configurations(model, n_validation, rng, margin))
    lv = validation_loads(wrench, loads, n_validation, rng) if payload is None else payload_wrenches(model, qv, *payload)
    ov = hung_readings(robot, arm, len(qv), draw)
    pv = se3.transform_points((se3.inverse(T_wt) @ true_tool_poses(robot, arm, model, qv, lv, ov))[:, None],
                              p_tm[None])
    mv = {"p_tracker_marker": pv} if lv is None else {"p_tracker_marker": pv, "wrench_tool": lv}
    validation = {arm: Dataset("markers", robot.name, (arm,), {**tip_readings(robot, arm, qv), **ov}, mv, {}, f"validation-{arm}",
                               {"noise_free": True, "noise": dict(NOISE_FREE)})}
    return ds, truth, validation
