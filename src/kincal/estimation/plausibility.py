"""Units implausible for the robot, found before any solve: degrees declared as radians, metres as mm.

A solve on such data grinds towards an arm shrunk or grown 1000 times (or cannot fit at all) and can take
minutes; the data loaders (``kincal.io.datasets``, naming file, line and column) and ``solve`` (naming the
data set and field) refuse it first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kincal.data import Dataset
from kincal.kinematics import PRISMATIC, Robot, forward_kinematics
from kincal.schema import LENGTH, SCHEMAS

# A revolute joint reading beyond this (rad) is not an angle in radians; measured points whose spread differs
# from the nominal tool's at the same readings by more than SPREAD_FACTOR (either way) are not in the stated
# length unit, judged only where the tool moves at least MIN_TOOL_SPREAD (m).
MAX_JOINT_RAD = 4 * math.pi
SPREAD_FACTOR = 30.0
MIN_TOOL_SPREAD = 0.01


@dataclass(frozen=True)
class Implausible:
    """What is implausible: a joint reading (``field`` "q": ``arm``, ``sample``, ``joint`` index, ``value`` rad)
    or a measured entry's spread (``field`` its key, ``value`` the ratio to the nominal tool's, ``spread`` and
    ``tool`` in m)."""

    field: str
    arm: str
    value: float
    sample: int = -1
    joint: int = -1
    spread: float = 0.0
    tool: float = 0.0

    def describe(self, robot: Robot) -> str:
        if self.field == "q":
            return (f"joint '{self.arm}.{robot[self.arm].joint_names[self.joint]}' reads {self.value:.6g} rad, "
                    f"beyond +-4 pi: not an angle in radians")
        return (f"the measured {self.field} spread over {self.spread * 1e3:.4g} mm RMS where the nominal "
                f"{robot.name} tool moves {self.tool * 1e3:.4g} mm RMS at these joint readings "
                f"({self.value:.3g} times): not in the stated length unit")


def implausible_units(robot: Robot, ds: Dataset) -> Implausible | None:
    """The first implausible joint reading or measured spread of ``ds`` for ``robot``, or None."""
    for a, q in ds.q.items():
        revolute = np.array([t != PRISMATIC for t in robot[a].joint_types])
        big = np.abs(q) * revolute > MAX_JOINT_RAD
        if big.any():
            i, j = np.argwhere(big)[0]
            return Implausible("q", a, float(q[i, j]), int(i), int(j))
    if len(ds.q) != 1:
        return None
    (a, q), = ds.q.items()
    tool = spread(forward_kinematics(robot[a], q)[:, :3, 3])
    if tool < MIN_TOOL_SPREAD:
        return None
    for f in SCHEMAS[ds.kind].measured:
        if f.key in ds.measured and (f.form == "pose" or (f.form == "points" and f.unit == LENGTH)):
            x = ds.measured[f.key][:, :3, 3] if f.form == "pose" else ds.measured[f.key]
            ratio = spread(x) / tool
            if not 1 / SPREAD_FACTOR <= ratio <= SPREAD_FACTOR:
                return Implausible(f.key, a, ratio, spread=spread(x), tool=tool)
    return None


def spread(x: np.ndarray) -> float:
    """RMS distance of points (N, ..., 3) from their mean over the samples."""
    return float(np.sqrt(np.mean(np.sum((x - x.mean(axis=0)) ** 2, axis=-1))))
