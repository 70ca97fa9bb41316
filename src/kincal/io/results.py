"""Write a calibration ``Result`` or a thesis baseline's result: the calibrated model (model file format) and a
report (YAML, one schema for both), never replacing existing files. Reports use mm and deg for readability, with suffixed keys."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

from kincal.baselines.thesis_common import BaselineResult
from kincal.errors import DataFormatError
from kincal.estimation import ResidualStats, Result, ValidationStats
from kincal.kinematics import Robot
from kincal.io.models import save_robot

DEG = 180.0 / math.pi


def _f(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


_PARTS = (("position_rms", "position_mm_rms", 1e3), ("position_max", "position_mm_max", 1e3),
          ("orientation_rms", "orientation_deg_rms", DEG), ("orientation_max", "orientation_deg_max", DEG))


def _stats(st: ResidualStats) -> dict:
    """One data set's residual statistics in mm and deg; absent parts left out."""
    out = {"experiment": st.experiment, "kind": st.kind, "samples": st.samples, "chi2": st.chi2, "dof": st.dof}
    for field, key, scale in _PARTS:
        if getattr(st, field) is not None:
            out[key] = _f(getattr(st, field) * scale)
    return out


def _validation(v: ValidationStats) -> dict:
    """A held-out data set's errors before and after calibration, in mm and deg."""
    out = {"experiment": v.experiment, "kind": v.kind, "samples": v.samples}
    for field, key, scale in _PARTS:
        if getattr(v.before, field) is not None:
            out[f"{key}_before"] = _f(getattr(v.before, field) * scale)
            out[f"{key}_after"] = _f(getattr(v.after, field) * scale)
    return out


def result_to_dict(result: Result | BaselineResult) -> dict:
    """The report of a kincal ``Result`` or of a thesis baseline's ``BaselineResult``, one schema: ``format``,
    ``version``, ``method``, ``status``, ``iterations``, ``messages``, ``estimates`` (a list of entries with
    ``name`` and ``value``), ``validation``; kincal adds its identifiability, uncertainty and statistics (the
    change from nominal split into ``determined`` and ``gauge_move`` in the stated ``gauge``, and the ``derived``
    quantities: axis geometry and tool pose at the nominal zero, docs/formats.md), the
    baseline the thesis' Eval_error before and after. ``outliers``: the rows left out of the solve,
    ``data_warnings``: impossible rows the loaders found."""
    if isinstance(result, BaselineResult):
        return _baseline_to_dict(result)
    ana = result.identifiability
    return {
        "format": "kincal-result",
        "version": 1,
        "method": "kincal",
        "status": result.status,
        "trusted": result.trusted,
        "iterations": result.iterations,
        "evaluations": result.evaluations,
        "residual_variance_factor": _f(result.sigma2),
        "rank": ana.rank,
        "free_parameters": len(ana.names),
        "condition_number": _f(ana.condition),
        "rank_rtol": ana.rtol,
        "messages": list(result.messages),
        "unidentifiable": [{"pivot": d.pivot, "partners": {n: v for n, v in d.partners}, "words": d.words}
                           for d in ana.directions],
        "scale_unidentifiable": bool(ana.scale_unidentifiable),
        "gauge": _gauge(result),
        "estimates": [
            {"name": e.name, "unit": e.unit, "value": _f(e.value), "nominal": _f(e.nominal), "std": _f(e.std),
             "identifiable": e.identifiable, **_split(result, e.name)}
            for e in result.estimates
        ],
        "derived": [{"name": d.name, "unit": d.unit, "value": _f(d.value), "nominal": _f(d.nominal), "std": _f(d.std),
                     "identifiable": d.identifiable, "words": d.words} for d in result.derived],
        "twists": [{"name": t.name, "value": _f(t.value), "std": _f(t.std)} for t in result.twists],
        "correlated": [{"a": a, "b": b, "rho": r} for a, b, r in result.correlated],
        "outliers": [_outlier(o) for o in result.outliers],
        "data_warnings": data_warnings(result),
        "residuals_before": [_stats(s) for s in result.before],
        "residuals_after": [_stats(s) for s in result.after],
        "validation": [_validation(v) for v in result.validation],
        "predict": prediction_rows(result),
        "validation_outliers": [_outlier(o) for o in result.validation_outliers],
        "validation_all_rows": [_validation(v) for v in result.validation_all],
        "cross_validation": cross_validation_dict(result.cross_validation),
        "stages": stage_rows(result),
        "frames": {k: np.asarray(v.as_array() if hasattr(v, "as_array") else v).tolist()
                   for k, v in result.extras.items()},
    }


