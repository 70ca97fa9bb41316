"""Reports of a calibration: plots (matplotlib, extra ``plot``). The only package that imports matplotlib."""

from kincal.report.plots import write_plots

__all__ = ["write_plots"]
