"""Experiment generators: a true robot in, ``(Dataset, Truth, validation)`` out.

Every generator

- solves the experiment's constraint on the *true* robot (``robot`` argument; make one with
  ``perturb_robot``), so the joint readings are ``true joint value - true offset`` (the model uses
  ``theta = q + offset``), within the joint limits;
- adds noise (``Noise``: encoder noise and backlash along the sample path, tracker noise);
- returns the ground truth (``Truth``) and a validation set: ``{arm: Dataset(kind="pose")}`` of fresh random
  configurations within the limits with the noise-free true tool poses (``T_world_tracker`` = identity);
- is deterministic for a given ``rng`` (numpy Generator or integer seed).

Nuisance quantities (fixture, plate, clamp, tracker, markers, socket) are always in ``Truth.values``; they
are in ``Dataset.known`` only when declared known.
"""

from __future__ import annotations

import logging
from typing import Callable

import numpy as np

from kincal._validate import as_array, check_transform
from kincal.data import Dataset
from kincal.errors import DegenerateExperimentError, ModelError
from kincal.kinematics import ArmModel, Robot, forward_kinematics, loaded_forward_kinematics
from kincal.lie import se3, so3
from kincal.simulate.ik import ClosedChainConstraint, PoseConstraint, PositionConstraint, solve
from kincal.simulate.noise import Noise, joint_readings, tracker_points, tracker_poses
from kincal.simulate.selfmotion import Exploration, explore, joint_spread, pick_evenly
from kincal.simulate.truth import Truth

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]

# Thesis Figure 3.5: two tool changers on a 90-degree L-bracket. Arm B's tool frame sits 0.10 m along
# x and 0.10 m along z of arm A's tool frame, turned -90 degrees about y, so z_B = -x_A (each tool's z
# axis points into its own face of the bracket) and y_B = y_A.
BRACKET_90 = se3.make(so3.exp(np.array([0.0, -np.pi / 2, 0.0])), np.array([0.10, 0.0, 0.10]))


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


# ---------------------------------------------------------------------------------------------- helpers


def _arm(robot: Robot, arm: str | None) -> tuple[str, ArmModel]:
    if arm is None:
        if len(robot.arms) != 1:
            raise ModelError(f"robot '{robot.name}' has arms {', '.join(robot.arms)}; name the arm to use")
        arm = next(iter(robot.arms))
    return arm, robot[arm]


