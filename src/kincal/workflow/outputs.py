"""A command's output folder, written all or nothing (``kincal.io.atomic``): a calibration's model, report and
plots; a simulation's data, truth and validation sets; the demo's simulation and job (docs/formats.md "Outputs").

Each function takes the final folder and returns the final paths; the writers write into a temporary folder
beside it that is moved into place only once everything is written.
"""

from __future__ import annotations

import importlib.util

from kincal.errors import KincalError
from kincal.io.atomic import Staging, output_directory
from kincal.io.datasets import write_simulation
from kincal.io.jobs import write_job
from kincal.io.results import write_results
from kincal.report import write_plots

CALIBRATION_ENTRIES = ("model.yaml", "result.yaml")
SIMULATION_ENTRIES = ("data.yaml", "data.csv", "truth", "validation")
DEMO_ENTRIES = SIMULATION_ENTRIES + ("job.yaml",)


def require_plots(what: str = "plots", hint: str = " (or leave out --plots)") -> None:
    """Refuse ``--plots`` (or a report) before any work when matplotlib is missing (nothing gets written, no
    solve is wasted)."""
    if importlib.util.find_spec("matplotlib") is None:
        raise KincalError(f'{what} need matplotlib: pip install "kincal[plot]"{hint}')


def write_calibration(result, out, *, robot=None, plots: bool = False, provenance: dict | None = None,
                      overwrite: bool = False) -> dict:
    """``model.yaml``, ``result.yaml`` and with ``plots`` the ``plots/`` folder, all or nothing; returns their
    final paths (``plots``: a list of files). ``result.yaml`` is moved in last: it marks a complete output."""
    names = CALIBRATION_ENTRIES + (("plots",) if plots else ())
    with output_directory(out, names=names, overwrite=overwrite, last="result.yaml") as stage:
        paths = write_results(result, stage.path, robot=robot, provenance=provenance)
        figures = write_plots(result, stage.path / "plots") if plots else []
    return {**{k: stage.final(p) for k, p in paths.items()}, "plots": [stage.final(f) for f in figures]}


def write_simulation_output(out, dataset, truth, validation, robot, *, overwrite: bool = False, **units) -> dict:
    """``kincal.io.datasets.write_simulation`` all or nothing; with ``overwrite`` the previous simulation's
    entries (``SIMULATION_ENTRIES``) are replaced as a whole at the end. ``data.yaml`` marks a complete output."""
    with output_directory(out, names=SIMULATION_ENTRIES, overwrite=overwrite, last="data.yaml",
                          inside_ok=False) as stage:
        paths = write_simulation(stage.path, dataset, truth, validation, robot, **units)
    return {k: stage.final(p) for k, p in paths.items()}


def write_demo_input(out, dataset, truth, validation, robot, *, model: str, job_name: str, free: str) -> Staging:
    """The demo's simulation and the job that calibrates it (``job.yaml``), all or nothing. Returns the
    ``Staging``, whose ``undo()`` removes them again if the calibration that follows fails or is interrupted."""
    stage = None
    try:
        with output_directory(out, names=DEMO_ENTRIES, last="job.yaml", inside_ok=False) as stage:
            write_simulation(stage.path, dataset, truth, validation, robot, model=model)
            write_job(stage.path / "job.yaml", name=job_name, model=model, data=["data.yaml"],
                      validation=[f"validation/{a}.yaml" for a in validation], free=free)
    except BaseException:  # an interrupt held back during the move arrives after it: take the move back
        if stage is not None:
            stage.undo()
        raise
    return stage
