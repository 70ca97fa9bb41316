"""Data set files: a CSV of samples plus a YAML manifest  <->  ``kincal.data.Dataset``.

The format is documented in docs/formats.md. In short, the manifest (``format: kincal-dataset``,
``version: 1``) names the experiment ``kind``, the ``model`` (built-in robot name or model file path
relative to the manifest), the ``arms``, the CSV file (``data``), the ``units`` of the CSV and of the known
transforms, the ``known`` quantities, optional ``noise`` levels and optional ``frames`` (role -> frame name,
for frames shared with other data sets). The CSV header names its columns:

- joints ``<arm>.<joint>`` (e.g. ``left.j1``), every joint of every arm;
- the measured entries of the kind, as its schema declares them (``kincal.schema``, one generic codec per
  form): a pose ``<prefix>.x, .y, .z, .qw, .qx, .qy, .qz``; a pose covariance ``<prefix>.<a>.<b>`` (a <= b in
  x y z rx ry rz: 21 columns, position in ``units.length``, orientation in ``units.angle``); points ``<prefix>1.x, <prefix>1.y, ...``; a vector
  its named columns; an index one integer column. Optional entries are read when their columns are present;
- optional ``t`` (s) in any kind, kept in ``Dataset.meta["t"]``.

Known entries are written in the manifest by form as well (pose blocks, lists of numbers, numbers), lengths
in ``units.length``. No kind has code here: a new kind's files follow from its schema.

Every problem is a DataFormatError naming the file, the row (1-based line number in the CSV) and the
column or manifest field. Writers never replace an existing file unless ``overwrite=True``. Ground truth
(``write_truth``) and validation sets go to separate files beside the data.
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from kincal.data import Dataset, frames_problem
from kincal.errors import DataFormatError, KincalError
from kincal.estimation.plausibility import CELL_FACTOR, implausible_units, past_limits
from kincal.io import units
from kincal.io.csvtable import Table, read_table
from kincal.io.models import _Ctx, _mapping, _matrix, _number, _pose, _vector, load_robot, save_robot
from kincal.io.references import model_reference, resolve, same_model
from kincal.io.yamlfile import clip, quote, read_yaml
from kincal.kinematics import PRISMATIC, Robot
from kincal.kinematics.branches import model_loading_branches
from kincal.kinematics.couplings import derive_readings
from kincal.lie import se3
from kincal.lie.rotations import matrix_to_quat_wxyz, quat_wxyz_to_matrix
from kincal.params import State, build_layout
from kincal.schema import ANGLE, LENGTH, SCHEMAS, Field, Schema, covariance_problem
from kincal.simulate.generators import OPTIONS as GENERATOR_OPTIONS
from kincal.simulate.perturb import LEVELS as PERTURBATION_LEVELS
from kincal.simulate.perturb import Perturbation

FORMAT = "kincal-dataset"
VERSION = 1
QUAT_TOL = 1e-6
_TOP_KEYS = {"format", "version", "name", "kind", "model", "arms", "data", "units", "known", "noise", "description",
             "meta", "frames"}
POSE_SUFFIXES = ("x", "y", "z", "qw", "qx", "qy", "qz")
# a pose covariance's components (position, orientation) and its 21 CSV entries (a <= b)
COV_AXES = ("x", "y", "z", "rx", "ry", "rz")
COV_TRIU = np.triu_indices(6)


def _fmt(x: float) -> str:
    return repr(float(x))


# --------------------------------------------------------------------------------------------- reading


def load_dataset(manifest, robot: Robot | None = None, *, job_model: str | None = None,
                 root: Path | None = None) -> Dataset:
    """Read and validate a data set from its manifest path.

    ``robot``: the model to check joint names (and prismatic units) against; default: the manifest's
    ``model`` (built-in name or a path relative to the manifest). ``job_model``: the resolved model reference
    of the job reading the manifest (``references.model_reference``); the manifest's ``model`` must name the
    same model, or a model of the same robot (same name, arms and joints: e.g. one calibrated before).
    ``root``: the folder every file reference must lie in (a confined job).
    """
    manifest = Path(manifest)
    data = read_yaml(manifest, "data set manifest")
    ctx = _Ctx(str(manifest))
    top = _mapping(ctx, data, "(top level)", _TOP_KEYS, ("format", "version", "kind", "model", "arms", "data", "units"))
    if top["format"] != FORMAT:
        raise ctx.fail("format", f"expected {quote(FORMAT)}, found {quote(top['format'])}")
    if top["version"] != VERSION or isinstance(top["version"], bool):
        raise ctx.fail("version", f"expected {VERSION}, found {quote(top['version'])}")
    kind = ctx.one_of("kind", top["kind"], SCHEMAS)
    schema = SCHEMAS[kind]
    arms = top["arms"]
    if not isinstance(arms, list) or not all(isinstance(a, str) and a for a in arms) or len(set(arms)) != len(arms):
        raise ctx.fail("arms", f"expected a list of distinct arm names, found {quote(arms)}")
    if len(arms) != schema.arms:
        raise ctx.fail("arms", f"kind '{kind}' needs {schema.arms} arm(s), found {arms}")
    u = _mapping(ctx, top["units"], "units", {"angle", "length"}, ("angle", "length"))
    ctx.angle = units.factor("angle", u["angle"], f"{manifest}: units.angle")
    ctx.length = units.factor("length", u["length"], f"{manifest}: units.length")
    model_ref = top["model"]
    if not isinstance(model_ref, str) or not model_ref:
        raise ctx.fail("model", f"expected a built-in robot name or a model file path, found {quote(model_ref)}")
    resolved = model_reference(manifest, model_ref, f"{manifest}: model", root)
    if robot is None or (job_model is not None and not same_model(resolved, job_model)):
        robot = _job_robot(ctx, resolved, robot, job_model)
    for a in arms:
        if a not in robot.arms:
            raise ctx.fail("arms", f"model '{robot.name}' has no arm {quote(a)}; its arms: {', '.join(robot.arms)}")
    known = _known(ctx, schema, top.get("known") or {})
    frames = top.get("frames") or {}
    bad = frames_problem(kind, frames, tuple(robot.arms))
    if bad:
        raise ctx.fail(*bad)
    noise = units.noise_from_file(top.get("noise") or {}, f"{ctx.file}: noise").as_si()
    csv_path = resolve(manifest, str(top["data"]), f"{manifest}: data", root)
    table = read_table(csv_path, integer={c for f in schema.measured if f.form == "index" for c in f.columns})
    q = _readings(ctx, table, robot, arms)
    measured = _measured(ctx, schema, table, known)
    meta = {"noise": noise, "manifest": str(manifest), "description": top.get("description", ""),
            "file": str(csv_path), "lines": table.lines,  # header = line 1
            "warnings": _impossible_rows(table, measured) + _limit_warnings(ctx, table, robot, q, u)}
    if "t" in table.header:
        meta["t"] = table.take(["t"])[:, 0]
    extra = [c for c in table.header if c not in table.used]
    if extra:
        raise DataFormatError(f"{csv_path}: line {table.header_line}, column '{clip(extra[0])}': unexpected column "
                              f"for kind "
                              f"'{kind}' with arms {arms}; expected only {', '.join(table.used)}")
    name = str(top.get("name") or manifest.stem)
    try:
        ds = Dataset(kind, resolved, tuple(arms), q, measured, known, name, meta, frames)
    except KincalError as exc:
        raise DataFormatError(f"{manifest}: {exc}") from None
    _plausible_units(ctx, table, robot, ds, u)
    return ds


COUPLING_TOL = 1e-4  # rad or m: a given reading of a coupled joint must agree this well with the derived one


def _readings(ctx, table: Table, robot: Robot, arms) -> dict[str, np.ndarray]:
    """Joint readings (SI) of the data set's arms and of every arm carrying them (``<torso>.<joint>`` columns on
    a tree-structured robot). A coupled joint's column may be absent (its reading is derived from the joints it
    depends on) or given (then checked against the derived value within ``COUPLING_TOL``, and the derived value
    kept, so the coupling holds exactly)."""
    q = {}
    for a in [c for arm in arms for c in robot.lineage(arm)] + _hung_arms(robot, arms, table):
        if a in q:
            continue
        model = robot[a]
        f = np.array([ctx.length if t == PRISMATIC else ctx.angle for t in model.joint_types])
        free = [i for i, j in enumerate(model.joint_names) if j not in model.couplings or f"{a}.{j}" in table.header]
        qa = np.zeros((len(table.lines), model.dof))
        qa[:, free] = table.take([f"{a}.{model.joint_names[i]}" for i in free]) * f[free]
        q[a] = derive_readings(model.couplings, model.joint_names, qa)
        for i in free:
            bad = np.flatnonzero(np.abs(q[a][:, i] - qa[:, i]) > COUPLING_TOL)
            if bad.size:
                r, j = bad[0], model.joint_names[i]
                raise DataFormatError(f"{table.path}: line {table.lines[r]}, column '{a}.{j}': reading "
                                      f"{qa[r, i] / f[i]:.6g} disagrees with the coupling of {j} "
                                      f"({q[a][r, i] / f[i]:.6g} from the joints it follows; model field "
                                      f"arms.{a}.couplings.{j})")
    return q


def _hung_arms(robot: Robot, arms, table: Table) -> list[str]:
    """The other arms of a tree with gravity whose weight loads the data set's arms' carriers and whose columns
    the file has (``<left>.<joint>``); a missing one is refused when the data set is used (naming it)."""
    hung = [o for arm in arms for o in model_loading_branches(robot, robot.lineage(arm))]
    return [o for o in dict.fromkeys(hung) if any(f"{o}.{j}" in table.header for j in robot[o].joint_names)]


def _plausible_units(ctx, table: Table, robot: Robot, ds: Dataset, u: dict) -> None:
    """Raise, naming file, line and column, on joint readings or measured lengths whose size does not fit the
    robot: a unit mix-up (``kincal.estimation.plausibility``)."""
    bad = implausible_units(robot, ds)
    if bad is None:
        return
    if bad.field == "q":
        raise DataFormatError(
            f"{table.path}: line {table.lines[bad.sample]}, column '{bad.arm}.{robot[bad.arm].joint_names[bad.joint]}':"
            f" expected a joint angle within +-4 pi rad, found {bad.value / ctx.angle:.6g} {u['angle']}: check "
            f"units.angle ('{u['angle']}') in {ctx.file}: are the readings in "
            f"{'degrees' if u['angle'] == 'rad' else 'other units'}?")
    f = SCHEMAS[ds.kind].field(bad.field)
    cols = _columns(f, table)[:3] if f.form == "pose" else _columns(f, table)
    if bad.column >= 0:
        raise DataFormatError(
            f"{table.path}: line {table.lines[bad.sample]}, column '{cols[bad.column]}': expected a length within "
            f"{bad.spread / ctx.length:.4g} {u['length']} of the column's median ({CELL_FACTOR:g} times the data's "
            f"size), found {bad.value / ctx.length:.6g} {u['length']}: not a measurement of this robot")
    raise DataFormatError(
        f"{table.path}: columns '{cols[0]}'..'{cols[-1]}': {bad.describe(robot)}: check units.length "
        f"('{u['length']}') in {ctx.file}{_unit_hint(bad.value, ctx.length)}")


def _limit_warnings(ctx, table: Table, robot: Robot, q: dict, u: dict) -> tuple[str, ...]:
    """Warnings (not errors: a robot may be driven past a limit set in software) on joint readings past the
    model's limits, per joint: the first lines, the first reading and the limit it is past, in file units."""
    out = []
    for a, j, rows, limit in past_limits(robot, q):
        prismatic = robot[a].joint_types[j] == PRISMATIC
        f, unit = (ctx.length, u["length"]) if prismatic else (ctx.angle, u["angle"])
        column = f"{a}.{robot[a].joint_names[j]}"
        lines = ", ".join(str(table.lines[r]) for r in rows[:MAX_ROW_WARNINGS])
        more = f" and {len(rows) - MAX_ROW_WARNINGS} more" if len(rows) > MAX_ROW_WARNINGS else ""
        shown = [_in_file_units(x, f, unit, prismatic) for x in (q[a][rows[0], j], limit)]
        out.append(f"{table.path}: line(s) {lines}{more}, column '{column}': reading {shown[0]} is past the "
                   f"joint limit {shown[1]} of model '{robot.name}'")
    return tuple(out)


