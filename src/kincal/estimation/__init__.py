"""One solver for any mix of experiments: assemble, whiten, gauge-fix, solve, report."""

from kincal.estimation.constraints import FrameDistance
from kincal.estimation.problem import Problem
from kincal.noise import Noise
from kincal.estimation.result import Estimate, Result
from kincal.estimation.solver import calibrate, evaluate

__all__ = ["Estimate", "FrameDistance", "Noise", "Problem", "Result", "calibrate", "evaluate"]
