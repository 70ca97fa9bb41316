"""Write a calibration ``Result``: the calibrated model (model file format) and a report (YAML), never
replacing existing files. Reports use mm and deg for readability, with suffixed keys."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

from kincal.errors import DataFormatError
from kincal.estimation import Result
from kincal.io.models import save_robot

DEG = 180.0 / math.pi


def _f(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _stats(st: dict) -> dict:
    out = {k: v for k, v in st.items() if not (k.startswith("position") or k.startswith("orientation"))}
    for k, v in st.items():
        if k.startswith("position"):
            out[k.replace("position", "position_mm", 1)] = _f(v * 1e3)
        elif k.startswith("orientation"):
            out[k.replace("orientation", "orientation_deg", 1)] = _f(v * DEG)
    return out


def result_to_dict(result: Result) -> dict:
    ana = result.identifiability
    return {
        "format": "kincal-result",
        "version": 1,
        "status": result.status,
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
        "estimates": [
            {"name": e.name, "unit": e.unit, "value": _f(e.value), "nominal": _f(e.nominal), "std": _f(e.std),
             "identifiable": e.identifiable}
            for e in result.estimates
        ],
        "twists": [
            {"name": n, "value": _f(v), "std": _f(s) if result.twists[2] is not None else None}
            for n, v, s in zip(result.twists[0], result.twists[1],
                               result.twists[2] if result.twists[2] is not None else [math.nan] * len(result.twists[0]))
        ] if result.twists and len(result.twists[0]) else [],
        "correlated": [{"a": a, "b": b, "rho": r} for a, b, r in result.correlated],
        "residuals_before": [_stats(s) for s in result.before],
        "residuals_after": [_stats(s) for s in result.after],
        "validation": [_stats(s) for s in result.validation],
        "predict": prediction_rows(result),
        "frames": {k: np.asarray(v.as_array() if hasattr(v, "as_array") else v).tolist()
                   for k, v in result.extras.items()},
    }


def prediction_rows(result: Result) -> list[dict]:
    """Per validation set and calibrated arm: the predicted accuracy next to the actual validation errors of the
    set (mm, deg). Effects of undetermined directions are tool motion per unit norm of a direction in natural
    units: mm per mm-or-mrad and mrad per mm-or-mrad."""
    actual = {v["experiment"]: v for v in result.validation}
    rows = []
    for name, p in result.predictions:
        st, v = p.stats(), actual.get(name, {})
        row = {"set": name, "arm": p.arm, "samples": p.samples, "registered": p.registered,
               "tool_registered": p.tool_registered, "trusted": p.trusted,
               "position_mm_std_rms": _f(st["position_std_rms"] * 1e3),
               "position_mm_std_max": _f(st["position_std_max"] * 1e3),
               "orientation_deg_std_rms": _f(st["orientation_std_rms"] * DEG),
               "orientation_deg_std_max": _f(st["orientation_std_max"] * DEG)}
        for k, scale, unit in (("position_rms", 1e3, "mm"), ("position_max", 1e3, "mm"),
                               ("orientation_rms", DEG, "deg"), ("orientation_max", DEG, "deg")):
            if f"{k}_after" in v:
                quantity, stat = k.split("_")
                row[f"{quantity}_{unit}_{stat}_actual"] = _f(v[f"{k}_after"] * scale)
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


def write_results(result: Result, directory) -> dict[str, Path]:
    """``model.yaml`` (calibrated robot) and ``result.yaml`` in ``directory`` (created if needed).

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
    save_robot(result.robot, paths["model"])
    try:
        with open(paths["result"], "x", encoding="utf-8") as fh:
            yaml.safe_dump(result_to_dict(result), fh, sort_keys=False)
    except OSError as exc:
        raise DataFormatError(f"{paths['result']}: cannot write: {exc.strerror or exc}") from None
    return paths
