"""Unit names accepted in files and on the command line, and their factors to SI."""

from __future__ import annotations

import math
import re

from kincal.errors import DataFormatError
from kincal.io.yamlfile import quote
from kincal.noise import Noise

LENGTH = {"m": 1.0, "mm": 1e-3}
ANGLE = {"rad": 1.0, "deg": 0.017453292519943295}  # pi / 180


def factor(kind: str, name: str, where: str) -> float:
    """SI factor of unit ``name`` ('length' or 'angle'); ``where`` names file and field for the error."""
    table = {"length": LENGTH, "angle": ANGLE}[kind]
    try:
        return table[name]
    except (KeyError, TypeError):
        raise DataFormatError(
            f"{where}: unknown {kind} unit {quote(name)}; expected one of {', '.join(repr(k) for k in table)}"
        ) from None


# A noise key is ``<quantity>_<unit>``; the quantity decides which unit table applies.
NOISE_UNITS = {"position": "length", "orientation": "angle", "joint": "angle", "backlash": "angle", "pixel": "pixel"}
PIXEL = {"px": 1.0}


def noise_from_file(data, where: str):
    """A ``kincal.noise.Noise`` from a file's ``noise`` mapping (``position_mm: 0.02``, ``joint_deg: 0.001``, ...);
    ``where`` names file and field."""
    from_keys = {}
    if not isinstance(data, dict):
        raise DataFormatError(f"{where}: expected a mapping of <quantity>_<unit>: sigma, found {type(data).__name__}")
    for key, value in data.items():
        quantity, _, unit = str(key).rpartition("_")
        if quantity not in NOISE_UNITS:
            keys = ", ".join(f"{q}_<unit>" for q in NOISE_UNITS)
            raise DataFormatError(f"{where}.{key}: unknown key; expected one of {keys}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
            raise DataFormatError(f"{where}.{key}: expected a finite number >= 0, found {quote(value)}")
        from_keys[quantity] = float(value) * _noise_factor(quantity, unit, f"{where}.{key}")
    named = {k: from_keys.pop(k) for k in ("position", "orientation", "joint", "backlash") if k in from_keys}
    return Noise(**named, other=from_keys)


def noise_keys() -> set[str]:
    """Every accepted noise key (for schema checks)."""
    tables = {"length": LENGTH, "angle": ANGLE, "pixel": PIXEL}
    return {f"{q}_{u}" for q, kind in NOISE_UNITS.items() for u in tables[kind]}


def _noise_factor(quantity: str, unit: str, where: str) -> float:
    kind = NOISE_UNITS[quantity]
    if kind == "pixel":
        if unit not in PIXEL:
            raise DataFormatError(f"{where}: unknown pixel unit {quote(unit)}; expected 'px'")
        return 1.0
    return factor(kind, unit, where)


# Plain decimal or scientific notation, ASCII digits only: Python's float() also takes "3_0_4", "٣" and "nan".
_DECIMAL = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)
_INTEGER = re.compile(r"[+-]?[0-9]+", re.ASCII)


def overflows(text: str) -> bool:
    """Whether ``text`` reads as a number that is not finite (nan, inf, 1e999)."""
    try:
        return not math.isfinite(float(text))
    except ValueError:
        return False


def plain_number(text: str, integer: bool = False) -> float | int | None:
    """The number written in ``text`` (plain decimal or scientific notation; an integer if asked), or None."""
    text = text.strip()
    if not (_INTEGER if integer else _DECIMAL).fullmatch(text):
        return None
    x = int(text) if integer else float(text)
    return x if math.isfinite(x) else None
