"""Study files (``format: kincal-study``, docs/partial-pose.md "Study files"): Monte Carlo studies of a
calibration, read and checked into plain data in SI units for ``kincal.workflow.study``.

A study is a scenario (model, truth, experiment, noise, validation: docs/simulation.md) repeated ``repeats``
times, each repeat calibrated by every variant. The scenario keys are read by the scenario reader's own
helpers, so they mean the same in both files.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

from kincal.errors import DataFormatError
from kincal.io import units
from kincal.io.datasets import _experiment, _truth, file_header
from kincal.io.jobs import parse_stages
from kincal.io.models import _Ctx, _mapping, _number
from kincal.io.yamlfile import quote, read_yaml

STUDY_FORMAT = "kincal-study"
BUILTIN_STUDIES = Path(__file__).resolve().parents[1] / "studies"
_KEYS = {"format", "version", "name", "description", "model", "seed", "repeats", "units", "truth", "experiment",
         "noise", "validation", "quantities", "variants"}
CONFIGURATIONS = ("fixed", "redrawn")
DATA = ("markers", "pose")
WEIGHTING = ("full", "diagonal", "equal")  # kincal.experiments.pose.WEIGHTS
# Calibration options a variant passes on to ``kincal.estimation.calibrate`` (checked there by their meaning);
# "stages" as in a job file (``kincal.io.jobs.parse_stages``).
CALIBRATE_OPTIONS = {"free", "fixed", "gauge", "loss", "f_scale", "max_outer", "outliers", "stages"}


def study_names() -> list[str]:
    """The built-in studies (``kincal/studies/*.yaml``), by name."""
    return sorted(p.stem for p in BUILTIN_STUDIES.glob("*.yaml"))


def study_path(name_or_path) -> Path:
    """A study file path, or the built-in study of that name (``table1``)."""
    path = Path(name_or_path)
    if path.exists() or path.suffix:
        return path
    if name_or_path in study_names():
        return BUILTIN_STUDIES / f"{name_or_path}.yaml"
    raise DataFormatError(f"{name_or_path}: no such study file, and not a built-in study ({', '.join(study_names())})")


def load_study(path) -> dict:
    """Read and check a study file: plain data in SI units (see the module docstring)."""
    path = study_path(path)
    ctx = _Ctx(str(path))
    top = _mapping(ctx, read_yaml(path, "study"), "(top level)", _KEYS,
                   ("format", "version", "model", "experiment", "variants"))
    robot, model = file_header(ctx, path, top, STUDY_FORMAT)
    u = top.get("units", {"length": "m", "angle": "rad"})  # checked by file_header
    exp = top["experiment"]
    if not isinstance(exp, dict):
        raise ctx.fail("experiment", f"expected a mapping with a kind, found {quote(exp)}")
    configurations = ctx.one_of("experiment.configurations", exp.get("configurations", "fixed"), CONFIGURATIONS)
    kind, options = _experiment(ctx, {k: v for k, v in exp.items() if k != "configurations"}, robot)
    return {"name": str(top.get("name") or path.stem), "file": str(path), "robot": robot, "model": model,
            "kind": kind, "options": options, "configurations": configurations,
            "truth": _study_truth(ctx, top.get("truth") or {}, robot),
            "noise": units.noise_from_file(top.get("noise") or {}, f"{ctx.file}: noise"),
            "validation": _count(ctx, top.get("validation", 100), "validation", minimum=0),
            "repeats": _count(ctx, top.get("repeats", 100), "repeats", minimum=2),
            "seed": _count(ctx, top.get("seed", 0), "seed", minimum=0),
            "units": {"length": u["length"], "angle": u["angle"]},
            "quantities": _quantities(ctx, top.get("quantities") or {}),
            "variants": _variants(ctx, top["variants"])}


def _count(ctx, value: Any, path: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ctx.fail(path, f"expected an integer >= {minimum}, found {quote(value)}")
    return value


def _study_truth(ctx, data: Any, robot) -> dict:
    """The scenario's ``truth:`` (a perturbation, or explicit ``errors`` by parameter name:
    ``kincal.io.datasets.truth_errors``) plus ``redraw:`` (a new true robot every repeat)."""
    data = _mapping(ctx, data, "truth", set(data) if isinstance(data, dict) else set())
    redraw = data.get("redraw", False)
    if not isinstance(redraw, bool):
        raise ctx.fail("truth.redraw", f"expected true or false, found {quote(redraw)}")
    out = _truth(ctx, {k: v for k, v in data.items() if k != "redraw"}, robot)
    out["redraw"] = redraw
    if redraw and out["errors"]:
        raise ctx.fail("truth.redraw", "explicit errors give one true robot; redraw needs a perturbation")
    return out


def _quantities(ctx, data: Any) -> dict:
    """``name: {parameter: coefficient, ...}``: reported linear combinations of the estimated parameters."""
    q = _mapping(ctx, data, "quantities", set(data) if isinstance(data, dict) else set())
    out = {}
    for name, combo in q.items():
        terms = _mapping(ctx, combo, f"quantities.{name}", set(combo) if isinstance(combo, dict) else set())
        if not terms:
            raise ctx.fail(f"quantities.{name}", "expected at least one parameter: coefficient")
        out[str(name)] = {str(k): _number(ctx, v, f"quantities.{name}.{k}") for k, v in terms.items()}
    return out


def _variants(ctx, data: Any) -> list[dict]:
    if not isinstance(data, list) or not data:
        raise ctx.fail("variants", f"expected a non-empty list of variants, found {quote(data)}")
    out, seen = [], set()
    for i, v in enumerate(data):
        where = f"variants[{i}]"
        v = _mapping(ctx, v, where, {"name", "data", "weighting", "length_per_radian", "noise_known"}
                     | CALIBRATE_OPTIONS, ("name",))
        name = v["name"]
        if not isinstance(name, str) or not name or name in seen:
            raise ctx.fail(f"{where}.name", f"expected a new variant name, found {quote(name)}")
        seen.add(name)
        data_kind = ctx.one_of(f"{where}.data", v.get("data", "markers"), DATA)
        weighting = ctx.one_of(f"{where}.weighting", v.get("weighting", "full"), WEIGHTING)
        if "weighting" in v and data_kind != "pose":
            raise ctx.fail(f"{where}.weighting", "applies to data: pose only (markers are weighted by their noise)")
        scale = v.get("length_per_radian", 1.0)  # equal weighting: this length (file units) weighs as 1 rad
        if "length_per_radian" in v and weighting != "equal":
            raise ctx.fail(f"{where}.length_per_radian", "applies to weighting: equal only")
        scale = _number(ctx, scale, f"{where}.length_per_radian") * (ctx.length if "length_per_radian" in v else 1.0)
        if scale <= 0:
            raise ctx.fail(f"{where}.length_per_radian", f"expected a length > 0, found {quote(v['length_per_radian'])}")
        noise_known = v.get("noise_known", True)
        if not isinstance(noise_known, bool) or ("noise_known" in v and weighting == "full"):
            raise ctx.fail(f"{where}.noise_known", "expected true or false, for weighting: diagonal or equal; found "
                                                   f"{quote(noise_known)} with weighting {weighting}")
        options = {k: v[k] for k in CALIBRATE_OPTIONS if k in v}
        _check_patterns(ctx, options, where)
        if "stages" in options:
            if {"free", "fixed"} & set(options):
                raise ctx.fail(f"{where}.stages", "with stages, give free and fixed in each stage instead")
            options["stages"] = tuple(parse_stages(ctx.file, options["stages"], f"{where}.stages"))
        out.append({"name": name, "data": data_kind, "weighting": weighting, "length_per_radian": scale,
                    "noise_known": noise_known, "options": options})
    return out


def _check_patterns(ctx, options: dict, where: str) -> None:
    free = options.get("free", "offsets")
    if not (isinstance(free, str) or (isinstance(free, list) and all(isinstance(x, str) for x in free))):
        raise ctx.fail(f"{where}.free", f"expected a level word or a list of names/globs, found {quote(free)}")
    fixed = options.get("fixed", [])
    if not (isinstance(fixed, list) and all(isinstance(x, str) for x in fixed)):
        raise ctx.fail(f"{where}.fixed", f"expected a list of names/globs, found {quote(fixed)}")
    if "max_outer" in options:
        _count(ctx, options["max_outer"], f"{where}.max_outer", minimum=1)
    for key in ("gauge", "loss"):
        if key in options and not isinstance(options[key], str):
            raise ctx.fail(f"{where}.{key}", f"expected a name, found {quote(options[key])}")


# --------------------------------------------------------------------------------------------- writing


def write_csv(path, rows: list[dict]) -> Path:
    """One table as CSV (header from the first row's keys); floats with 6 significant digits."""
    path = Path(path)
    with open(path, "x", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        if rows:
            w.writerow(list(rows[0]))
        for r in rows:
            w.writerow([f"{v:.6g}" if isinstance(v, float) else v for v in r.values()])
    return path
