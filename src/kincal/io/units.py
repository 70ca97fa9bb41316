"""Unit names accepted in files and on the command line, and their factors to SI."""

from __future__ import annotations

from kincal.errors import DataFormatError

LENGTH = {"m": 1.0, "mm": 1e-3}
ANGLE = {"rad": 1.0, "deg": 0.017453292519943295}  # pi / 180


def factor(kind: str, name: str, where: str) -> float:
    """SI factor of unit ``name`` ('length' or 'angle'); ``where`` names file and field for the error."""
    table = {"length": LENGTH, "angle": ANGLE}[kind]
    try:
        return table[name]
    except (KeyError, TypeError):
        raise DataFormatError(
            f"{where}: unknown {kind} unit {name!r}; expected one of {', '.join(repr(k) for k in table)}"
        ) from None
