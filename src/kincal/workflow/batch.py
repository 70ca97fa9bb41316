"""Many calibration jobs at once (``kincal batch``, a fleet of robots): each job on the Dask back end
(``kincal.workflow.parallel``), its outputs in its own folder written as ``kincal calibrate`` writes them
(all or nothing, ``kincal.io.atomic``), and one summary table. A job that fails is a row of the table."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Sequence

from kincal.errors import KincalError
from kincal.io.atomic import output_file
from kincal.io.jobs import load_job
from kincal.io.studies import write_csv
from kincal.workflow.jobs import run_job
from kincal.workflow.outputs import write_calibration
from kincal.workflow.parallel import run_tasks
from kincal.workflow.provenance import provenance

FAILED = "failed"
SUMMARY = "summary.csv"


def folders(jobs: Sequence[Path]) -> list[str]:
    """One output folder name per job: the job file's stem, numbered where stems repeat."""
    out, seen = [], {}
    for j in jobs:
        stem = Path(j).stem
        seen[stem] = seen.get(stem, 0) + 1
        out.append(stem if seen[stem] == 1 else f"{stem}_{seen[stem]}")
    return out


def run_one(job: Path, out: Path, overwrite: bool) -> dict:
    """Calibrate one job into ``out``: its summary row; a failure (bad input, or any error) is the row's status."""
    t0 = time.perf_counter()
    row = {"job": str(job), "folder": str(out), "status": FAILED, "trusted": False, "position_rms_before_mm": "",
           "position_rms_after_mm": "", "validation_rms_mm": "", "seconds": 0.0, "message": ""}
    try:
        j = load_job(job)
        result = run_job(j)
        robot = result.calibrated(j.robot) if j.method == "thesis" else None
        write_calibration(result, out, robot=robot, provenance=provenance(j), overwrite=overwrite)
        row.update(_numbers(result))
    except KincalError as exc:
        row["message"] = str(exc)
    except Exception as exc:  # a batch reports a job's crash in its row and goes on with the others
        row["message"] = f"{type(exc).__name__}: {exc}"
    row["seconds"] = time.perf_counter() - t0
    return row


def _numbers(result) -> dict:
    def mm(stats):
        vals = [s.position_rms for s in stats if s.position_rms is not None]
        return max(vals) * 1e3 if vals else ""

    status = getattr(result, "status", None) or ("converged" if result.converged else "not converged")
    return {"status": status, "trusted": bool(getattr(result, "trusted", status == "converged")),
            "position_rms_before_mm": mm(getattr(result, "before", ())), "position_rms_after_mm": mm(
                getattr(result, "after", ())),
            "validation_rms_mm": mm([v.after for v in getattr(result, "validation", ())])}


def run_batch(jobs: Sequence[Path], output, *, workers: int | None = None, scheduler: str | None = None,
              overwrite: bool = False, progress: Callable[[int, int], None] | None = None) -> list[dict]:
    """Calibrate every job (its folder in ``output``: see ``folders``) and write ``output/summary.csv``;
    returns the summary rows in the order of ``jobs``."""
    output = Path(output)
    if output.exists() and not output.is_dir():
        raise KincalError(f"{output}: exists and is not a directory; expected an output directory")
    if (output / SUMMARY).exists() and not overwrite:  # said before any job runs
        raise KincalError(f"{output / SUMMARY}: exists; refusing to overwrite it (pass --overwrite)")
    output.mkdir(parents=True, exist_ok=True)  # before the workers make their folders inside it
    tasks = [(Path(j).resolve(), output / name, overwrite) for j, name in zip(jobs, folders(jobs))]
    done = [0]

    def tick(i):
        done[0] += 1
        if progress:
            progress(done[0], len(tasks))

    rows = run_tasks(run_one, tasks, workers=workers, scheduler=scheduler, progress=tick)
    with output_file(output / SUMMARY, overwrite=overwrite) as path:
        write_csv(path, rows)
    return rows
