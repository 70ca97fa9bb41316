"""Where a calibration came from: the job file, every input file with its SHA-256, the kincal version and the
date (result.yaml ``provenance:`` and the HTML report); paths are absolute, so a result can be reported from
anywhere on the machine that computed it. ``kincal report`` and ``kincal plot`` recompute a result
from its recorded job and refuse when an input has changed since."""

from __future__ import annotations

import hashlib
import sys
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import scipy

from kincal import __version__
from kincal.errors import DataFormatError
from kincal.io.jobs import Job


def sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def input_files(job: Job) -> list[Path]:
    """The job file, its model file (when not a built-in) and every data set's manifest and CSV, in order."""
    files = [Path(job.path)]
    if job.model and Path(job.model).is_file():  # a model file, not a built-in name
        files.append(Path(job.model))
    for ds in tuple(job.datasets) + tuple(job.validation):
        files += [Path(ds.meta[k]) for k in ("manifest", "file") if ds.meta.get(k)]
    return list(dict.fromkeys(files))


def provenance(job: Job) -> dict:
    """The ``provenance`` block of result.yaml for ``job``."""
    return {"job": str(Path(job.path).resolve()), "kincal": __version__,
            "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "python": sys.version.split()[0], "numpy": np.__version__, "scipy": scipy.__version__,
            "inputs": [{"file": str(f.resolve()), "sha256": sha256(f)} for f in input_files(job) if f.is_file()]}


def check_unchanged(recorded: dict, where: str) -> None:
    """Refuse when a recorded input file is gone or differs from what the result was computed from."""
    for entry in recorded.get("inputs", []):
        f = Path(entry["file"])
        if not f.is_file():
            raise DataFormatError(f"{where}: input {f} of this result is gone; the result cannot be recomputed")
        if sha256(f) != entry["sha256"]:
            raise DataFormatError(f"{where}: input {f} changed since this result was computed (SHA-256 differs); "
                                  "calibrate again")
