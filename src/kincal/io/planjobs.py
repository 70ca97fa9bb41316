"""Job data entries that name a plan instead of measured data (docs/job-format.md, "Planning without measured
data"): ``scenario:`` (a built-in scenario or a scenario file) or ``configurations:`` (a CSV of joint
configurations with the experiment that will measure them).

Either becomes a ``Dataset`` of the **nominal** robot's readings, so ``kincal analyze`` and ``kincal design`` run
on a job before anything is measured: a scenario's configurations as its generator draws them with its seed,
with its stated noise (``kincal analyze SCENARIO`` reads a scenario the same way); a configurations file's as
given, noise-free, stating no noise (the entry's ``noise:`` or kincal's default applies, as for any data set).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from kincal.data import Dataset
from kincal.errors import DataFormatError, KincalError
from kincal.schema import SCHEMAS
from kincal.io import units
from kincal.io.csvtable import read_table
from kincal.io.datasets import _experiment, load_scenario, scenario_path
from kincal.io.models import _Ctx
from kincal.io.references import resolve
from kincal.io.yamlfile import quote
from kincal.kinematics import Robot, forward_kinematics
from kincal.lie import se3
from kincal.simulate import GENERATORS, Noise
from kincal.simulate.perturb import perturbation
from kincal.simulate.scenario import build_scenario, run

KEYS = {"scenario": {"scenario", "noise", "frames"},
        "configurations": {"configurations", "experiment", "units", "noise", "frames"}}


def is_planned(entry: Any) -> bool:
    """Whether a job's data entry names a scenario or a configurations file."""
    return isinstance(entry, dict) and any(k in entry for k in KEYS)


def planned_source(entry: Mapping) -> str:
    """'scenario' or 'configurations': what a planned entry names."""
    return next(k for k in KEYS if k in entry)


def planned_dataset(where: str, job: Path, entry: Mapping, robot: Robot, root: Path | None = None) -> Dataset:
    """The data set of a planned entry (module docstring); ``where`` names the job file and the entry."""
    if all(k in entry for k in KEYS):
        raise DataFormatError(f"{where}: name either a scenario or a configurations file, not both")
    source = planned_source(entry)
    extra = set(entry) - KEYS[source]
    if extra:
        raise DataFormatError(f"{where}: unknown key(s) {sorted(extra)} for a {source} entry; expected some of "
                              f"{sorted(KEYS[source])}")
    if source == "scenario":
        ds = _scenario(where, job, entry["scenario"], robot, root)
    else:
        ds = _configurations(where, job, entry, robot, root)
    # marked, so that calibrate refuses it: the nominal robot's own readings fit the nominal model exactly
    return replace(ds, meta={**ds.meta, "planned": f"{source}: {entry[source]}"})


def scenario_file(where: str, job: Path, ref: Any, root: Path | None = None) -> Path:
    """A scenario named in a job: a file (a path with a suffix or a folder, relative to the job) or a built-in
    scenario's name."""
    if not isinstance(ref, str) or not ref:
        raise DataFormatError(f"{where}.scenario: expected a built-in scenario name or a scenario file, found "
                              f"{quote(ref)}")
    if Path(ref).suffix or "/" in ref:
        path = resolve(job, ref, f"{where}.scenario", root)
        if not path.is_file():
            raise DataFormatError(f"{where}.scenario: {path}: no such file")
        return path
    try:
        return scenario_path(ref)
    except KincalError as exc:
        raise DataFormatError(f"{where}.scenario: {exc}") from None


def _scenario(where: str, job: Path, ref: Any, robot: Robot, root) -> Dataset:
    spec = load_scenario(scenario_file(where, job, ref, root))
    if spec["robot"].name != robot.name:
        raise DataFormatError(f"{where}.scenario: {ref} is a scenario for the model '{spec['robot'].name}'; the "
                              f"job's model is '{robot.name}'")
    return scenario_dataset(spec, robot)[1]


def scenario_dataset(spec: Mapping, robot: Robot | None = None) -> tuple[Robot, Dataset]:
    """(robot, data set) of a scenario read by ``load_scenario``, simulated on the nominal ``robot`` (default:
    the scenario's own): its configurations and stated noise, its ``truth:`` ignored."""
    sc = build_scenario(spec)
    sc = replace(sc, robot=robot or sc.robot, perturbation=perturbation("none"))
    return sc.robot, run(sc)[1]


def _configurations(where: str, job: Path, entry: Mapping, robot: Robot, root) -> Dataset:
    ctx = _Ctx(where)
    u = entry.get("units") or {}
    if not isinstance(u, dict) or set(u) - {"length", "angle"}:
        raise ctx.fail("units", f"expected {{length: <unit>, angle: <unit>}}, found {quote(u)}")
    ctx.length = units.factor("length", u.get("length", "m"), f"{where}: units.length")
    ctx.angle = units.factor("angle", u.get("angle", "rad"), f"{where}: units.angle")
    if "experiment" not in entry:
        raise ctx.fail("experiment", "required with configurations: the experiment kind and its frames, as a "
                                     "scenario's experiment block (e.g. {kind: markers, arm: right, markers: 3})")
    exp = entry["experiment"]
    kind, options = _experiment(ctx, {"kind": exp} if isinstance(exp, str) else exp, robot)
    missing = [f.key for f in SCHEMAS[kind].measured if f.required and f.key not in _NOMINAL]
    if missing:
        raise ctx.fail("experiment.kind", f"'{kind}' measures {', '.join(missing)}, which kincal cannot predict "
                                          f"from configurations alone; name a scenario instead")
    path = resolve(job, str(entry["configurations"]), f"{where}.configurations", root)
    if not path.is_file():
        raise ctx.fail("configurations", f"{path}: no such file")
    options = {k: v for k, v in options.items() if k != "n"}  # the file's rows are the configurations
    ds, truth, _ = GENERATORS[kind](robot, n=1, rng=0, noise=Noise(), n_validation=1, **options)
    table = read_table(path, "configurations file")
    q = {a: table.take([f"{a}.{j}" for j in robot[a].joint_names]) * ctx.angle for a in ds.arms}
    extra = [c for c in table.header if c not in table.used]
    if extra:
        raise DataFormatError(f"{path}: line {table.header_line}, column '{extra[0]}': not a joint of the "
                              f"experiment's arms; expected the columns "
                              f"{', '.join(f'{a}.{j}' for a in ds.arms for j in robot[a].joint_names)}")
    measured = {k: f(robot, ds.arms, q, truth.values) for k, f in _NOMINAL.items()
                if any(m.key == k for m in SCHEMAS[kind].measured)}
    return Dataset(kind, robot.name, ds.arms, q, measured, dict(ds.known), path.stem, {})


def _tool_in_tracker(robot: Robot, arms, q, values) -> np.ndarray:
    (arm,) = arms
    return se3.inverse(values["T_world_tracker"]) @ forward_kinematics(robot[arm], q[arm])


def _markers_in_tracker(robot: Robot, arms, q, values) -> np.ndarray:
    return se3.transform_points(_tool_in_tracker(robot, arms, q, values)[:, None], values["p_tool_marker"][None])


# What the nominal robot's measurement is, per measured entry kincal can predict from configurations alone.
_NOMINAL = {"T_tracker_tool": _tool_in_tracker, "p_tracker_marker": _markers_in_tracker}