def stage_rows(result: Result) -> list[dict]:
    """A staged solve's stages in order (docs/calibration.md "Staged solves"): the free set as given, free
    coordinates and rank, whitened chi^2, residual variance factor, status, outer iterations, position and
    orientation RMS over every data set (mm, deg) and the residual statistics per data set at the stage's end.
    Empty for a single solve."""
    return [{"name": s.name, "free": s.free if isinstance(s.free, str) else list(s.free), "fixed": list(s.fixed),
             "free_parameters": s.parameters, "rank": s.rank, "chi2": _f(s.cost),
             "residual_variance_factor": _f(s.sigma2), "status": s.status, "iterations": s.iterations,
             "position_mm_rms": None if s.rms("position") is None else _f(s.rms("position") * 1e3),
             "orientation_deg_rms": None if s.rms("orientation") is None else _f(s.rms("orientation") * DEG),
             "residuals": [_stats(x) for x in s.after]} for s in result.stages]


def _outlier(o) -> dict:
    return {"experiment": o.experiment, "sample": o.sample, "line": o.line, "file": o.file,
            "standardized_residual": _f(o.standardized)}


def cross_validation_dict(cv) -> dict | None:
    """``calibrate(..., cv=K)``'s folds: per fold the held-out RMS (outlying rows left out, and with them) and
    the RMS predicted from its training fit (mm, deg), then the same pooled over the folds and the
    cross-validated model error the predictions carry. None without a cross-validation."""
    if cv is None:
        return None

    def part(h, scale, unit, quantity):
        if not h.groups_all:
            return {}
        return {f"{quantity}_{unit}_rms_actual": _f(h.rms * scale), f"{quantity}_{unit}_rms_predicted":
                _f(h.rms_predicted * scale), f"{quantity}_{unit}_rms_actual_with_outliers": _f(h.rms_all * scale),
                f"{quantity}_outlying_rows": h.flagged}

    def figures(get):
        return {**part(get("position"), 1e3, "mm", "position"), **part(get("orientation"), DEG, "deg", "orientation")}

    return {"folds": cv.k, "seed": cv.seed,
            "per_fold": [{"fold": f.index, "held_out": dict(f.held_out), "status": f.status,
                          "residual_variance_factor": _f(f.sigma2), **figures(lambda q: getattr(f, q))}
                         for f in cv.folds],
            "overall": figures(cv.pooled),
            "model_error_position_mm": _f(cv.position_model * 1e3),
            "model_error_orientation_deg": _f(cv.orientation_model * DEG)}


def _gauge(result: Result) -> dict | None:
    """The gauge of the estimates' ``determined`` part and of the derived quantities' standard deviations."""
    g = result.gauge
    return None if g is None else {"name": g.name, "description": g.description}


def _split(result: Result, name: str) -> dict:
    """One estimate's change from nominal split in the gauge: ``determined`` (with ``determined_std``) and
    ``gauge_move``; empty without a gauge (a degenerate solve)."""
    if result.gauge is None:
        return {}
    d, s, g = result.gauge.split(name)
    return {"determined": _f(d), "determined_std": _f(s), "gauge_move": _f(g)}


def data_warnings(result: Result) -> list[str]:
    """The loaders' warnings on the data sets solved (impossible rows: ``kincal.io.datasets``)."""
    exps = result.problem.experiments if result.problem is not None else ()
    return [w for e in exps for w in e.dataset.meta.get("warnings", ())]


def _baseline_to_dict(res: BaselineResult) -> dict:
    before, after = res.initial_error, res.final_error
    return {
        "format": "kincal-result",
        "version": 1,
        "method": res.method,
        "status": res.status,
        "iterations": res.iterations_label,  # the thesis' notation: run(accepted)
        "messages": ["no identifiability analysis or standard deviations: the thesis' method has none"],
        "estimates": [{"name": e.name, "value": _f(e.value)} for e in res.estimates],
        "eval_error_before": {"translation_m": before[0], "rotation_rad": before[1]},
        "eval_error_after": {"translation_m": after[0], "rotation_rad": after[1]},
        "validation": [_validation(v) for v in res.validation],
    }


