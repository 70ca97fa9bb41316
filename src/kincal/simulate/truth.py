"""Ground truth of a simulated experiment, kept apart from the data set it generated."""

from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

import numpy as np

from kincal.kinematics import Robot
from kincal.simulate.noise import Noise


def _ro(a) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Truth:
    """What the simulator knows and the calibration must find.

    Attributes
    ----------
    robot : the true Robot (perturbed model) that generated the data.
    values : true values of every nuisance quantity of the experiment, whether or not the data set
        declares it known, under the Dataset's names: ``T_world_fixture``, ``T_world_plate``,
        ``T_plate_fixture``, ``T_toolA_toolB``, ``T_world_tracker``, ``p_tool_marker``, ``p_world_socket``.
    q : noise-free joint readings per arm (N, n), same samples and order as the data set.
    noise : the noise that was added to the data set.
    meta : generator statistics (IK starts tried/failed, rejected steps, branches visited, seed).
    """

    robot: Robot
    values: Mapping[str, np.ndarray]
    q: Mapping[str, np.ndarray]
    noise: Noise = field(default_factory=Noise)
    meta: Mapping = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "values", MappingProxyType({k: _ro(v) for k, v in self.values.items()}))
        object.__setattr__(self, "q", MappingProxyType({k: _ro(v) for k, v in self.q.items()}))
        object.__setattr__(self, "meta", MappingProxyType(dict(self.meta)))