def _in_file_units(x: float, factor: float, unit: str, prismatic: bool) -> str:
    """``x`` (SI) in the file's unit, with degrees beside an angle the file gives in another unit."""
    text = f"{x / factor:.6g} {unit}"
    return text if prismatic or unit == "deg" else f"{text} ({math.degrees(x):.4g} deg)"


def _unit_hint(ratio: float, length: float) -> str:
    """The length unit that would bring ``ratio`` closest to 1, as a question."""
    best = min(units.LENGTH, key=lambda n: abs(math.log(ratio * units.LENGTH[n] / length)))
    return f": are the columns in '{best}'?" if units.LENGTH[best] != length else ""


def _job_robot(ctx, resolved: str, robot: Robot | None, job_model: str | None) -> Robot:
    """The manifest's own model; with a job's ``robot`` (model ``job_model``), that robot when the manifest's
    model is another model of the same robot (same name, arms and joint names), else an error naming both."""
    try:
        own = load_robot(resolved)
    except KincalError as exc:
        if robot is None:
            raise ctx.fail("model", str(exc)) from None
        raise ctx.fail("model", f"'{resolved}' is not the job's model '{job_model}', and it cannot be "
                                f"read to compare: {exc}") from None
    if robot is None:
        return own
    if own.name != robot.name or any(a not in own.arms or own[a].joint_names != robot[a].joint_names
                                     for a in robot.arms):
        raise ctx.fail("model", f"'{resolved}' (robot '{own.name}') is not the job's model '{job_model}' "
                                f"(robot '{robot.name}'): the data were recorded on another robot")
    return robot


