"""Running things that files describe: a calibration job with kincal's solver or the thesis baseline.

Above ``kincal.io`` (which only reads and writes) and below ``kincal.cli``.
"""

from kincal.workflow.jobs import run_job

__all__ = ["run_job"]
