"""Run a calibration job read by ``kincal.io.jobs.load_job`` (docs/job-format.md)."""

from __future__ import annotations

from kincal.baselines import thesis
from kincal.errors import DataFormatError
from kincal.estimation import calibrate
from kincal.io.jobs import Job


def run_job(job: Job, progress=None):
    """Run the job's solver: kincal's (a ``Result``) or the thesis baseline (a ``BaselineResult``). Refuses a
    job whose data are a plan (``kincal.io.planjobs``): the nominal robot's readings, not measurements."""
    _require_measured(job)
    if job.method == "thesis":
        return _thesis(job)
    free, fixed = (None, ()) if job.stages else (job.free, job.fixed)
    return calibrate(job.robot, job.datasets, free, fixed=fixed, priors=job.priors, noise=job.noise,
                     gauge=job.gauge, validation=job.validation, constraints=job.constraints, progress=progress,
                     outliers=job.outliers, stages=job.stages, **job.options)


def _require_measured(job: Job) -> None:
    for ds in job.datasets + job.validation:
        if "planned" in ds.meta:
            raise DataFormatError(
                f"{job.path}: data set '{ds.name}' is a plan ({ds.meta['planned']}), not measured data: it holds the "
                "nominal model's own readings, which any calibration fits exactly; plans are for `kincal analyze` "
                "and `kincal design`. Calibrate measured data, or `kincal simulate` the scenario and calibrate its "
                "job to try the calibration")


def _thesis(job: Job):
    """The thesis method that fits the job's one data set (clamp, plate or dual) and free level."""
    if len(job.datasets) != 1:
        raise DataFormatError(f"{job.path}: solver.method 'thesis' takes exactly one data set, found {len(job.datasets)}")
    ds = job.datasets[0]
    level = job.free if isinstance(job.free, str) else None
    method = {"clamp": "single_offsets", "plate": "several_points"}.get(ds.kind)
    if ds.kind == "dual":
        method = "dual_kinematic" if level == "kinematic" else "dual_offsets"
    if method is None:
        raise DataFormatError(f"{job.path}: the thesis has no method for '{ds.kind}' data sets "
                              "(clamp, plate and dual only)")
    return thesis.run(method, ds, job.robot)
