"""Calibration job files (YAML, ``format: kincal-job``) <-> ``Job``; see docs/job-format.md.

Reading only: ``kincal.workflow.run_job`` runs a Job.

Paths in a job are relative to the job file (``kincal.io.references``); with ``confine`` (the job's key or
``load_job(confine=True)``, ``kincal calibrate --confine``) every file the job and its manifests name must lie
in the job's folder. Units appear only here, in suffixed keys
(``sigma_deg``, ``position_mm``); everything is converted to SI on reading.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

import yaml

from kincal.data import Dataset, frames_problem
from kincal.errors import DataFormatError
from kincal.estimation import FrameDistance
from kincal.estimation.stages import Stage, StageError, stage_problems
from kincal.noise import Noise, effective
from kincal.io import units
from kincal.io.datasets import load_dataset
from kincal.io.jobschema import check_job_types
from kincal.io.models import load_robot
from kincal.io.planjobs import is_planned, read_plan
from kincal.io.references import model_reference, resolve
from kincal.io.yamlfile import quote, read_yaml
from kincal.kinematics import Robot
from kincal.params import LEVELS, Prior

_TOP = {"format", "version", "name", "model", "data", "validation", "free", "fixed", "priors", "gauge", "solver",
        "description", "constraints", "outliers", "confine", "stages"}
_SOLVER = {"method", "loss", "f_scale", "max_outer", "rank_rtol", "correlation_threshold", "cv"}
_LOSSES = ("linear", "huber", "soft_l1", "cauchy", "arctan")


@dataclass(frozen=True, eq=False)
class Job:
    """A parsed job: the nominal robot, data sets (loaded), and every calibration option (SI)."""

    path: Path
    name: str
    robot: Robot
    datasets: tuple[Dataset, ...]
    validation: tuple[Dataset, ...] = ()
    free: str | tuple[str, ...] = "offsets"
    fixed: tuple[str, ...] = ()
    priors: Mapping[str, Prior] = field(default_factory=dict)
    noise: Mapping[str, Noise] = field(default_factory=dict)
    gauge: str | tuple[str, ...] = "min-change"
    method: str = "kincal"
    options: Mapping[str, Any] = field(default_factory=dict)  # loss, f_scale, max_outer, rank_rtol, ...
    constraints: tuple = ()  # FrameDistance
    outliers: str | float = "reject"  # reject | keep | a tail probability (``calibrate(outliers=...)``)
    model: str = ""  # the model reference as resolved: a built-in name or the model file's path
    stages: tuple[Stage, ...] = ()  # a staged solve (``calibrate(stages=...)``); ``free`` is then the last stage's


def load_job(path, confine: bool = False, plan=None) -> Job:
    """Read a job file; ``confine``: refuse file references outside the job's folder (as the job's own
    ``confine: true``). ``plan(Plan, robot) -> Dataset`` makes a data entry that names a plan a data set
    (``kincal.workflow.plan.load_plan_job``); without it such an entry is refused: a plan is not measured data."""
    path = Path(path)
    top = read_yaml(path, "job file")
    f = str(path)
    if not isinstance(top, dict):
        raise DataFormatError(f"{f}: expected a mapping at the top level, found {type(top).__name__}")
    check_job_types(top, f)
    unknown = set(top) - _TOP
    if unknown:
        raise DataFormatError(f"{f}: unknown field(s) {sorted(unknown)}; expected some of {sorted(_TOP)}")
    if top.get("format", "kincal-job") != "kincal-job":
        raise DataFormatError(f"{f}: field 'format' must be 'kincal-job', found {quote(top.get('format'))}")
    if top.get("version", 1) != 1:
        raise DataFormatError(f"{f}: field 'version' must be 1, found {quote(top.get('version'))}")
    if "model" not in top:
        raise DataFormatError(f"{f}: field 'model' is required (a built-in robot name or a model file path)")
    root = Path(os.path.realpath(path.parent)) if confine or top.get("confine", False) else None
    model = model_reference(path, str(top["model"]), f"{f}: model", root)
    robot = load_robot(model)
    refs = (path, model, root, plan)
    datasets, noise = _data(f, refs, top.get("data"), "data", robot, required=True)
    validation, _ = _data(f, refs, top.get("validation") or [], "validation", robot, required=False)
    free = _free(f, top.get("free", "offsets"), "free")
    fixed = _strings(f, top.get("fixed") or [], "fixed")
    gauge = top.get("gauge", "min-change")
    if not (gauge == "min-change" or isinstance(gauge, list)):
        raise DataFormatError(f"{f}: field 'gauge' must be 'min-change' or a list of globs, found {quote(gauge)}")
    gauge = gauge if isinstance(gauge, str) else _strings(f, gauge, "gauge")
    priors = {k: _prior(f, k, v) for k, v in (top.get("priors") or {}).items()}
    solver = top.get("solver") or {}
    if not isinstance(solver, dict) or set(solver) - _SOLVER:
        raise DataFormatError(f"{f}: field 'solver' must be a mapping with keys among {sorted(_SOLVER)}, found "
                              f"{quote(solver)}")
    method = solver.get("method", "kincal")
    if method not in ("kincal", "thesis"):
        raise DataFormatError(f"{f}: field solver.method is {quote(method)}; expected 'kincal' or 'thesis'")
    if solver.get("loss", "linear") not in _LOSSES:
        raise DataFormatError(f"{f}: field solver.loss is {quote(solver.get('loss'))}; expected one of "
                              f"{', '.join(_LOSSES)}")
    options = {k: v for k, v in solver.items() if k != "method"}
    for k in ("f_scale", "rank_rtol", "correlation_threshold", "max_outer"):
        if k in options and not (isinstance(options[k], (int, float)) and options[k] > 0):
            raise DataFormatError(f"{f}: field solver.{k} must be a positive number, found {quote(options[k])}")
    constraints = top.get("constraints") or []
    if not isinstance(constraints, list):
        raise DataFormatError(f"{f}: field 'constraints' must be a list, found {quote(constraints)}")
    constraints = tuple(_constraint(f"{f}: constraints[{i}]", c) for i, c in enumerate(constraints))
    job = Job(path, str(top.get("name", path.stem)), robot, datasets, validation, free, fixed, priors, noise, gauge,
              method, options, constraints, _outliers(f, top.get("outliers", "reject")), model)
    return _stages(f, top, job) if "stages" in top else job


def _free(f: str, free, key: str) -> str | tuple[str, ...]:
    """A ``free`` field: a level word or a list of names/globs."""
    if isinstance(free, str):
        if free not in LEVELS:
            raise DataFormatError(f"{f}: field '{key}' is {quote(free)}; expected {' or '.join(LEVELS)} or a list of "
                                  "names")
        return free
    if isinstance(free, list) and all(isinstance(x, str) for x in free):
        return tuple(free)
    raise DataFormatError(f"{f}: field '{key}' must be a level word or a list of names/globs, found {quote(free)}")


def parse_stages(f: str, spec, key: str = "stages") -> list[Stage]:
    """``[{name, free, fixed}, ...]`` -> Stage objects (names not yet checked against a model: ``stage_problems``);
    ``key`` names the field in errors."""
    if not isinstance(spec, list) or not spec:
        raise DataFormatError(f"{f}: field '{key}' must be a non-empty list of {{name, free, fixed}}, found "
                              f"{quote(spec)}")
    stages = []
    for i, st in enumerate(spec):
        where = f"{key}[{i}]"
        if not isinstance(st, dict) or "free" not in st:
            raise DataFormatError(f"{f}: field {where}: expected {{free: ..., fixed: [...], name: ...}} (free "
                                  f"required), found {quote(st)}")
        if set(st) - {"name", "free", "fixed"}:
            raise DataFormatError(f"{f}: field {where}: unknown key(s) {sorted(set(st) - {'name', 'free', 'fixed'})}; "
                                  "expected free, fixed, name")
        free = _free(f, st["free"], f"{where}.free")
        if not free:
            raise DataFormatError(f"{f}: field {where}.free: empty; a stage frees at least one parameter")
        if not isinstance(st.get("name", ""), str):
            raise DataFormatError(f"{f}: field {where}.name: expected text, found {quote(st['name'])}")
        stages.append(Stage(free, _strings(f, st.get("fixed") or [], f"{where}.fixed"), st.get("name", "")))
    return stages


def _stages(f: str, top: dict, job: Job) -> Job:
    """``stages: [{name, free, fixed}, ...]`` (docs/job-format.md "Staged solves"), every stage's free set
    checked against the job's model and data."""
    spec = top["stages"]
    for key in ("free", "fixed"):
        if key in top:
            raise DataFormatError(f"{f}: field '{key}': with 'stages', give '{key}' in each stage instead")
    if job.method != "kincal":
        raise DataFormatError(f"{f}: field 'stages' needs kincal's solver (solver.method 'kincal')")
    stages = parse_stages(f, spec)
    try:
        stage_problems(job.robot, job.datasets, stages, job.priors, job.noise, job.constraints)
    except StageError as exc:
        raise DataFormatError(f"{f}: field {exc.field}: {exc.reason}") from None
    return replace(job, stages=tuple(stages), free=stages[-1].free)  # free: what `kincal analyze` plans by default