def _factor(ctx, unit: str) -> float:
    """The SI factor of a file's numbers of this unit kind."""
    return ctx.length if unit == LENGTH else ctx.angle if unit == ANGLE else 1.0


def _columns(f: Field, table: Table | None = None, count: int = 0) -> list[str]:
    """The CSV columns of a measured entry (points: as many as ``table``'s header lists, else ``count``)."""
    if f.form == "pose":
        return [f"{f.columns[0]}.{c}" for c in POSE_SUFFIXES]
    if f.form == "covariance":
        return [f"{f.columns[0]}.{COV_AXES[i]}.{COV_AXES[j]}" for i, j in zip(*COV_TRIU)]
    if f.form == "points":
        while table is not None and f"{f.columns[0]}{count + 1}.x" in table.col:
            count += 1
        return [f"{f.columns[0]}{i}.{c}" for i in range(1, count + 1) for c in "xyz"]
    return list(f.columns)


def _measured(ctx, schema: Schema, table: Table, known: dict) -> dict:
    out = {}
    for f in schema.measured:
        cols = _columns(f, table)
        if not f.required and not any(c in table.col for c in cols):
            continue
        if f.form == "points" and not cols:
            p = f.columns[0]
            raise DataFormatError(f"{table.path}: line {table.header_line}, column '{p}1.x': missing; kind "
                                  f"'{schema.kind}' needs columns {p}1.x, {p}1.y, {p}1.z (and {p}2.x ... for more)")
        out[f.key] = _READ_COLUMNS[f.form](ctx, f, table, cols, known)
    return out


# Rows listed per kind of impossible row at most; the count says how many there are.
MAX_ROW_WARNINGS = 5


