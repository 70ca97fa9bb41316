"""A calibration result again, from its output folder: result.yaml records the job and every input with its
SHA-256 (``kincal.workflow.provenance``); the job is run again (the solve is deterministic) after checking that
no input changed, and the recomputed status and estimates must match what was written. For ``kincal report``
and ``kincal plot`` on an existing result."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kincal.errors import DataFormatError
from kincal.io.jobs import load_job
from kincal.io.yamlfile import read_yaml
from kincal.workflow.jobs import run_job
from kincal.workflow.provenance import check_unchanged

# Estimates recomputed from the same inputs agree to round-off; this much is a different result.
AGREE = 1e-8


def recompute(result_dir) -> tuple[object, dict]:
    """(Result, provenance) of the calibration written to ``result_dir``."""
    d = Path(result_dir)
    path = d / "result.yaml"
    if not path.is_file():
        raise DataFormatError(f"{d}: no result.yaml (a kincal calibrate output folder is expected)")
    written = read_yaml(path, "result file")
    prov = written.get("provenance") if isinstance(written, dict) else None
    if not prov or "job" not in prov:
        raise DataFormatError(f"{path}: records no job (written by an older kincal): calibrate again to report it")
    check_unchanged(prov, str(path))
    job = load_job(prov["job"])
    if job.method == "thesis":
        raise DataFormatError(f"{path}: a thesis-baseline result has no report; use kincal's solver")
    result = run_job(job)
    _agree(result, written, path)
    return result, prov


def _agree(result, written: dict, path: Path) -> None:
    if result.status != written.get("status"):
        raise DataFormatError(f"{path}: recomputed status '{result.status}' differs from the recorded "
                              f"'{written.get('status')}'")
    recorded = {e["name"]: e.get("value") for e in written.get("estimates", []) if isinstance(e, dict)}
    for e in result.estimates:
        r = recorded.get(e.name)
        if r is None or not np.isfinite(r):
            continue
        if abs(e.value - r) > AGREE * max(1.0, abs(r)):
            raise DataFormatError(f"{path}: recomputed {e.name} = {e.value:.12g} differs from the recorded {r:.12g}")