def write_job(path, *, name: str, model: str, data, validation=(), free: str | list[str] = "offsets") -> Path:
    """Write a minimal job file (manifest paths relative to it); refuses to replace an existing file."""
    path = Path(path)
    job = {"format": "kincal-job", "version": 1, "name": name, "model": model,
           "data": [{"manifest": str(m)} for m in data], "validation": [{"manifest": str(m)} for m in validation],
           "free": free}
    try:
        with open(path, "x", encoding="utf-8") as fh:
            yaml.safe_dump(job, fh, sort_keys=False)
    except FileExistsError:
        raise DataFormatError(f"{path}: file exists; not overwritten (choose another output directory)") from None
    return path


def _outliers(f: str, spec) -> str | float:
    """``outliers: reject | keep | {threshold: p}`` -> ``calibrate``'s ``outliers`` (p a tail probability)."""
    if spec in ("reject", "keep"):
        return spec
    if isinstance(spec, dict) and set(spec) == {"threshold"}:
        p = spec["threshold"]
        if isinstance(p, (int, float)) and not isinstance(p, bool) and 0 < p < 1:
            return float(p)
    raise DataFormatError(f"{f}: field 'outliers' must be 'reject', 'keep' or {{threshold: p}} with p a tail "
                          f"probability in (0, 1) (e.g. 1e-6), found {quote(spec)}")


