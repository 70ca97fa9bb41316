"""Robot programs as CSV (``kincal compensate``; docs/deploy.md): joint targets, in model order (``<arm>.<joint>``)
or in controller order and motor units (``<arm>.ch<c>``), or Cartesian tool poses (``<arm>.x, .y, .z, .qw, .qx,
.qy, .qz`` in the world frame) with the nominal joint values that reach them as seeds.

Reading uses the data CSV rules (``kincal.io.csvtable``); angles and lengths in the units given (joint columns
in ``angle``, pose positions in ``length``; motor columns always motor rad). The compensated program is written
in the input's own form and units, one row per input row, with per arm the ``status``, the remaining position
error (in ``length``) and rotation error (in ``angle``) of the calibrated model.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from kincal.errors import DataFormatError
from kincal.io import units
from kincal.io.atomic import output_file
from kincal.io.csvtable import Table, read_table
from kincal.io.logs import joint_to_motor, motor_to_joint
from kincal.kinematics import Robot
from kincal.lie import se3
from kincal.lie.rotations import quat_wxyz_to_matrix

FORMS = ("joints", "controller", "poses")
POSE = ("x", "y", "z", "qw", "qx", "qy", "qz")


@dataclass(frozen=True, eq=False)
class Program:
    """A program read from ``path``: ``form`` (one of ``FORMS``), per arm the joint values in model order and SI
    (for poses: the seeds), ``poses`` per arm (N, 4, 4) for Cartesian programs, the file ``lines`` of the rows,
    and the units to write back in."""

    path: Path
    form: str
    q: Mapping[str, np.ndarray]
    poses: Mapping[str, np.ndarray]
    lines: np.ndarray
    angle: str
    length: str


def read_program(path, robot: Robot, angle: str = "rad", length: str = "m") -> Program:
    """Read a program for ``robot``; the arms are those with columns in the header."""
    path = Path(path)
    fa, fl = units.factor("angle", angle, "--angle"), units.factor("length", length, "--length")
    table = read_table(path, "program")
    arms = [a for a in robot.arms if any(c.startswith(f"{a}.") for c in table.header)]
    if not arms:
        raise DataFormatError(f"{path}: line {table.header_line}: no column of any arm of '{robot.name}' "
                              f"(expected <arm>.<joint>, <arm>.ch<c> or <arm>.x ... <arm>.qz; arms: "
                              f"{', '.join(robot.arms)})")
    form = _form(table, robot, arms)
    q, poses = {}, {}
    for a in arms:
        m = robot[a]
        scale = np.array([fl if t == "prismatic" else fa for t in m.joint_types])
        if form == "controller":
            q[a] = motor_to_joint(table.take([f"{a}.ch{c + 1}" for c in range(m.dof)]), m)
        else:
            q[a] = table.take([f"{a}.{j}" for j in m.joint_names]) * scale
        if form == "poses":
            v = table.take([f"{a}.{k}" for k in POSE])
            poses[a] = _poses(path, table, v, fl)
    extra = [c for c in table.header if c not in table.used]
    if extra:
        raise DataFormatError(f"{path}: line {table.header_line}, column '{extra[0]}': not a column of this "
                              f"{form} program")
    return Program(path, form, q, poses, table.lines, angle, length)


def _form(table: Table, robot: Robot, arms) -> str:
    a = arms[0]
    if f"{a}.x" in table.col:
        return "poses"
    if f"{a}.ch1" in table.col:
        return "controller"
    return "joints"


def _poses(path, table: Table, v: np.ndarray, length: float) -> np.ndarray:
    norm = np.linalg.norm(v[:, 3:], axis=1)
    bad = np.flatnonzero(np.abs(norm - 1) > 1e-6)
    if len(bad):
        raise DataFormatError(f"{path}: line {table.lines[bad[0]]}: quaternion norm {norm[bad[0]]:.6g}, expected a "
                              "unit quaternion (qw, qx, qy, qz)")
    return se3.make(quat_wxyz_to_matrix(v[:, 3:]), v[:, :3] * length)


def write_program(path, program: Program, robot: Robot, comp, *, overwrite: bool = False) -> Path:
    """The compensated program in the form and units of ``program``, with per arm status and residuals."""
    fa, fl = units.factor("angle", program.angle, "--angle"), units.factor("length", program.length, "--length")
    header, cols = [], []
    for a, q in comp.q.items():
        m = robot[a]
        if program.form == "controller":
            header += [f"{a}.ch{c + 1}" for c in range(m.dof)]
            cols.append(joint_to_motor(q, m))
        else:
            scale = np.array([fl if t == "prismatic" else fa for t in m.joint_types])
            header += [f"{a}.{j}" for j in m.joint_names]
            cols.append(q / scale)
        header += [f"{a}.position_error_{program.length}", f"{a}.rotation_error_{program.angle}"]
        cols.append(np.column_stack([comp.position_error[a] / fl, comp.rotation_error[a] / fa]))
    values = np.concatenate(cols, axis=1)
    status = [comp.status[a] for a in comp.q]
    with output_file(path, overwrite=overwrite) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(",".join(header + [f"{a}.status" for a in comp.q]) + "\n")
        for i, row in enumerate(values):
            fh.write(",".join([repr(float(x)) for x in row] + [str(s[i]) for s in status]) + "\n")
    return Path(path)

