"""File references inside files (a job's manifests and model, a manifest's CSV and model, a scenario's model).

A reference is taken relative to the folder of the file that holds it (an absolute path stays as it is), never
relative to the working directory. With a ``root`` (a job read with ``confine``), every reference must lie in
that folder once symbolic links and ``..`` are resolved. What is read must be a regular file
(``yamlfile.read_text``); a built-in robot name is not a file and needs no confining.
"""

from __future__ import annotations

import os
from pathlib import Path

from kincal.errors import DataFormatError
from kincal.io.models import builtin_names
from kincal.io.yamlfile import quote

MODEL_SUFFIXES = (".yaml", ".yml")


def resolve(holder: Path, ref: str, where: str, root: Path | None = None) -> Path:
    """The file ``ref`` names, written in the file ``holder``; ``where`` names file and field for the error."""
    path = Path(ref)
    path = path if path.is_absolute() else Path(holder).parent / path
    if root is not None:
        real = Path(os.path.realpath(path))
        if not real.is_relative_to(root):
            raise DataFormatError(f"{where}: {quote(ref)} resolves to {real}, outside the job's folder {root} "
                                  "(references are confined to it)")
    return path


def model_reference(holder: Path, ref: str, where: str, root: Path | None = None) -> str:
    """A model reference: a built-in robot name as it is (unless a file of that name lies beside ``holder``),
    else the model file's path, resolved as ``resolve`` does."""
    looks_like_path = Path(ref).suffix in MODEL_SUFFIXES or "/" in ref or os.sep in ref
    if not looks_like_path and ref in builtin_names() and not (Path(holder).parent / ref).is_file():
        return ref
    return str(resolve(holder, ref, where, root))


def same_model(a: str, b: str) -> bool:
    """Whether two resolved model references name the same model: one built-in name, or one file."""
    if a in builtin_names() or b in builtin_names():
        return a == b
    return os.path.realpath(a) == os.path.realpath(b)