def prediction_rows(result: Result) -> list[dict]:
    """Per validation set and calibrated arm: the predicted accuracy next to the actual validation errors of the
    set (mm, deg): standard deviations, the RMS error to expect (``*_rms_predicted``: standard deviations,
    stated measurement noise and unexplained model error in quadrature), the trust verdict and its doubts. Effects of undetermined directions are tool motion per unit norm of a direction in natural
    units: mm per mm-or-mrad and mrad per mm-or-mrad."""
    actual = {v.experiment: v.after for v in result.validation}
    rows = []
    for name, p in result.predictions:
        st, after = p.stats(), actual.get(name)
        row = {"set": name, "arm": p.arm, "samples": p.samples, "registered": p.registered,
               "tool_registered": p.tool_registered, "trusted": p.trusted,
               "position_mm_std_rms": _f(st["position_std_rms"] * 1e3),
               "position_mm_std_max": _f(st["position_std_max"] * 1e3),
               "orientation_deg_std_rms": _f(st["orientation_std_rms"] * DEG),
               "orientation_deg_std_max": _f(st["orientation_std_max"] * DEG),
               "position_mm_rms_predicted": _f(st["position_rms_predicted"] * 1e3),
               "orientation_deg_rms_predicted": _f(st["orientation_rms_predicted"] * DEG),
               "position_mm_noise_rms": _f(st["position_noise_rms"] * 1e3),
               "orientation_deg_noise_rms": _f(st["orientation_noise_rms"] * DEG),
               "position_mm_model_error": _f(st["position_model"] * 1e3),
               "orientation_deg_model_error": _f(st["orientation_model"] * DEG),
               "doubts": list(p.doubts)}
        for field, key, scale in _PARTS:
            if after is not None and getattr(after, field) is not None:
                row[f"{key}_actual"] = _f(getattr(after, field) * scale)
        for key, moving, pos, rot in (("unidentifiable", p.null_moving, "null_position_max", "null_orientation_max"),
                                      ("weak", p.weak_moving, "weak_position_max", "weak_orientation_max")):
            row[f"{key}_moving"] = moving
            row[f"{key}_position_mm_per_unit_max"] = _f(st[pos])
            row[f"{key}_orientation_mrad_per_unit_max"] = _f(st[rot])
        row["directions"] = [{"kind": d.kind, "pivot": d.pivot, "position_mm_per_unit": _f(d.position),
                              "orientation_mrad_per_unit": _f(d.orientation)} for d in p.directions[:5]]
        row["messages"] = list(p.messages)
        rows.append(row)
    return rows


def write_results(result: Result | BaselineResult, directory, robot: Robot | None = None,
                  provenance: dict | None = None) -> dict[str, Path]:
    """``model.yaml`` (calibrated robot) and ``result.yaml`` (``result_to_dict``) in ``directory`` (created if
    needed). ``robot``: the calibrated robot of a baseline (``BaselineResult.calibrated``); a ``Result`` has its own.
    ``provenance``: job, input files with SHA-256, versions and date (``kincal.workflow.provenance``).

    Refuses to run if either file exists, before writing anything.
    """
    d = Path(directory)
    paths = {"model": d / "model.yaml", "result": d / "result.yaml"}
    existing = [str(p) for p in paths.values() if p.exists()]
    if existing:
        raise DataFormatError(f"{', '.join(existing)}: file exists; not overwritten (choose another output directory)")
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataFormatError(f"{d}: cannot create output directory: {exc.strerror or exc}") from None
    save_robot(result.robot if robot is None else robot, paths["model"])
    try:
        with open(paths["result"], "x", encoding="utf-8") as fh:
            yaml.safe_dump({**result_to_dict(result), **({"provenance": provenance} if provenance else {})}, fh,
                           sort_keys=False)
    except OSError as exc:
        raise DataFormatError(f"{paths['result']}: cannot write: {exc.strerror or exc}") from None
    return paths
