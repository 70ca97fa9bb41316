"""The types of a job file, as a JSON Schema, checked before a job is interpreted (``kincal.io.jobs``).

Every problem becomes one line naming the file and the field, what was expected and what was found. The
schema checks types only where the job reader would otherwise trip over them; the reader itself then checks
the values with its own words (unknown top-level fields, solver method and loss, data entries, frames,
units, parameter globs).
"""

from __future__ import annotations

import math

import jsonschema

from kincal.errors import DataFormatError

_POSITIVE = {"type": "number", "exclusiveMinimum": 0}
_STRINGS = {"type": "array", "items": {"type": "string"}}
_NUMBERS = {"type": "object", "additionalProperties": {"type": "number"}}
_ENTRY = {"properties": {"manifest": {"type": "string"}, "noise": {"type": ["object", "null"]}}}

JOB_SCHEMA = {
    "type": "object",
    "properties": {
        "format": {"enum": ["kincal-job"]},
        "version": {"type": "integer", "enum": [1]},
        "name": {"type": "string"},
        "description": {"type": "string"},
        "confine": {"type": "boolean"},
        "model": {"type": "string"},
        "data": {"items": _ENTRY},
        "validation": {"items": _ENTRY},
        "free": {"oneOf": [{"type": "string"}, _STRINGS]},
        "fixed": {"type": ["array", "null"], "items": {"type": "string"}},
        "priors": {"type": ["object", "null"], "additionalProperties": _NUMBERS},
        "gauge": {"oneOf": [{"enum": ["min-change"]}, {**_STRINGS, "minItems": 1}]},
        "solver": {"type": ["object", "null"], "properties": {
            "method": {"type": "string"},
            "loss": {"type": "string"},
            "f_scale": _POSITIVE,
            "max_outer": {"type": "integer", "minimum": 1, "maximum": 10000},
            "rank_rtol": {"type": "number", "exclusiveMinimum": 0, "exclusiveMaximum": 1},
            "correlation_threshold": {"type": "number", "exclusiveMinimum": 0, "maximum": 1},
            "cv": {"type": "integer", "minimum": 2, "maximum": 1000},
        }},
        "constraints": {"type": ["array", "null"], "items": {"type": "object"}},
        "outliers": {"oneOf": [{"enum": ["reject", "keep"]}, {
            "type": "object", "required": ["threshold"], "additionalProperties": False,
            "properties": {"threshold": {"type": "number", "exclusiveMinimum": 0, "exclusiveMaximum": 1}}}]},
    },
}

_VALIDATOR = jsonschema.Draft202012Validator(JOB_SCHEMA)


def check_job_types(top, file: str) -> None:
    """Raise a one-line DataFormatError at the first field of ``top`` (a parsed job) of the wrong type."""
    _check_keys(top, file, ())
    _check_finite(top, file, ())
    error = jsonschema.exceptions.best_match(_VALIDATOR.iter_errors(top))
    if error is not None:
        raise DataFormatError(f"{file}: field {_path(error.absolute_path)}: {_expected(error)}, found "
                              f"{_short(error.instance)}")


def _check_keys(value, file: str, path: tuple) -> None:
    """Every mapping key is text (YAML allows numbers and lists as keys; a job never needs them)."""
    if isinstance(value, dict):
        for k, v in value.items():
            if not isinstance(k, str):
                raise DataFormatError(f"{file}: field {_path(path)}: expected text keys, found the key {_short(k)}")
            _check_keys(v, file, path + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _check_keys(v, file, path + (i,))


def _check_finite(value, file: str, path: tuple) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        raise DataFormatError(f"{file}: field {_path(path)}: expected a finite number, found {value!r}")
    children = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for k, v in children:
        _check_finite(v, file, path + (k,))


def _expected(error) -> str:
    """What the schema wanted, in words."""
    v = error.validator
    if v == "type":
        types = error.validator_value if isinstance(error.validator_value, list) else [error.validator_value]
        return "expected " + " or ".join({"string": "text", "array": "a list", "object": "a mapping",
                                          "integer": "an integer", "number": "a number",
                                          "null": "nothing"}.get(t, t) for t in types)
    if v == "enum":
        return "expected one of " + ", ".join(repr(x) for x in error.validator_value)
    if v == "additionalProperties":
        allowed = sorted(error.schema.get("properties", {}))
        return "unknown key(s); expected some of " + ", ".join(allowed) if allowed else "unexpected keys"
    if v == "required":
        return f"missing {error.message.split(' is a required')[0]}"
    if v in ("minimum", "exclusiveMinimum", "maximum", "exclusiveMaximum"):
        sign = {"minimum": ">=", "exclusiveMinimum": ">", "maximum": "<=", "exclusiveMaximum": "<"}[v]
        return f"expected a number {sign} {error.validator_value}"
    if v == "minItems":
        return f"expected at least {error.validator_value} item(s)"
    if v == "oneOf":
        return "expected " + {"free": "a level word or a list of names/globs",
                              "gauge": "'min-change' or a non-empty list of globs"}.get(
            str(error.absolute_path[-1]) if error.absolute_path else "", "a manifest path or {manifest: path, ...}")
    return "expected " + error.message.splitlines()[0][:120]


def _path(path) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out or "(top level)"


def _short(x) -> str:
    text = repr(x).replace("\n", " ")
    return text if len(text) <= 80 else text[:77] + "..."
