"""kincal: kinematic calibration of robot arms."""

from kincal.errors import (
    DataFormatError,
    DegenerateExperimentError,
    KincalError,
    ManifoldError,
    ModelError,
    ShapeError,
)
from kincal.kinematics import ArmModel, Robot, forward_kinematics

# registers every experiment kind (its data schema) before any data set is built or read
import kincal.experiments  # noqa: E402,F401  isort: skip

__version__ = "0.1.0"

__all__ = [
    "ArmModel",
    "DataFormatError",
    "DegenerateExperimentError",
    "KincalError",
    "ManifoldError",
    "ModelError",
    "Robot",
    "ShapeError",
    "forward_kinematics",
]
