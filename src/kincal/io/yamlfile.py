"""Reading YAML files safely, with errors that name the file, line and column."""

from __future__ import annotations

from pathlib import Path

import yaml

from kincal.errors import DataFormatError


def parse_yaml(text: str, file: str):
    """``yaml.safe_load`` of ``text``; a syntax error becomes a DataFormatError naming file, line, column."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise DataFormatError(f"{file}: not valid YAML{where}: {problem}") from None


def read_text(path, what: str) -> str:
    """The text of ``path``; ``what`` says which kind of file it should be (for the error)."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None


def read_yaml(path, what: str):
    """Read and safely parse a YAML file."""
    return parse_yaml(read_text(path, what), str(path))
