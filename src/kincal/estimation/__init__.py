"""One solver for any mix of experiments: ``Problem.build`` -> ``solve(problem, SolverOptions(...))`` -> ``Result``
(``calibrate`` does all three); ``validate`` and ``evaluate`` for held-out data."""

from kincal.estimation.constraints import FrameDistance
from kincal.estimation.finalize import finalize
from kincal.estimation.iterate import Iteration, iterate
from kincal.estimation.options import SolverOptions
from kincal.estimation.outliers import Outlier
from kincal.estimation.problem import Problem
from kincal.estimation.result import Estimate, Result, StageRecord, TwistEstimate
from kincal.estimation.stages import Stage
from kincal.estimation.solver import calibrate, evaluate, solve, validate, validation_stats
from kincal.estimation.stats import ResidualStats, ValidationStats
from kincal.noise import Noise

__all__ = ["Estimate", "FrameDistance", "Iteration", "Noise", "Outlier", "Problem", "ResidualStats", "Result",
           "SolverOptions", "Stage", "StageRecord", "TwistEstimate", "ValidationStats", "calibrate", "evaluate",
           "finalize", "iterate", "solve", "validate", "validation_stats"]
