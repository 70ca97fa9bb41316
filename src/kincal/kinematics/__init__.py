"""POE arm models, forward kinematics, geometric Jacobians and the tool pose's parameter Jacobians."""

from kincal.kinematics.fk import (
    Kinematics,
    body_jacobian,
    chain,
    forward_kinematics,
    joint_array,
    joint_axes,
    kinematics,
    sample_chain,
    space_jacobian,
)
from kincal.kinematics.elastic import (
    LoadedKinematics,
    load_torques,
    loaded_chain,
    loaded_forward_kinematics,
    loaded_kinematics,
)
from kincal.kinematics.jacobians import TOOL_PARTS, tool_jacobians
from kincal.kinematics.model import PRISMATIC, REVOLUTE, ArmModel, Robot
from kincal.kinematics.twists import TWIST_COORDS, conform_twists, tangent_basis, tangent_frames, tangent_generators

__all__ = [
    "ArmModel",
    "Kinematics",
    "LoadedKinematics",
    "PRISMATIC",
    "REVOLUTE",
    "Robot",
    "body_jacobian",
    "chain",
    "conform_twists",
    "forward_kinematics",
    "joint_array",
    "joint_axes",
    "load_torques",
    "loaded_chain",
    "loaded_forward_kinematics",
    "loaded_kinematics",
    "kinematics",
    "sample_chain",
    "space_jacobian",
    "TOOL_PARTS",
    "TWIST_COORDS",
    "tool_jacobians",
    "tangent_basis",
    "tangent_frames",
    "tangent_generators",
]
