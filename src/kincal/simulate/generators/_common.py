"""Shared parts of the experiment generators: the registry of generators with their scenario options, arms and
joint limits, validation sets, noise on joint readings, generator statistics.

A generator module (``kincal.simulate.generators.<kind>``) decorates its function with ``@generator(kind,
*options)``; the package imports every such module, so a new generator is one new module. Its ``Option``s are the
keys of a scenario file's ``experiment:`` block (docs/simulation.md): ``kincal.io`` reads and checks them by
``type``, converts their numbers by ``unit`` and passes them to the function as keyword ``argument``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from kincal._validate import check_transform
from kincal.data import Dataset
from kincal.errors import DegenerateExperimentError, ModelError
from kincal.kinematics import ArmModel, Robot, loaded_forward_kinematics
from kincal.kinematics.tree import tip_model, tip_pose
from kincal.simulate.generators._tree import hung_readings, tree_has_gravity, true_tool_poses, with_couplings
from kincal.noise import Noise
from kincal.schema import LENGTH, NONE
from kincal.simulate.noise import joint_readings
from kincal.simulate.selfmotion import Exploration, joint_spread
from kincal.simulate.truth import Truth

Progress = Callable[[int, int], None]

# option types (how a scenario file gives the value; kincal.io.datasets reads each type)
OPTION_TYPES = {
    "count": "a positive integer",
    "bool": "true or false",
    "arm": "an arm of the model",
    "arms": "two arms of the model",
    "pose": "a pose block (xyz in the scenario's length unit, rpy/quaternion/matrix)",
    "poses": "a non-empty list of pose blocks",
    "point": "[x, y, z]",
    "points": "a non-empty list of [x, y, z]",
    "vector": "a list of numbers",
    "box": "{lower: [x, y, z], upper: [x, y, z]}",
    "explore": "{n_seeds, n_steps, step_rad, momentum} of the self-motion walk (selfmotion.explore)",
    "wrench": "a load magnitude > 0 (N, random directions) or [fx, fy, fz, tx, ty, tz] (N, N m)",
    "configurations": "a list of joint-value lists (angle unit; prismatic joints length unit)",
    "payload": "{mass_kg, com: [x, y, z]} (centre of mass in the tool frame, length unit)",
}


@dataclass(frozen=True)
class Option:
    """A scenario option of a generator: its key in the file, type, unit kind, default and keyword argument."""

    name: str
    type: str
    unit: str = NONE
    default: Any = None
    argument: str = ""  # the generator's keyword argument; default: ``name``
    doc: str = ""
    size: int = 0  # length of a ``vector``

    def __post_init__(self) -> None:
        if self.type not in OPTION_TYPES:
            raise ValueError(f"option {self.name!r}: type {self.type!r} is not one of {', '.join(OPTION_TYPES)}")
        if not self.argument:
            object.__setattr__(self, "argument", self.name)


@dataclass(frozen=True)
class Generator:
    kind: str
    function: Callable
    options: tuple[Option, ...]


REGISTRY: dict[str, Generator] = {}


def generator(kind: str, *options: Option) -> Callable:
    """Register the decorated function as the generator of ``kind`` with its scenario ``options``."""
    def register(function: Callable) -> Callable:
        REGISTRY[kind] = Generator(kind, function, options)
        return function
    return register


def count_option(default: int, name: str = "n", doc: str = "number of samples") -> Option:
    return Option(name, "count", NONE, default, doc=doc)


def known_option(role: str, default: bool = False) -> Option:
    return Option(f"known_{role}", "bool", NONE, default, doc=f"declare the {role} known in the data set")


ARM = Option("arm", "arm", doc="the arm (needed when the model has more than one)")
WORKSPACE = Option("workspace", "box", LENGTH, doc="keep the tool inside this box (world frame)")
EXPLORE = Option("explore", "explore", NONE, argument="explore_options", doc="self-motion walk settings")
WRENCH = Option("wrench_N", "wrench", NONE, argument="wrench", doc="loads on the tool")


def pick_arm(robot: Robot, arm: str | None) -> tuple[str, ArmModel]:
    if arm is None:
        if len(robot.arms) != 1:
            raise ModelError(f"robot '{robot.name}' has arms {', '.join(robot.arms)}; name the arm to use")
        arm = next(iter(robot.arms))
    return arm, robot[arm]


def finite_limits(model: ArmModel, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Limits shrunk by ``margin`` of their span (+-pi where a joint has no limit)."""
    lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
    hi = np.where(np.isfinite(model.upper), model.upper, np.pi)
    pad = margin * (hi - lo)
    return lo + pad, hi - pad