def _finite_limits(model: ArmModel, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Limits shrunk by ``margin`` of their span (+-pi where a joint has no limit)."""
    lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
    hi = np.where(np.isfinite(model.upper), model.upper, np.pi)
    pad = margin * (hi - lo)
    return lo + pad, hi - pad


def random_configurations(model: ArmModel, n: int, rng: np.random.Generator, margin: float = 0.0) -> np.ndarray:
    """n readings uniform within the limits shrunk by ``margin`` of their span: (n, dof)."""
    lo, hi = _finite_limits(model, margin)
    return rng.uniform(lo, hi, (n, model.dof))


def validation_set(robot: Robot, arms, n: int, rng: np.random.Generator, name: str = "validation") -> dict:
    """``{arm: Dataset(kind="pose")}``: n fresh random configurations with noise-free true tool poses.

    The poses are given in the world frame, but the frame is not declared known: evaluating a model on this
    set first fits it (a best rigid registration, as a tracker of unknown pose would), so the score is the
    accuracy that a self-calibration can determine. Where the world frame itself is not observable (a clamp
    or plate of unknown pose, the common frame of two arms) a world-frame score would measure the gauge choice.
    """
    out = {}
    for a in arms:
        q = random_configurations(robot[a], n, rng)
        out[a] = Dataset(
            "pose", robot.name, (a,), {a: q},
            measured={"T_tracker_tool": forward_kinematics(robot[a], q)},
            name=f"{name}-{a}", meta={"noise_free": True, "frame": "world (registered when evaluated)"},
        )
    return out


def random_tracker_pose(robot: Robot, arm: str, rng: np.random.Generator, distance_m: float = 2.5) -> np.ndarray:
    """A tracker ``distance_m`` from the arm base, roughly level with it, looking at it (z towards the arm)."""
    base = robot[arm].base[:3, 3]
    az = rng.uniform(-np.pi, np.pi)
    p = base + np.array([distance_m * np.cos(az), distance_m * np.sin(az), rng.uniform(-0.2, 0.5)])
    z = (base - p) / np.linalg.norm(base - p)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z], axis=-1)
    return se3.make(so3.exp(rng.normal(0, 0.05, 3)) @ R, p)


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


def _loads(wrench, n: int, rng) -> np.ndarray | None:
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


def _validation_loads(wrench, loads, n: int, rng) -> np.ndarray | None:
    """Loads for validation samples: fresh random ones of the same magnitude, the constant, or rows of the given."""
    if loads is None:
        return None
    if np.ndim(wrench) == 0 or np.shape(wrench) == (6,):
        return _loads(wrench, n, rng)
    return loads[rng.integers(0, len(loads), n)]


def _tool_poses(model: ArmModel, q, loads) -> np.ndarray:
    """True tool poses: deflected by the loads (with the model's compliance) when there are loads."""
    return forward_kinematics(model, q) if loads is None else loaded_forward_kinematics(model, q, loads)


def _pose_or(T, name, default):
    """``T`` validated, or ``default()`` when T is None."""
    return default() if T is None else check_transform(T, name, 1e-6)


def _noisy(q_clean: dict, noise: Noise, rng) -> dict:
    return {a: joint_readings(q, noise, rng) for a, q in q_clean.items()}


def _stats(ex: Exploration) -> dict:
    return {
        "ik_starts": ex.n_seeds_tried,
        "ik_starts_rejected": ex.n_seeds_failed,
        "walk_steps_rejected": ex.n_steps_rejected,
        "duplicates_removed": ex.n_duplicates,
        "branches": ex.n_branches,
        "candidates": int(ex.q.shape[0]),
    }


def _meta(kind: str, noise: Noise, extra: dict | None = None) -> dict:
    return {"generator": kind, "noise": noise.as_si(), **(extra or {})}


def _check_n(n: int, name: str = "n") -> int:
    if int(n) != n or n < 1:
        raise DegenerateExperimentError(f"{name}: expected a positive number of samples, got {n!r}")
    return int(n)


# ------------------------------------------------------------------------------------ tracker experiments


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
    n, rng = _check_n(n), np.random.default_rng(rng)
    arm, model = _arm(robot, arm)
    T_wt = _pose_or(T_world_tracker, "T_world_tracker", lambda: random_tracker_pose(robot, arm, rng))
    q = random_configurations(model, n, rng, margin)
    loads = _loads(wrench, n, rng)
    T = se3.inverse(T_wt) @ _tool_poses(model, q, loads)
    measured = {"T_tracker_tool": tracker_poses(T, noise, rng)}
    if loads is not None:
        measured["wrench_tool"] = loads
    ds = Dataset("pose", robot.name, (arm,), _noisy({arm: q}, noise, rng), measured,
                 {"T_world_tracker": T_wt} if known_tracker else {}, "pose", _meta("pose", noise))
    truth = Truth(robot, {"T_world_tracker": T_wt}, {arm: q}, noise, {"generator": "pose"})
    return ds, truth, validation_set(robot, (arm,), n_validation, rng)


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
) -> tuple[Dataset, Truth, dict]:
    """Positions of markers on the tool seen by a tracker (partial pose): ``p_tracker_marker`` (N, m, 3).

    ``markers`` is a count (random offsets within 0.1 m of the tool origin) or ``p_tool_marker`` (m, 3).
    ``wrench``: loads on the tool (``wrench_tool``, applied to the tool by the environment, tool frame): a
    constant (6,) (force N, torque N m), one per sample (n, 6), or a magnitude in N for random loads
    (``random_wrenches``); the true poses are deflected with the true robot's compliance
    (``kincal.kinematics.elastic``) and the validation set carries loads too. Without it the draws, and so
    the outputs for a seed, are those of earlier versions.
    """
    n, rng = _check_n(n), np.random.default_rng(rng)
    arm, model = _arm(robot, arm)
    p_tm = random_markers(int(markers), rng) if np.ndim(markers) == 0 else as_array(markers, "markers", (3,))
    if p_tm.ndim != 2 or len(p_tm) < 1:
        raise DegenerateExperimentError(f"markers: expected a count >= 1 or an (m, 3) array, got {markers!r}")
    T_wt = _pose_or(T_world_tracker, "T_world_tracker", lambda: random_tracker_pose(robot, arm, rng))
    q = random_configurations(model, n, rng, margin)
    loads = _loads(wrench, n, rng)
    T = se3.inverse(T_wt) @ _tool_poses(model, q, loads)
    p = se3.transform_points(T[:, None], p_tm[None])
    known = {}
    if known_tracker:
        known["T_world_tracker"] = T_wt
    if known_markers:
        known["p_tool_marker"] = p_tm
    measured = {"p_tracker_marker": tracker_points(p, noise, rng)}
    if loads is not None:
        measured["wrench_tool"] = loads
    ds = Dataset("markers", robot.name, (arm,), _noisy({arm: q}, noise, rng), measured, known, "markers",
                 _meta("markers", noise))
    truth = Truth(robot, {"T_world_tracker": T_wt, "p_tool_marker": p_tm}, {arm: q}, noise, {"generator": "markers"})
    # Validate what this experiment observes: marker positions at fresh configurations, noise-free, with the
    # tracker frame and marker offsets left unknown (refitted), not the world-frame tool pose (which a partial
    # pose measurement does not determine: the tracker gauge, and with one marker the tool orientation).
    qv = random_configurations(model, n_validation, rng, margin)
    lv = _validation_loads(wrench, loads, n_validation, rng)
    pv = se3.transform_points((se3.inverse(T_wt) @ _tool_poses(model, qv, lv))[:, None], p_tm[None])
    mv = {"p_tracker_marker": pv} if lv is None else {"p_tracker_marker": pv, "wrench_tool": lv}
    validation = {arm: Dataset("markers", robot.name, (arm,), {arm: qv}, mv, {}, f"validation-{arm}",
                               {"noise_free": True})}
    return ds, truth, validation


# ------------------------------------------------------------------------------------- clamped experiments


def _explore_to_n(constraint, n, rng, explore_options, progress):
    opts = {"n_seeds": 64, "n_steps": max(60, 3 * n // 8), "margin_rad": 0.0, **(explore_options or {})}
    ex = explore(constraint, rng, progress=progress, **opts)
    if ex.q.shape[0] < n:
        raise DegenerateExperimentError(
            f"self-motion gave {ex.q.shape[0]} distinct configurations, {n} asked; raise n_seeds or n_steps"
        )
    return ex, pick_evenly(ex.q.shape[0], n)


def _candidate_poses(model, count, rng, margin, workspace):
    """Tool poses of random configurations (limits shrunk by ``margin``), inside ``workspace`` if given."""
    T = forward_kinematics(model, random_configurations(model, 20 * count if workspace else count, rng, margin))
    if workspace is not None:
        lo, hi = (np.asarray(w, dtype=float) for w in workspace)
        T = T[np.all((T[:, :3, 3] >= lo) & (T[:, :3, 3] <= hi), axis=-1)]
        if len(T) == 0:
            raise DegenerateExperimentError(f"workspace {workspace}: the arm '{model.name}' never reaches it")
    return T[:count]


def reachable_pose(
    model: ArmModel, rng: np.random.Generator, *, candidates: int = 20, margin: float = 0.2, min_solutions: int = 6,
    workspace: tuple | None = None,
) -> np.ndarray:
    """A tool pose the arm reaches in many ways within its limits (a place to bolt a fixture).

    Draws poses from configurations inside the limits (shrunk by ``margin``) with the tool inside the box
    ``workspace = (lower (3,), upper (3,))`` (world frame) if given; keeps the first with at least
    ``min_solutions`` distinct IK solutions from 24 random starts, else the one with the most.
    """
    best, best_count = None, -1
    for T in _candidate_poses(model, candidates, rng, margin, workspace):
        res = solve(PoseConstraint(model, T), random_configurations(model, 24, rng), max_iter=60)
        count = np.unique(np.round(res.q, 2), axis=0).shape[0]
        if count > best_count:
            best, best_count = T, count
        if count >= min_solutions:
            break
    return best


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
    n, rng = _check_n(n), np.random.default_rng(rng)
    arm, model = _arm(robot, arm)
    T_wf = _pose_or(T_world_fixture, "T_world_fixture", lambda: reachable_pose(model, rng, workspace=workspace))
    ex, pick = _explore_to_n(PoseConstraint(model, T_wf), n, rng, explore_options, progress)
    q = ex.q[pick]
    stats = _stats(ex)
    log.info("clamp: %s", stats)
    ds = Dataset("clamp", robot.name, (arm,), _noisy({arm: q}, noise, rng), {},
                 {"T_world_fixture": T_wf} if known_fixture else {}, "clamp", _meta("clamp", noise))
    truth = Truth(robot, {"T_world_fixture": T_wf}, {arm: q}, noise, {"generator": "clamp", **stats})
    return ds, truth, validation_set(robot, (arm,), n_validation, rng)


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
    n, rng = _check_n(n), np.random.default_rng(rng)
    arm, model = _arm(robot, arm)
    T_pf = plate_layout() if T_plate_fixture is None else check_transform(T_plate_fixture, "T_plate_fixture", 1e-6)
    if T_pf.ndim != 3 or len(T_pf) < 1:
        raise DegenerateExperimentError(f"T_plate_fixture: expected (K, 4, 4) with K >= 1, got {T_pf.shape}")
    K = len(T_pf)
    if n < K:
        raise DegenerateExperimentError(f"n: {K} fixtures need at least {K} samples, got {n}")
    T_wp = _pose_or(T_world_plate, "T_world_plate", lambda: _place_plate(model, T_pf, rng, candidates, workspace))
    counts = np.full(K, n // K)
    counts[: n % K] += 1
    qs, fixture, stats = [], [], []
    for k in range(K):
        ex, pick = _explore_to_n(PoseConstraint(model, T_wp @ T_pf[k]), int(counts[k]), rng, explore_options, progress)
        qs.append(ex.q[pick])
        fixture.append(np.full(len(pick), k))
        stats.append(_stats(ex))
    q = np.concatenate(qs)
    known = {"T_plate_fixture": T_pf}
    if known_plate:
        known["T_world_plate"] = T_wp
    ds = Dataset("plate", robot.name, (arm,), _noisy({arm: q}, noise, rng), {"fixture": np.concatenate(fixture)},
                 known, "plate", _meta("plate", noise))
    truth = Truth(robot, {"T_world_plate": T_wp, "T_plate_fixture": T_pf}, {arm: q}, noise,
                  {"generator": "plate", "fixtures": stats})
    return ds, truth, validation_set(robot, (arm,), n_validation, rng)


def _place_plate(model, T_pf, rng, candidates, workspace):
    """Plate pose maximizing the fewest distinct IK solutions over its fixtures."""
    best, best_score = None, -1
    for T0 in _candidate_poses(model, candidates, rng, 0.2, workspace):
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
    self-motion of the closed chain. ``workspace = (lower (3,), upper (3,))`` optionally keeps arm A's tool
    inside a box in the world frame (e.g. in front of the robot).
    """
    n, rng = _check_n(n), np.random.default_rng(rng)
    a, b = arms
    ma, mb = robot[a], robot[b]
    C = BRACKET_90 if clamp is None else check_transform(clamp, "clamp", 1e-6)
    accept = None
    if workspace is not None:
        lo, hi = (np.asarray(w, dtype=float) for w in workspace)

        def accept(qq):
            p = forward_kinematics(ma, qq[:, : ma.dof])[:, :3, 3]
            return np.all((p >= lo) & (p <= hi), axis=-1)

    # a workspace rejects most random starts: try more of them
    opts = {"n_seeds": 64 if accept is None else 192, "n_steps": max(40, 3 * n // 64), "momentum": 0.8,
            "accept": accept, **(explore_options or {})}
    ex = explore(ClosedChainConstraint(ma, mb, C), rng, progress=progress, **opts)
    if ex.q.shape[0] < n:
        raise DegenerateExperimentError(
            f"dual: self-motion gave {ex.q.shape[0]} distinct configurations, {n} asked; raise n_seeds or n_steps"
        )
    q = ex.q[pick_evenly(ex.q.shape[0], n)]
    q_clean = {a: q[:, : ma.dof], b: q[:, ma.dof :]}
    stats = _stats(ex)
    ds = Dataset("dual", robot.name, (a, b), _noisy(q_clean, noise, rng), {},
                 {"T_toolA_toolB": C} if known_clamp else {}, "dual", _meta("dual", noise))
    truth = Truth(robot, {"T_toolA_toolB": C}, q_clean, noise, {"generator": "dual", **stats})
    return ds, truth, validation_set(robot, (a, b), n_validation, rng)


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
    n, rng = _check_n(n), np.random.default_rng(rng)
    arm, model = _arm(robot, arm)
    if p_world_socket is None:
        p = reachable_pose(model, rng, workspace=workspace)[:3, 3]
    else:
        p = as_array(p_world_socket, "p_world_socket", (3,))
    options = {"momentum": 0.8, **(explore_options or {})}
    ex, pick = _explore_to_n(PositionConstraint(model, p), n, rng, options, progress)
    q = ex.q[pick]
    ds = Dataset("socket", robot.name, (arm,), _noisy({arm: q}, noise, rng), {},
                 {"p_world_socket": p} if known_socket else {}, "socket", _meta("socket", noise))
    truth = Truth(robot, {"p_world_socket": p}, {arm: q}, noise, {"generator": "socket", **_stats(ex)})
    return ds, truth, validation_set(robot, (arm,), n_validation, rng)


GENERATORS = {
    "pose": generate_pose,
    "markers": generate_markers,
    "clamp": generate_clamp,
    "plate": generate_plate,
    "dual": generate_dual,
    "socket": generate_socket,
}


def dataset_spread(dataset: Dataset, robot: Robot, truth: Truth | None = None, *, weak_rad: float = 0.1) -> dict:
    """``{arm: JointSpread}``: per-joint range covered by the data set, weak joints named.

    The number of self-motion branches visited is taken from ``truth.meta`` when given.
    """
    branches = None if truth is None else truth.meta.get("branches")
    return {
        a: joint_spread(dataset.q[a], robot[a].joint_names, robot[a].lower, robot[a].upper,
                        weak_rad=weak_rad, n_branches=branches)
        for a in dataset.arms
    }
