"""Joint targets of a designed experiment (``kincal design``), ready to run; docs/design.md.

A folder with three files:

- ``targets.csv``: one line per configuration, columns ``<arm>.<joint>`` in model order, rad (m for prismatic
  joints), the order to measure them in; on a tree-structured robot the carriers' columns too (``torso.t1``),
  each shared joint once;
- ``controller.csv``: the same targets as the controller takes them, columns ``<arm>.ch<c>`` in controller
  channel order, motor rad via the gear ratios (``motor = q * gear_ratio``, thesis Table 3.1);
- ``design.yaml``: what was chosen and why (criterion, values against random designs, predicted accuracy).

The folder is written beside the target under a temporary name and renamed into place at the end
(``kincal.io.atomic``), so an interrupted run leaves no partial folder; an existing folder is never overwritten.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np
import yaml

from kincal.errors import DataFormatError
from kincal.io.atomic import output_directory
from kincal.io.logs import joint_to_motor
from kincal.kinematics import Robot


def write_targets(directory, robot: Robot, q: Mapping[str, np.ndarray], summary: Mapping,
                  overwrite: bool = False) -> dict[str, Path]:
    """Write ``targets.csv``, ``controller.csv`` and ``design.yaml`` into the new folder ``directory``, all or
    nothing (``kincal.io.atomic.output_directory``)."""
    d = Path(directory)
    names = ("targets.csv", "controller.csv", "design.yaml")
    if d.exists() and not overwrite:
        raise DataFormatError(f"{d}: exists; not overwritten (choose another output folder or pass --overwrite)")
    with output_directory(d, names=names, overwrite=overwrite, last="design.yaml") as stage:
        _write(stage.path, robot, q, summary)
    return {name: d / name for name in names}


def _write(folder: Path, robot: Robot, q: Mapping[str, np.ndarray], summary: Mapping) -> None:
    arms = sorted(q, key=lambda a: len(robot.lineage(a)))  # a tree's carriers (a torso) before the arms on them
    joints = np.concatenate([q[a] for a in arms], axis=1)
    header = [f"{a}.{j}" for a in arms for j in robot[a].joint_names]
    _csv(folder / "targets.csv", header, joints)
    motor = np.concatenate([joint_to_motor(q[a], robot[a]) for a in arms], axis=1)
    channels = [f"{a}.ch{c + 1}" for a in arms for c in range(robot[a].dof)]
    _csv(folder / "controller.csv", channels, motor)
    with open(folder / "design.yaml", "x", encoding="utf-8") as fh:  # output_directory fsyncs the folder
        yaml.safe_dump(dict(summary), fh, sort_keys=False)


def _csv(path: Path, header: list[str], values: np.ndarray) -> None:
    with open(path, "x", encoding="utf-8") as fh:
        fh.write(",".join(header) + "\n")
        np.savetxt(fh, values, delimiter=",", fmt="%.17g")  # round-trip exact: a target at a limit stays within it
