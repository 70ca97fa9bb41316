"""Running things that files describe: a calibration job with kincal's solver or the thesis baseline.

Above ``kincal.io`` (which only reads and writes) and below ``kincal.cli``. ``run_job`` is imported on first
use: a study's Dask workers import ``kincal.workflow.study`` without the job runner (the thesis baseline with
SciPy's optimizers, a few tenths of a second of imports).
"""

__all__ = ["run_job"]


def __getattr__(name: str):
    if name == "run_job":
        from kincal.workflow.jobs import run_job  # lazy: see the module docstring

        return run_job
    raise AttributeError(f"module 'kincal.workflow' has no attribute {name!r}")
