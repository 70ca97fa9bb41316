"""Job data entries that name a plan instead of measured data (docs/job-format.md, "Planning without measured
data"): ``scenario:`` (a built-in scenario or a scenario file) or ``configurations:`` (a CSV of joint
configurations with the experiment that will measure them).

Reading only: an entry becomes a ``Plan`` (the scenario as ``load_scenario`` reads it, or the experiment and the
configurations table); ``kincal.workflow.plan`` turns a Plan into the **nominal** robot's readings, so that
``kincal analyze`` and ``kincal design`` run on a job before anything is measured.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from kincal.errors import DataFormatError, KincalError
from kincal.schema import SCHEMAS
from kincal.io import units
from kincal.io.csvtable import Table, read_table
from kincal.io.datasets import _experiment, load_scenario, scenario_path
from kincal.io.models import _Ctx
from kincal.io.references import resolve
from kincal.io.yamlfile import quote
from kincal.kinematics import Robot

KEYS = {"scenario": {"scenario", "noise", "frames"},
        "configurations": {"configurations", "experiment", "units", "noise", "frames"}}
# What kincal can predict from configurations alone (``kincal.workflow.plan`` computes each at the nominal).
PREDICTABLE = ("T_tracker_tool", "p_tracker_marker")


@dataclass(frozen=True)
class Plan:
    """A planned data entry as read: ``where`` (job file and entry), ``label`` ('scenario: NAME' or
    'configurations: FILE'); a scenario's ``scenario`` (as ``load_scenario`` returns it), or a configurations
    file's experiment ``kind`` and generator ``options``, its ``table`` and the ``angle`` factor of its unit."""

    where: str
    label: str
    scenario: Mapping | None = None
    kind: str = ""
    options: Mapping[str, Any] = field(default_factory=dict)
    table: Table | None = None
    angle: float = 1.0
    name: str = ""


def is_planned(entry: Any) -> bool:
    """Whether a job's data entry names a scenario or a configurations file."""
    return isinstance(entry, dict) and any(k in entry for k in KEYS)


def planned_source(entry: Mapping) -> str:
    """'scenario' or 'configurations': what a planned entry names."""
    return next(k for k in KEYS if k in entry)


def read_plan(where: str, job: Path, entry: Mapping, robot: Robot, root: Path | None = None) -> Plan:
    """The Plan of a planned entry (module docstring); ``where`` names the job file and the entry."""
    if all(k in entry for k in KEYS):
        raise DataFormatError(f"{where}: name either a scenario or a configurations file, not both")
    source = planned_source(entry)
    extra = set(entry) - KEYS[source]
    if extra:
        raise DataFormatError(f"{where}: unknown key(s) {sorted(extra)} for a {source} entry; expected some of "
                              f"{sorted(KEYS[source])}")
    label = f"{source}: {entry[source]}"
    if source == "scenario":
        return Plan(where, label, scenario=_scenario(where, job, entry["scenario"], robot, root))
    return _configurations(where, label, job, entry, robot, root)


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


def _scenario(where: str, job: Path, ref: Any, robot: Robot, root) -> Mapping:
    spec = load_scenario(scenario_file(where, job, ref, root))
    if spec["robot"].name != robot.name:
        raise DataFormatError(f"{where}.scenario: {ref} is a scenario for the model '{spec['robot'].name}'; the "
                              f"job's model is '{robot.name}'")
    return spec


def _configurations(where: str, label: str, job: Path, entry: Mapping, robot: Robot, root) -> Plan:
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
    missing = [f.key for f in SCHEMAS[kind].measured if f.required and f.key not in PREDICTABLE]
    if missing:
        raise ctx.fail("experiment.kind", f"'{kind}' measures {', '.join(missing)}, which kincal cannot predict "
                                          f"from configurations alone; name a scenario instead")
    path = resolve(job, str(entry["configurations"]), f"{where}.configurations", root)
    if not path.is_file():
        raise ctx.fail("configurations", f"{path}: no such file")
    options = {k: v for k, v in options.items() if k != "n"}  # the file's rows are the configurations
    return Plan(where, label, kind=kind, options=options, table=read_table(path, "configurations file"),
                angle=ctx.angle, name=path.stem)