def _impossible_rows(table: Table, measured: dict) -> tuple[str, ...]:
    """Warnings (not errors: the outlier rule leaves such rows out) on rows no instrument gives: a measured
    point or position exactly at the origin (a tracker that lost its target reports zeros), a row repeated
    exactly (a logger that wrote a reading twice)."""
    out = []
    for key, m in measured.items():
        m = np.asarray(m, float)
        pts = m[..., :3, 3] if m.shape[-2:] == (4, 4) else m
        if pts.shape[-1] != 3:
            continue
        zero = np.flatnonzero(np.all(pts.reshape(len(pts), -1, 3) == 0, axis=2).any(axis=1))
        out += _row_warning(table, zero, f"'{key}' has a point exactly at the origin (a lost target?)")
    _, first, inverse = np.unique(table.values, axis=0, return_index=True, return_inverse=True)
    out += _row_warning(table, np.flatnonzero(first[inverse.ravel()] != np.arange(len(table))),
                        "repeats an earlier row exactly")
    return tuple(out)


def _row_warning(table: Table, rows: np.ndarray, what: str) -> list[str]:
    if not len(rows):
        return []
    lines = ", ".join(str(table.lines[r]) for r in rows[:MAX_ROW_WARNINGS])
    more = f" and {len(rows) - MAX_ROW_WARNINGS} more" if len(rows) > MAX_ROW_WARNINGS else ""
    return [f"{table.path}: line(s) {lines}{more}: {what}"]


def _read_pose_columns(ctx, f: Field, table: Table, cols, known) -> np.ndarray:
    v = table.take(cols)
    norm = np.linalg.norm(v[:, 3:], axis=-1)
    bad = np.flatnonzero(np.abs(norm - 1) > QUAT_TOL)
    if bad.size:
        line = table.lines[bad[0]]
        raise DataFormatError(f"{table.path}: line {line}, column '{cols[3]}': expected a unit quaternion "
                              f"(norm 1 within {QUAT_TOL:g}), found norm {norm[bad[0]]:.9g}")
    return se3.make(quat_wxyz_to_matrix(v[:, 3:] / norm[:, None]), v[:, :3] * ctx.length)


def _read_index_column(ctx, f: Field, table: Table, cols, known) -> np.ndarray:
    idx = table.take(cols)[:, 0].astype(int)
    K = known[f.bound].shape[0]
    bad = np.flatnonzero((idx < 0) | (idx >= K))
    if bad.size:
        raise DataFormatError(f"{table.path}: line {table.lines[bad[0]]}, column '{cols[0]}': expected an index "
                              f"0..{K - 1} into known.{f.bound} (which lists {K}), found {idx[bad[0]]}")
    return idx


def _cov_scale(length: float, angle: float) -> np.ndarray:
    """SI / file factor of each entry of a pose covariance: position in ``length``, orientation in ``angle``."""
    f = np.array([length] * 3 + [angle] * 3)
    return np.outer(f, f)


def _read_covariance_columns(ctx, f: Field, table: Table, cols, known) -> np.ndarray:
    v = table.take(cols)
    C = np.zeros((len(v), 6, 6))
    C[:, COV_TRIU[0], COV_TRIU[1]] = v
    C[:, COV_TRIU[1], COV_TRIU[0]] = v
    bad = covariance_problem(C)
    if bad:
        raise DataFormatError(f"{table.path}: line {table.lines[bad[0]]}, columns '{cols[0]}'..'{cols[-1]}': expected "
                              f"a positive definite 6x6 covariance, found {bad[1]}")
    return C * _cov_scale(ctx.length, ctx.angle)