def random_configurations(model: ArmModel, n: int, rng: np.random.Generator, margin: float = 0.0) -> np.ndarray:
    """n readings uniform within the limits shrunk by ``margin`` of their span: (n, dof)."""
    lo, hi = finite_limits(model, margin)
    return rng.uniform(lo, hi, (n, model.dof))


def tip_configurations(robot: Robot, arm: str, n: int, rng: np.random.Generator, margin: float = 0.0) -> dict:
    """n random readings (``random_configurations``) of ``arm`` and every arm carrying it, couplings applied, and
    of the other arms whose weight loads its carriers (gravity on a tree): arm -> (n, dof)."""
    q = with_couplings(robot, {s: random_configurations(robot[s], n, rng, margin) for s in robot.lineage(arm)})
    q.update(hung_readings(robot, arm, n, lambda m, k: random_configurations(m, k, rng, margin)))
    return q


def workspace_sample(robot: Robot, arm: str, n: int, rng: np.random.Generator):
    """n random readings of ``arm`` as ``analysis.prediction.tool_jacobian`` takes them: (n, dof) for an arm
    alone (the root of a tree too), a mapping over its lineage and the arms loading it (``tip_configurations``)
    for a mounted arm."""
    if len(robot.lineage(arm)) == 1:
        return random_configurations(robot[arm], n, rng)
    return tip_configurations(robot, arm, n, rng)


def validation_set(robot: Robot, arms, n: int, rng: np.random.Generator, name: str = "validation") -> dict:
    """``{arm: Dataset(kind="pose")}``: n fresh random configurations with noise-free true tool poses.

    The poses are given in the world frame, but the frame is not declared known: evaluating a model on this
    set first fits it (a best rigid registration, as a tracker of unknown pose would), so the score is the
    accuracy that a self-calibration can determine. Where the world frame itself is not observable (a clamp
    or plate of unknown pose, the common frame of two arms) a world-frame score would measure the gauge choice.
    """
    out = {}
    for a in arms:
        q = tip_configurations(robot, a, n, rng)
        line = robot.lineage(a)
        if tree_has_gravity(robot, a):  # sags under the whole tree's weight
            T = true_tool_poses(robot, a, tip_model(robot, a), np.concatenate([q[s] for s in line], -1), None,
                                {o: q[o] for o in q if o not in line})
        else:  # mounted: through its carriers; alone: sags under its weight
            T = tip_pose(robot, a, q) if len(line) > 1 else loaded_forward_kinematics(robot[a], q[a])
        out[a] = Dataset(
            "pose", robot.name, (a,), q, measured={"T_tracker_tool": T},
            name=f"{name}-{a}", meta={"noise_free": True, "noise": dict(NOISE_FREE), "frame": "world (registered when evaluated)"},
        )
    return out


def pose_or(T, name, default):
    """``T`` validated, or ``default()`` when T is None."""
    return default() if T is None else check_transform(T, name, 1e-6)


def noisy_readings(q_clean: dict, noise: Noise, rng) -> dict:
    return {a: joint_readings(q, noise, rng) for a, q in q_clean.items()}


def exploration_stats(ex: Exploration) -> dict:
    return {
        "ik_starts": ex.n_seeds_tried,
        "ik_starts_rejected": ex.n_seeds_failed,
        "walk_steps_rejected": ex.n_steps_rejected,
        "duplicates_removed": ex.n_duplicates,
        "branches": ex.n_branches,
        "candidates": int(ex.q.shape[0]),
    }


# What a noise-free validation set states (the one noise rule then expects no measurement noise there).
NOISE_FREE = {"position_m": 0.0, "orientation_rad": 0.0, "joint_rad": 0.0}


def dataset_meta(kind: str, noise: Noise, extra: dict | None = None) -> dict:
    return {"generator": kind, "noise": noise.as_si(), **(extra or {})}


def check_n(n: int, name: str = "n") -> int:
    if int(n) != n or n < 1:
        raise DegenerateExperimentError(f"{name}: expected a positive number of samples, got {n!r}")
    return int(n)


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