def _constraint(where, spec):
    """``{distance: [frame_a, frame_b], value_<unit>: d, sigma_<unit>: s}`` -> FrameDistance (SI)."""
    if not isinstance(spec, dict) or "distance" not in spec:
        raise DataFormatError(f"{where}: expected {{distance: [frame_a, frame_b], value_mm: ..., sigma_mm: ...}}, "
                              f"found {quote(spec)}")
    frames = spec["distance"]
    if not (isinstance(frames, list) and len(frames) == 2 and all(isinstance(x, str) for x in frames)):
        raise DataFormatError(f"{where}: field distance must name two frames, found {quote(frames)}")
    out = {}
    for k, v in spec.items():
        if k == "distance":
            continue
        base, _, unit = k.partition("_")
        if base not in ("value", "sigma") or base in out:
            raise DataFormatError(f"{where}: unknown key {quote(k)}; expected value_<unit> and sigma_<unit>")
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0):
            raise DataFormatError(f"{where}: {k} must be a positive number, found {quote(v)}")
        out[base] = float(v) * units.factor("length", unit, f"{where}: {k}")
    if set(out) != {"value", "sigma"}:
        raise DataFormatError(f"{where}: expected value_<unit> and sigma_<unit>, found {sorted(spec)}")
    return FrameDistance(frames[0], frames[1], out["value"], out["sigma"])


def _strings(f, x, key) -> tuple[str, ...]:
    if not isinstance(x, list) or not all(isinstance(s, str) for s in x):
        raise DataFormatError(f"{f}: field '{key}' must be a list of strings, found {quote(x)}")
    return tuple(x)