_READ_COLUMNS = {
    "pose": _read_pose_columns,
    "covariance": _read_covariance_columns,
    "points": lambda ctx, f, table, cols, known: table.take(cols).reshape(-1, len(cols) // 3, 3) * _factor(ctx, f.unit),
    "vector": lambda ctx, f, table, cols, known: table.take(cols) * _factor(ctx, f.unit),
    "index": _read_index_column,
}


def _known(ctx, schema: Schema, data: Any) -> dict:
    fields = {f.key: f for f in schema.known}
    d = _mapping(ctx, data, "known", set(fields), tuple(k for k, f in fields.items() if f.required))
    return {key: _READ_KNOWN[fields[key].form](ctx, fields[key], value, f"known.{key}") for key, value in d.items()}


def _read_list(ctx, value, path: str, what: str) -> list:
    if not isinstance(value, list) or not value:
        raise ctx.fail(path, f"expected a non-empty list of {what}")
    return value


def _read_plane(ctx, f: Field, value, path: str) -> np.ndarray:
    v = _vector(ctx, value, path, 4)
    norm = np.linalg.norm(v[:3])
    if abs(norm - 1) > 1e-6:
        raise ctx.fail(path, f"expected [nx, ny, nz, d] with a unit normal, found |n| = {norm:.9g}")
    return np.concatenate([v[:3], [v[3] * _factor(ctx, f.unit)]])


_READ_KNOWN = {
    "pose": lambda ctx, f, value, path: _pose(ctx, value, path),
    "poses": lambda ctx, f, value, path: np.stack(
        [_pose(ctx, v, f"{path}[{i}]") for i, v in enumerate(_read_list(ctx, value, path, "poses"))]),
    "points": lambda ctx, f, value, path: _matrix(
        ctx, _read_list(ctx, value, path, "[x, y, z]"), path, len(value), 3) * _factor(ctx, f.unit),
    "vector": lambda ctx, f, value, path: _vector(ctx, value, path, f.size) * _factor(ctx, f.unit),
    "scalar": lambda ctx, f, value, path: np.array(_number(ctx, value, path) * _factor(ctx, f.unit)),
    "plane": _read_plane,
}


# --------------------------------------------------------------------------------------------- writing


def _new_file(path: Path, overwrite: bool) -> Path:
    if path.exists() and not overwrite:
        raise DataFormatError(f"{path}: exists; refusing to overwrite it (pass overwrite=True / --overwrite)")
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def _pose_block(T: np.ndarray, length: float) -> dict:
    M = np.array(T, dtype=float)
    M[:3, 3] /= length
    return {"matrix": [[float(x) for x in row] for row in M]}


def _unit_factors(angle: str, length: str) -> dict[str, float]:
    return {LENGTH: units.factor("length", length, "length unit"), ANGLE: units.factor("angle", angle, "angle unit")}


def _plain_numbers(v, factors, unit) -> Any:
    return (np.asarray(v, dtype=float) / factors.get(unit, 1.0)).tolist()


_WRITE_KNOWN = {
    "pose": lambda v, factors, unit: _pose_block(v, factors[LENGTH]),
    "poses": lambda v, factors, unit: [_pose_block(T, factors[LENGTH]) for T in v],
    "points": _plain_numbers,
    "vector": _plain_numbers,
    "scalar": _plain_numbers,
    "plane": lambda v, factors, unit: [float(x) for x in v[:3]] + [float(v[3]) / factors.get(unit, 1.0)],
}


def dataset_to_dict(ds: Dataset, model: str, data_file: str, angle: str = "rad", length: str = "m") -> dict:
    """The manifest content of ``ds`` (known quantities in the given units)."""
    factors = _unit_factors(angle, length)
    schema = SCHEMAS[ds.kind]
    known = {k: _WRITE_KNOWN[schema.field(k).form](v, factors, schema.field(k).unit) for k, v in ds.known.items()}
    out = {"format": FORMAT, "version": VERSION, "name": ds.name, "kind": ds.kind, "model": model,
           "arms": list(ds.arms), "data": data_file, "units": {"angle": angle, "length": length}}
    if known:
        out["known"] = known
    if ds.frames:
        out["frames"] = dict(ds.frames)
    noise = dict(ds.meta.get("noise") or {})
    if noise:
        out["noise"] = {k: float(v) for k, v in noise.items()}
    if ds.meta.get("description"):
        out["description"] = str(ds.meta["description"])
    return out


_WRITE_COLUMNS = {
    "pose": lambda T, f: np.concatenate([T[:, :3, 3] / f, matrix_to_quat_wxyz(T[:, :3, :3])], axis=1),
    "covariance": lambda C, f: (C / _cov_scale(*f))[:, COV_TRIU[0], COV_TRIU[1]],
    "points": lambda p, f: p.reshape(len(p), -1) / f,
    "vector": lambda v, f: v / f,
    "index": lambda k, f: k[:, None].astype(float),
}


def write_dataset(
    ds: Dataset,
    manifest,
    robot: Robot,
    *,
    model: str | None = None,
    angle: str = "rad",
    length: str = "m",
    overwrite: bool = False,
) -> Path:
    """Write ``ds`` as ``manifest`` (YAML) plus a CSV of the same stem; returns the manifest path.

    ``robot`` gives the joint names and types; ``model`` is the manifest's model reference (default
    ``ds.robot``; an existing file path is written relative to the manifest). Units: ``angle`` 'rad'/'deg',
    ``length`` 'm'/'mm'. Floats are written with shortest round-trip text, so rad/m files reload exactly.
    """
    manifest = Path(manifest)
    fa = units.factor("angle", angle, "angle unit")
    fl = units.factor("length", length, "length unit")
    csv_path = manifest.with_suffix(".csv")
    model = ds.robot if model is None else model
    if Path(model).is_file():
        model = os.path.relpath(Path(model).resolve(), manifest.parent.resolve())
    header, cols = [], []
    if "t" in ds.meta:
        header.append("t")
        cols.append(np.asarray(ds.meta["t"], dtype=float)[:, None])
    for a in ds.q:  # the data set's arms, then those carrying them (a torso)
        m = robot[a]
        header += [f"{a}.{j}" for j in m.joint_names]
        f = np.array([fl if t == PRISMATIC else fa for t in m.joint_types])
        cols.append(ds.q[a] / f)
    is_int = [False] * len(header)
    for f in SCHEMAS[ds.kind].measured:
        if f.key in ds.measured:
            v = np.asarray(ds.measured[f.key])
            header += _columns(f, count=v.shape[1] if f.form == "points" else 0)
            factor = (fl, fa) if f.form == "covariance" else {LENGTH: fl, ANGLE: fa}.get(f.unit, 1.0)
            cols.append(_WRITE_COLUMNS[f.form](v, factor))
            is_int += [f.form == "index"] * cols[-1].shape[1]
    table = np.concatenate(cols, axis=1)
    _new_file(manifest, overwrite)
    _new_file(csv_path, overwrite)
    with open(csv_path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        for row in table:
            w.writerow([str(int(x)) if i else _fmt(x) for x, i in zip(row, is_int)])
    content = dataset_to_dict(ds, model, csv_path.name, angle, length)
    with open(manifest, "w", encoding="utf-8") as fh:
        yaml.safe_dump(content, fh, sort_keys=False, default_flow_style=None, width=120)
    return manifest


def write_truth(truth, directory, dataset: Dataset, *, overwrite: bool = False) -> Path:
    """Ground truth beside a data set, in ``directory``: ``robot.yaml`` (the true model, model-file format),
    ``truth.yaml`` (nuisance values in SI, noise, generator statistics) and ``q_true.csv`` (noise-free readings)."""
    directory = Path(directory)
    save_robot(truth.robot, _new_file(directory / "robot.yaml", overwrite), overwrite=True)
    values = {}
    for k, v in truth.values.items():
        v = np.asarray(v)
        values[k] = ([_pose_block(T, 1.0) for T in v] if v.ndim == 3 else _pose_block(v, 1.0)) if k.startswith("T_") \
            else v.tolist()
    content = {"format": "kincal-truth", "version": VERSION, "data_set": dataset.name, "robot": "robot.yaml",
               "units": {"angle": "rad", "length": "m"}, "values": values,
               "noise": truth.noise.as_si(), "meta": _plain(dict(truth.meta))}
    with open(_new_file(directory / "truth.yaml", overwrite), "w", encoding="utf-8") as fh:
        yaml.safe_dump(content, fh, sort_keys=False, default_flow_style=None, width=120)
    with open(_new_file(directory / "q_true.csv", overwrite), "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow([f"{a}.{j}" for a in truth.q for j in truth.robot[a].joint_names])
        for row in np.concatenate([truth.q[a] for a in truth.q], axis=1):
            w.writerow([_fmt(x) for x in row])
    return directory


def read_truth_values(path) -> dict[str, np.ndarray]:
    """The ``values`` block of a ``truth.yaml`` as arrays (SI)."""
    path = Path(path)
    data = read_yaml(path, "truth file")
    ctx = _Ctx(str(path))
    out = {}
    for k, v in (data.get("values") or {}).items():
        if k.startswith("T_"):
            out[k] = np.stack([_pose(ctx, b, f"values.{k}[{i}]") for i, b in enumerate(v)]) if isinstance(v, list) \
                else _pose(ctx, v, f"values.{k}")
        else:
            out[k] = np.asarray(v, dtype=float)
    return out


def _plain(x: Any) -> Any:
    if isinstance(x, Mapping):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return x


def write_simulation(directory, dataset: Dataset, truth, validation: Mapping[str, Dataset], robot: Robot, *,
                     model: str | None = None, angle: str = "rad", length: str = "m", overwrite: bool = False) -> dict:
    """The output of ``kincal simulate``: ``data.yaml``/``data.csv``, ``truth/`` and ``validation/<arm>.yaml``.

    ``robot`` is the nominal model (joint names); ``model`` the manifest's model reference (default ``dataset.robot``).
    """
    directory = Path(directory)
    paths = {"data": write_dataset(dataset, directory / "data.yaml", robot, model=model, angle=angle, length=length,
                                   overwrite=overwrite)}
    paths["truth"] = write_truth(truth, directory / "truth", dataset, overwrite=overwrite)
    for a, v in validation.items():
        paths[f"validation.{a}"] = write_dataset(v, directory / "validation" / f"{a}.yaml", robot, model=model,
                                                 angle=angle, length=length, overwrite=overwrite)
    return paths


# --------------------------------------------------------------------------------------------- scenarios

SCENARIO_FORMAT = "kincal-scenario"
_SCENARIO_KEYS = {"format", "version", "name", "model", "seed", "units", "truth", "experiment", "noise", "validation",
                  "output", "description"}
_EXPLORE_KEYS = {"n_seeds", "n_steps", "step_rad", "momentum"}
COMPLIANCE_KEY = "compliance_rad_per_Nm"


def _si_key(ctx, key: str, value: Any, path: str) -> tuple[str, float]:
    """``twist_mm: 1`` -> ('twist_m', 0.001); the suffix names the unit."""
    base, _, unit = str(key).rpartition("_")
    if unit in units.LENGTH:
        return f"{base}_m", _number(ctx, value, path) * units.LENGTH[unit]
    if unit in units.ANGLE:
        return f"{base}_rad", _number(ctx, value, path) * units.ANGLE[unit]
    raise ctx.fail(path, f"key must end in a unit ({', '.join(list(units.LENGTH) + list(units.ANGLE))}), "
                         f"found {quote(key)}")


BUILTIN_SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def scenario_path(name_or_path) -> Path:
    """A scenario file path, or the built-in scenario of that name (``frida_dual_bracket``)."""
    path = Path(name_or_path)
    if path.exists() or path.suffix:
        return path
    builtin = BUILTIN_SCENARIOS / f"{name_or_path}.yaml"
    if builtin.exists():
        return builtin
    names = ", ".join(sorted(p.stem for p in BUILTIN_SCENARIOS.glob("*.yaml")))
    raise DataFormatError(f"{name_or_path}: no such scenario file, and not a built-in scenario ({names})")


def file_header(ctx: _Ctx, path: Path, top: Mapping, fmt: str) -> tuple[Robot, str]:
    """The head of a scenario or study file: ``format`` and ``version`` checked, ``units`` read into ``ctx``
    (file units to SI), the model loaded: (robot, model reference)."""
    if top["format"] != fmt:
        raise ctx.fail("format", f"expected {quote(fmt)}, found {quote(top['format'])}")
    if top["version"] != VERSION:
        raise ctx.fail("version", f"expected {VERSION}, found {quote(top['version'])}")
    u = _mapping(ctx, top.get("units", {"length": "m", "angle": "rad"}), "units", {"length", "angle"},
                 ("length", "angle"))
    ctx.length = units.factor("length", u["length"], f"{path}: units.length")
    ctx.angle = units.factor("angle", u["angle"], f"{path}: units.angle")
    model = model_reference(path, str(top["model"]), f"{path}: model")
    try:
        return load_robot(model), model
    except KincalError as exc:
        raise ctx.fail("model", str(exc)) from None


def load_scenario(path) -> dict:
    """Read and check a scenario file (docs/simulation.md): plain data in SI units, for
    ``kincal.simulate.scenario.build_scenario``. The ``experiment:`` keys are the options its generator
    declares (``kincal.simulate.generators.OPTIONS``), each read by its type."""
    path = scenario_path(path)
    data = read_yaml(path, "scenario")
    ctx = _Ctx(str(path))
    top = _mapping(ctx, data, "(top level)", _SCENARIO_KEYS, ("format", "version", "model", "experiment"))
    robot, model = file_header(ctx, path, top, SCENARIO_FORMAT)
    kind, options = _experiment(ctx, top["experiment"], robot)
    out = _mapping(ctx, top.get("output") or {"angle": "rad", "length": "m"}, "output", {"angle", "length"})
    for q in ("angle", "length"):
        units.factor(q, out.get(q, "rad" if q == "angle" else "m"), f"{path}: output.{q}")
    seed = top.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ctx.fail("seed", f"expected a non-negative integer, found {quote(seed)}")
    n_val = top.get("validation", 100)
    if isinstance(n_val, bool) or not isinstance(n_val, int) or n_val < 1:
        raise ctx.fail("validation", f"expected a positive number of configurations, found {quote(n_val)}")
    return {"name": str(top.get("name") or path.stem), "robot": robot, "model": model, "kind": kind,
            "options": options, "truth": _truth(ctx, top.get("truth") or {}, robot),
            "noise": units.noise_from_file(top.get("noise") or {}, f"{ctx.file}: noise"), "validation": n_val,
            "seed": seed, "output": {"angle": out.get("angle", "rad"), "length": out.get("length", "m")}}


def _truth(ctx, data: Any, robot: Robot) -> dict:
    """``truth:``: a perturbation level, magnitudes overriding it (SI) and the arms to perturb; or ``errors``,
    explicit errors by parameter name (``truth_errors``)."""
    fields = [f for f in Perturbation.__dataclass_fields__ if f != "compliance"]
    allowed = (set(fields) | {"level", "arms", "errors", COMPLIANCE_KEY}
               | {f"{f.rpartition('_')[0]}_{u}" for f in fields for u in ("mm", "deg")})
    truth = _mapping(ctx, data, "truth", allowed)
    errors = truth_errors(ctx, truth.get("errors"), robot)
    if errors and set(truth) - {"errors"}:
        raise ctx.fail("truth", f"give explicit errors or a perturbation, not both (found "
                                f"{', '.join(sorted(set(truth) - {'errors'}))})")
    over = dict(_si_key(ctx, k, v, f"truth.{k}") for k, v in truth.items()
                if k not in ("level", "arms", "errors", COMPLIANCE_KEY))
    if COMPLIANCE_KEY in truth:  # joint compliances drawn in [0, value] (rad/(N m); prismatic joints m/N)
        c = _number(ctx, truth[COMPLIANCE_KEY], f"truth.{COMPLIANCE_KEY}")
        if not (np.isfinite(c) and c >= 0):
            raise ctx.fail(f"truth.{COMPLIANCE_KEY}", f"expected a compliance >= 0, found {quote(c)}")
        over["compliance"] = c
    level = ctx.one_of("truth.level", truth.get("level", "thesis"), PERTURBATION_LEVELS)
    arms = truth.get("arms")
    if arms is not None and (not isinstance(arms, list) or any(a not in robot.arms for a in arms)):
        raise ctx.fail("truth.arms", f"expected a list of arms of '{robot.name}' ({', '.join(robot.arms)}), "
                       f"found {quote(arms)}")
    return {"level": "none" if errors else level, "overrides": over, "arms": arms, "errors": errors}


def truth_errors(ctx, data: Any, robot: Robot) -> dict[str, float]:
    """``truth.errors``: the true robot's errors from the nominal one by parameter name (the names ``kincal
    calibrate`` reports), in the file's units: angles for radian coordinates, lengths for metre ones, others
    (compliances, rad/(N m)) in SI. Returned in SI."""
    if data is None:
        return {}
    errors = _mapping(ctx, data, "truth.errors", set(data) if isinstance(data, dict) else set())
    layout = build_layout(State.from_robot(robot), [])
    unit_of = dict(zip(layout.names, layout.units))
    out = {}
    for name, value in errors.items():
        if name not in unit_of:
            raise ctx.fail(f"truth.errors.{name}", f"no such parameter of '{robot.name}' (e.g. "
                                                   f"{', '.join(layout.names[:4])}, ...)")
        out[str(name)] = _number(ctx, value, f"truth.errors.{name}") * {"m": ctx.length, "rad": ctx.angle}.get(
            unit_of[name], 1.0)
    return out


def _experiment(ctx, exp: Any, robot: Robot) -> tuple[str, dict]:
    """(kind, generator keyword arguments) of ``experiment:``, each key read as its declared option."""
    kind = ctx.one_of("experiment.kind", exp.get("kind") if isinstance(exp, dict) else exp, GENERATOR_OPTIONS)
    declared = {o.name: o for o in GENERATOR_OPTIONS[kind]}
    exp = _mapping(ctx, exp, "experiment", set(declared) | {"kind"})
    options = {}
    for key, value in exp.items():
        if key != "kind":
            o = declared[key]
            options[o.argument] = _OPTION_READERS[o.type](ctx, o, value, f"experiment.{key}", robot)
    arm = next((o for o in declared.values() if o.type == "arm"), None)
    if arm is not None and arm.argument not in options and len(robot.arms) > 1:
        raise ctx.fail(f"experiment.{arm.name}", f"name the arm; '{robot.name}' has {', '.join(robot.arms)}")
    return kind, options


def _read_count(ctx, o, value, p, robot):
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ctx.fail(p, f"expected a positive integer, found {quote(value)}")
    return value


def _read_bool(ctx, o, value, p, robot):
    if not isinstance(value, bool):
        raise ctx.fail(p, f"expected true or false, found {quote(value)}")
    return value


def _read_arm(ctx, o, value, p, robot):
    if value not in robot.arms:
        raise ctx.fail(p, f"expected an arm of '{robot.name}' ({', '.join(robot.arms)}), found {quote(value)}")
    return value


def _read_arms(ctx, o, value, p, robot):
    if not isinstance(value, list) or len(value) != 2 or any(a not in robot.arms for a in value):
        raise ctx.fail(p, f"expected two arms of '{robot.name}' ({', '.join(robot.arms)}), found {quote(value)}")
    return tuple(value)


def _read_box(ctx, o, value, p, robot):
    w = _mapping(ctx, value, p, {"lower", "upper"}, ("lower", "upper"))
    f = _factor(ctx, o.unit)
    return _vector(ctx, w["lower"], f"{p}.lower", 3) * f, _vector(ctx, w["upper"], f"{p}.upper", 3) * f


def _read_explore(ctx, o, value, p, robot):
    e = _mapping(ctx, value, p, _EXPLORE_KEYS)
    return {k: (int(_number(ctx, v, f"{p}.{k}")) if k in ("n_seeds", "n_steps") else _number(ctx, v, f"{p}.{k}"))
            for k, v in e.items()}


def _read_wrench(ctx, o, value, p, robot):
    """Random loads of this magnitude (N), or one constant (fx, fy, fz, tx, ty, tz)."""
    if isinstance(value, list):
        return _vector(ctx, value, p, 6)
    w = _number(ctx, value, p)
    if not (np.isfinite(w) and w > 0):
        raise ctx.fail(p, f"expected a load magnitude > 0 (N) or [fx, fy, fz, tx, ty, tz], found {quote(value)}")
    return w


def _read_configurations(ctx, o, value, p, robot):
    """Joint readings, one list per configuration, in the scenario's angle (revolute) or length unit."""
    rows = _read_list(ctx, value, p, "configurations")
    if len(robot.arms) != 1:
        raise ctx.fail(p, f"fixed configurations need a model of one arm; '{robot.name}' has {', '.join(robot.arms)}")
    arm = next(iter(robot.arms.values()))
    q = np.array([_vector(ctx, r, f"{p}[{i}]", arm.dof) for i, r in enumerate(rows)])
    q = q * np.array([ctx.length if t == PRISMATIC else ctx.angle for t in arm.joint_types])
    for i, j in zip(*np.nonzero((q < arm.lower - 1e-9) | (q > arm.upper + 1e-9))):
        f = ctx.length if arm.joint_types[j] == PRISMATIC else ctx.angle
        raise ctx.fail(f"{p}[{i}][{j}]", f"expected a value of joint {arm.joint_names[j]} within its limits "
                       f"[{arm.lower[j] / f:g}, {arm.upper[j] / f:g}], found {quote(rows[i][j])}")
    return q


def _read_payload(ctx, o, value, p, robot):
    """``{mass_kg, com}``: the payload's mass and its centre of mass in the tool frame (length unit)."""
    d = _mapping(ctx, value, p, {"mass_kg", "com"}, ("mass_kg", "com"))
    mass = _number(ctx, d["mass_kg"], f"{p}.mass_kg")
    if mass <= 0:
        raise ctx.fail(f"{p}.mass_kg", f"expected a mass > 0 (kg), found {quote(d['mass_kg'])}")
    return mass, _vector(ctx, d["com"], f"{p}.com", 3) * ctx.length


_OPTION_READERS = {
    "count": _read_count,
    "bool": _read_bool,
    "arm": _read_arm,
    "arms": _read_arms,
    "pose": lambda ctx, o, value, p, robot: _pose(ctx, value, p),
    "poses": lambda ctx, o, value, p, robot: _READ_KNOWN["poses"](ctx, o, value, p),
    "point": lambda ctx, o, value, p, robot: _vector(ctx, value, p, 3) * _factor(ctx, o.unit),
    "points": lambda ctx, o, value, p, robot: _READ_KNOWN["points"](ctx, o, value, p),
    "vector": lambda ctx, o, value, p, robot: _READ_KNOWN["vector"](ctx, o, value, p),
    "box": _read_box,
    "explore": _read_explore,
    "wrench": _read_wrench,
    "configurations": _read_configurations,
    "payload": _read_payload,
}
