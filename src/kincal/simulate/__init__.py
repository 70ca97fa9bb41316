"""Simulation: true robots, inverse kinematics, self-motion, experiment generators, noise.

API summary (SI units; ``rng`` is a numpy Generator or an integer seed; same seed, same output)::

    perturb_robot(robot, level="thesis" | "fine" | Perturbation, rng, arms=None, **magnitudes) -> Robot
    generate_pose(robot, arm, n=, rng=, noise=, T_world_tracker=, known_tracker=)        -> (Dataset, Truth, validation)
    generate_markers(robot, arm, n=, rng=, noise=, markers=3 | (m, 3), known_markers=, known_tracker=)
    generate_clamp(robot, arm, n=, rng=, noise=, T_world_fixture=, known_fixture=, workspace=)
    generate_plate(robot, arm, n=, rng=, noise=, T_plate_fixture=plate_layout(), T_world_plate=, known_plate=)
    generate_dual(robot, arms=("left", "right"), n=, rng=, noise=, clamp=BRACKET_90, known_clamp=, workspace=)
    generate_socket(robot, arm, n=, rng=, noise=, p_world_socket=, known_socket=)
    GENERATORS[kind], OPTIONS[kind]                              every generator (kincal.simulate.generators, one
                                                                 module per kind) and its scenario options
    tip_configurations(robot, arm, n, rng) -> {arm: q}            readings of an arm with its carriers (trees)
    workspace_sample(robot, arm, n, rng)                         readings as analysis.prediction takes them
    dataset_spread(dataset, robot, truth) -> {arm: JointSpread}   per-joint range, weak joints, branches
    solve_ik(model, T_world_tool, q0) / solve_closed_chain(model_a, model_b, T_toolA_toolB, q0_a, q0_b) -> IKResult
    explore(constraint, rng, ...) -> Exploration                 self-motion walks (clamped / closed chain)
    Noise(position=, orientation=, joint=, backlash=, other=)     kincal.noise.Noise (SI; None: none added)

``validation`` is ``{arm: Dataset(kind="pose")}``: fresh random configurations with the noise-free true tool
poses (``T_world_tracker`` = identity); markers and camera validate with their own kind, frames refitted. ``Truth`` holds the true robot, the true nuisance values (fixture,
plate, clamp, tracker, markers, socket), the noise-free readings and generator statistics.
Joint readings are what the controller reports: true joint value minus true offset, plus noise.
"""

from kincal.simulate.generators import (
    BRACKET_90,
    GENERATORS,
    OPTIONS,
    dataset_spread,
    generate_clamp,
    generate_dual,
    generate_markers,
    generate_plate,
    generate_pose,
    generate_socket,
    plate_layout,
    random_configurations,
    reachable_pose,
    tip_configurations,
    validation_set,
    workspace_sample,
)
from kincal.simulate.ik import (
    ClosedChainConstraint,
    IKResult,
    PoseConstraint,
    PositionConstraint,
    closure_error,
    solve,
    solve_closed_chain,
    solve_ik,
)
from kincal.simulate.noise import Noise, backlash_offsets
from kincal.simulate.perturb import LEVELS, Perturbation, perturb_arm, perturb_robot, perturbation
from kincal.simulate.selfmotion import Exploration, JointSpread, explore, joint_spread
from kincal.simulate.truth import Truth

__all__ = [
    "BRACKET_90", "GENERATORS", "LEVELS", "OPTIONS", "ClosedChainConstraint", "Exploration", "IKResult", "JointSpread", "Noise",
    "Perturbation", "PoseConstraint", "PositionConstraint", "Truth", "backlash_offsets", "closure_error",
    "dataset_spread", "explore", "generate_clamp", "generate_dual", "generate_markers", "generate_plate",
    "generate_pose", "generate_socket", "joint_spread", "perturb_arm", "perturb_robot", "perturbation",
    "plate_layout", "random_configurations", "reachable_pose", "solve", "solve_closed_chain", "solve_ik",
    "tip_configurations", "validation_set", "workspace_sample",
]
