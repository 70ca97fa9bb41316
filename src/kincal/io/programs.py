"""Robot programs as CSV (``kincal compensate``; docs/deploy.md): joint targets, in model order (``<arm>.<joint>``)
or in controller order and motor units (``<arm>.ch<c>``), or Cartesian tool poses (``<arm>.x, .y, .z, .qw, .qx,
.qy, .qz`` in the world frame) with the nominal joint values that reach them as seeds.

Reading uses the data CSV rules (``kincal.io.csvtable``); angles and lengths in the units given (joint columns
in ``angle``, pose positions in ``length``; motor columns always motor rad). The compensated program is written
in the input's own form and units, one row per input row, with per arm the ``status``, the remaining position
error (in ``length``) and rotation error (in ``angle``) of the calibrated model.

Tree-structured robots: a mounted arm's rows carry its carriers' readings (``torso.t1, ..``, or ``torso.ch1, ..``
in a controller program; joint columns in a Cartesian one), which are held (``kincal.workflow.compensate``) and
written back unchanged. A coupled joint's column may be left out (it is derived); given, it must agree with the
coupling (``kincal.io.datasets.COUPLING_TOL``).

Tool loads: a solved arm's rows may carry its tool wrench ``<arm>.wrench.fx, .fy, .fz, .tx, .ty, .tz`` (N, N m;
tool frame, applied TO the tool, as the data sets' ``wrench.*`` columns): a compliant calibrated model is
compensated deflected by it (``kincal.workflow.sag``); the columns are written back unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

from kincal.errors import DataFormatError
from kincal.io import units
from kincal.io.atomic import output_file
from kincal.io.csvtable import Table, read_table
from kincal.io.datasets import COUPLING_TOL
from kincal.io.logs import joint_to_motor, motor_to_joint
from kincal.kinematics import Robot
from kincal.kinematics.couplings import derive_readings
from kincal.lie import se3
from kincal.lie.rotations import quat_wxyz_to_matrix

FORMS = ("joints", "controller", "poses")
POSE = ("x", "y", "z", "qw", "qx", "qy", "qz")
WRENCH = ("wrench.fx", "wrench.fy", "wrench.fz", "wrench.tx", "wrench.ty", "wrench.tz")


@dataclass(frozen=True, eq=False)
class Program:
    """A program read from ``path``: ``form`` (one of ``FORMS``), per arm the joint values in model order and SI
    (for poses: the seeds), ``poses`` per arm (N, 4, 4) for Cartesian programs, the file ``lines`` of the rows,
    the units to write back in, and ``wrench`` per arm with tool-load columns (N, 6) (N, N m, tool frame)."""

    path: Path
    form: str
    q: Mapping[str, np.ndarray]
    poses: Mapping[str, np.ndarray]
    lines: np.ndarray
    angle: str
    length: str
    wrench: Mapping[str, np.ndarray] = field(default_factory=dict)


def read_program(path, robot: Robot, angle: str = "rad", length: str = "m") -> Program:
    """Read a program for ``robot``; the arms are those with columns in the header (a mounted arm's carriers
    included: their columns must be there)."""
    path = Path(path)
    fa, fl = units.factor("angle", angle, "--angle"), units.factor("length", length, "--length")
    table = read_table(path, "program")
    arms = _arms(path, table, robot)
    carriers = {c for a in arms for c in robot.lineage(a)[:-1]}
    form = _form(table, [a for a in arms if a not in carriers] or arms)
    q, poses = {}, {}
    for a in arms:
        m = robot[a]
        if form == "controller":
            q[a] = motor_to_joint(table.take([f"{a}.ch{c + 1}" for c in range(m.dof)]), m)
        else:
            q[a] = _joint_columns(table, a, m, np.array([fl if t == "prismatic" else fa for t in m.joint_types]))
        if form == "poses" and a not in carriers:
            poses[a] = _poses(path, table, table.take([f"{a}.{k}" for k in POSE]), fl)
    wrench = {a: table.take([f"{a}.{k}" for k in WRENCH]) for a in arms
              if a not in carriers and any(f"{a}.{k}" in table.col for k in WRENCH)}
    extra = [c for c in table.header if c not in table.used]
    if extra:
        raise DataFormatError(f"{path}: line {table.header_line}, column '{extra[0]}': not a column of this "
                              f"{form} program")
    return Program(path, form, q, poses, table.lines, angle, length, wrench)


def _arms(path: Path, table: Table, robot: Robot) -> list[str]:
    """The arms with columns in the header, and every carrier of a mounted one (whose columns must be there)."""
    for c in table.header:
        prefix = c.split(".", 1)[0]
        if "." in c and prefix not in robot.arms:
            raise DataFormatError(f"{path}: line {table.header_line}, column '{c}': no arm '{prefix}' in robot "
                                  f"'{robot.name}' (arms: {', '.join(robot.arms)})")
    arms = [a for a in robot.arms if any(c.startswith(f"{a}.") for c in table.header)]
    if not arms:
        raise DataFormatError(f"{path}: line {table.header_line}: no column of any arm of '{robot.name}' "
                              f"(expected <arm>.<joint>, <arm>.ch<c> or <arm>.x ... <arm>.qz; arms: "
                              f"{', '.join(robot.arms)})")
    for a in arms:
        for c in robot.lineage(a)[:-1]:
            if c not in arms:
                first = f"{c}.ch1" if f"{a}.ch1" in table.col else f"{c}.{robot[c].joint_names[0]}"
                raise DataFormatError(f"{path}: line {table.header_line}, column '{first}': missing; arm '{a}' is "
                                      f"mounted on '{c}', whose readings each target of '{a}' needs (held fixed "
                                      f"while '{a}' is solved)")
    return arms


def _form(table: Table, arms) -> str:
    if any(f"{a}.x" in table.col for a in arms):
        return "poses"
    if any(f"{a}.ch1" in table.col for a in arms):
        return "controller"
    return "joints"


def _joint_columns(table: Table, a: str, m, scale: np.ndarray) -> np.ndarray:
    """Readings (SI) of arm ``a`` from its joint columns; a coupled joint's column may be absent (derived) or
    given (checked against the coupling)."""
    free = [i for i, j in enumerate(m.joint_names) if j not in m.couplings or f"{a}.{j}" in table.col]
    given = np.zeros((len(table.lines), m.dof))
    given[:, free] = table.take([f"{a}.{m.joint_names[i]}" for i in free]) * scale[free]
    q = derive_readings(m.couplings, m.joint_names, given)
    bad = np.argwhere(np.abs(q - given)[:, free] > COUPLING_TOL)
    if len(bad):
        r, i = bad[0][0], free[bad[0][1]]
        j = m.joint_names[i]
        raise DataFormatError(f"{table.path}: line {table.lines[r]}, column '{a}.{j}': {given[r, i] / scale[i]:.6g} "
                              f"disagrees with the coupling of {j} ({q[r, i] / scale[i]:.6g} from the joints it "
                              f"follows; model field arms.{a}.couplings.{j})")
    return q


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
    for a, q in comp.held.items():  # a tree's carriers, held as given
        _joint_block(program, robot, a, q, header, cols, fa, fl)
    for a, q in comp.q.items():
        _joint_block(program, robot, a, q, header, cols, fa, fl)
        if a in program.wrench:
            header += [f"{a}.{k}" for k in WRENCH]
            cols.append(program.wrench[a])
        header += [f"{a}.position_error_{program.length}", f"{a}.rotation_error_{program.angle}"]
        cols.append(np.column_stack([comp.position_error[a] / fl, comp.rotation_error[a] / fa]))
    values = np.concatenate(cols, axis=1)
    status = [comp.status[a] for a in comp.q]
    with output_file(path, overwrite=overwrite) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(",".join(header + [f"{a}.status" for a in comp.q]) + "\n")
        for i, row in enumerate(values):
            fh.write(",".join([repr(float(x)) for x in row] + [str(s[i]) for s in status]) + "\n")
    return Path(path)


def _joint_block(program: Program, robot: Robot, a: str, q: np.ndarray, header: list, cols: list, fa, fl) -> None:
    """Append arm ``a``'s joint columns (in the program's form and units) to ``header`` and ``cols``."""
    m = robot[a]
    if program.form == "controller":
        header += [f"{a}.ch{c + 1}" for c in range(m.dof)]
        cols.append(joint_to_motor(q, m))
    else:
        header += [f"{a}.{j}" for j in m.joint_names]
        cols.append(q / np.array([fl if t == "prismatic" else fa for t in m.joint_types]))