def _data(f, refs: tuple, entries, key, robot, required):
    """The data sets of ``entries``; ``refs``: (job file, its resolved model reference, confining folder, plan
    materializer or None)."""
    job, model, root, plan = refs
    if not isinstance(entries, list) or (required and not entries):
        raise DataFormatError(f"{f}: field '{key}' must be a non-empty list of data sets ({{manifest: path}})")
    datasets, noise = [], {}
    for i, e in enumerate(entries):
        where = f"{f}: {key}[{i}]"
        if isinstance(e, str):
            e = {"manifest": e}
        if is_planned(e):  # a scenario or configurations file instead of measured data (kincal.io.planjobs)
            ds = _planned(where, job, e, robot, root, plan)
            datasets.append(ds if e.get("frames") is None else _frames(where, e["frames"], ds, robot))
            noise[ds.name] = _noise(where, e.get("noise"), ds)
            continue
        if not isinstance(e, dict) or "manifest" not in e or set(e) - {"manifest", "noise", "frames"}:
            raise DataFormatError(f"{where}: expected a manifest path, {{manifest: path, noise: {{...}}, frames: "
                                  f"{{...}}}}, {{scenario: ...}} or {{configurations: ...}}, found {quote(e)}")
        manifest = resolve(job, str(e["manifest"]), f"{where}.manifest", root)
        ds = load_dataset(manifest, robot, job_model=model, root=root)
        if e.get("frames") is not None:
            ds = _frames(where, e["frames"], ds, robot)
        datasets.append(ds)
        noise[ds.name] = _noise(where, e.get("noise"), ds)
    return tuple(datasets), noise


def _planned(where, job, entry, robot, root, plan) -> Dataset:
    p = read_plan(where, job, entry, robot, root)
    if plan is None:
        raise DataFormatError(f"{where}: the data set is a plan ({p.label}), not measured data: its readings would "
                              "be the nominal model's own, which any calibration fits exactly; plans are for `kincal "
                              "analyze` and `kincal design`. Calibrate measured data, or `kincal simulate` the "
                              "scenario and calibrate its job to try the calibration")
    return plan(p, robot)


def _frames(where, frames, ds: Dataset, robot: Robot) -> Dataset:
    """The data set with the job's frame names (role -> name) over the manifest's own."""
    bad = frames_problem(ds.kind, frames, tuple(robot.arms))
    if bad:
        raise DataFormatError(f"{where}: field {bad[0]}: {bad[1]}")
    return replace(ds, frames={**ds.frames, **frames})


def _noise(where, data, ds: Dataset) -> Noise:
    """The one noise rule (``kincal.noise.effective``): the job's noise (position_mm, orientation_deg, joint_deg,
    ...) over the data set's own stated noise, over kincal's default."""
    return effective(units.noise_from_file(data or {}, f"{where}: noise"), ds.meta.get("noise"))


def _prior(f, name, spec) -> Prior:
    where = f"{f}: priors['{name}']"
    if not isinstance(spec, dict) or len([k for k in spec if k.startswith("sigma")]) != 1:
        raise DataFormatError(f"{where}: expected {{sigma_<unit>: value}} with optional mean_<unit>, found "
                              f"{quote(spec)}")
    out = {}
    for k, v in spec.items():
        base, _, unit = k.partition("_")
        if base not in ("sigma", "mean"):
            raise DataFormatError(f"{where}: unknown key {quote(k)}; expected sigma_<unit> and optional mean_<unit>")
        kind = "angle" if unit in units.ANGLE else "length"
        if not (isinstance(v, (int, float)) and math.isfinite(v)):
            raise DataFormatError(f"{where}: {k} must be a finite number, found {quote(v)}")
        out[base] = float(v) * units.factor(kind, unit, f"{where}: {k}")
    if out["sigma"] <= 0:
        raise DataFormatError(f"{where}: sigma must be positive, found {spec}")
    return Prior(out["sigma"], out.get("mean", 0.0))
