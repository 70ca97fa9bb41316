"""POE arm models, forward kinematics, geometric and identification Jacobians."""

from kincal.kinematics.fk import (
    Kinematics,
    body_jacobian,
    chain,
    forward_kinematics,
    joint_array,
    joint_axes,
    kinematics,
    space_jacobian,
)
from kincal.kinematics.elastic import (
    LoadedKinematics,
    load_torques,
    loaded_chain,
    loaded_forward_kinematics,
    loaded_kinematics,
)
from kincal.kinematics.identification import IdentificationJacobian, identification_jacobian
from kincal.kinematics.model import PRISMATIC, REVOLUTE, ArmModel, Robot
from kincal.kinematics.twists import conform_twists, tangent_basis, tangent_generators

__all__ = [
    "ArmModel",
    "IdentificationJacobian",
    "Kinematics",
    "LoadedKinematics",
    "PRISMATIC",
    "REVOLUTE",
    "Robot",
    "body_jacobian",
    "chain",
    "conform_twists",
    "forward_kinematics",
    "identification_jacobian",
    "joint_array",
    "joint_axes",
    "load_torques",
    "loaded_chain",
    "loaded_forward_kinematics",
    "loaded_kinematics",
    "kinematics",
    "space_jacobian",
    "tangent_basis",
    "tangent_generators",
]
