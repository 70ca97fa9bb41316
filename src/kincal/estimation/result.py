"""The outcome of a calibration: estimates with uncertainty, identifiability in words, statistics, model."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np

from kincal.analysis import Identifiability, Linearization
from kincal.analysis.derived import Derived, derived
from kincal.analysis.gauge import GaugeView, min_change, weights
from kincal.analysis.prediction import Prediction, predicted_accuracy
from kincal.estimation.outliers import Outlier
from kincal.estimation.problem import Problem
from kincal.estimation.stats import ResidualStats, ValidationStats
from kincal.kinematics import Robot
from kincal.noise import Noise
from kincal.params import Layout, State, displacement


@dataclass(frozen=True)
class Estimate:
    """One free coordinate's estimate: value and nominal in SI units (``unit``), standard deviation scaled by the
    residual variance (nan when ``identifiable`` is false)."""

    name: str
    value: float  # displacement from nominal in local coordinates for twists/poses; absolute for offsets/points
    nominal: float
    std: float  # nan when unidentifiable
    unit: str
    identifiable: bool
    # the change from nominal split in the result's gauge (``Result.gauge``, kincal.analysis.gauge): the part the
    # data determine, its standard deviation (finite for every coordinate), and a move along unidentifiable
    # directions (changes no residual); nan where there is no gauge view (a degenerate solve)
    determined: float = float("nan")
    std_determined: float = float("nan")
    gauge_move: float = float("nan")


@dataclass(frozen=True)
class TwistEstimate:
    """One derived coordinate of a joint twist (``arm.joint.xi.v_x`` .. ``w_z``): value and standard deviation,
    propagated from the estimated tangent coordinates (nan where they are not determined)."""

    name: str
    value: float
    std: float


@dataclass(frozen=True, eq=False)
class Result:
    """What ``solve`` returns. Reports, never raises, on non-convergence or rank deficiency (see ``status`` and
    ``messages``). ``problem`` and ``linearization`` (at the final state) are what it was computed from:
    reports and plots read residuals and Jacobians there."""

    robot: Robot  # calibrated
    nominal_robot: Robot
    state: State
    layout: Layout
    estimates: tuple[Estimate, ...]
    covariance: np.ndarray  # (p_free, p_free) in local coordinates, gauge-fixed
    correlated: tuple[tuple[str, str, float], ...]
    identifiability: Identifiability  # after solving
    identifiability_before: Identifiability
    before: tuple[ResidualStats, ...]  # per experiment at the start (the nominal values)
    after: tuple[ResidualStats, ...]
    sigma2: float  # residual variance factor (chi^2 / (m - rank)) that scales the covariance
    status: str  # converged | misfit | not converged | degenerate (docs/calibration.md "Statuses and exit codes")
    iterations: int  # outer iterations: linearizations, the one that confirmed convergence included
    evaluations: int  # residual evaluations spent on steps (Gauss-Newton trials, least_squares)
    messages: tuple[str, ...]
    extras: Mapping[str, object] = field(default_factory=dict)  # final experiment frames
    problem: Problem | None = None
    linearization: Linearization | None = None  # at ``state``
    twists: tuple[TwistEstimate, ...] = ()  # derived twist coordinates of every arm with free twists
    validation: tuple[ValidationStats, ...] = ()
    predictions: tuple[tuple[str, Prediction], ...] = ()  # (validation set, prediction) per arm
    weights: np.ndarray | None = None  # robust loss: per whitened residual row, the weight the loss gave it
    outliers: tuple[Outlier, ...] = ()  # configurations left out of the solve (``calibrate(outliers=...)``)
    gauge: GaugeView | None = None  # the gauge of ``Estimate.determined`` and of ``derived``'s standard deviations
    derived: tuple[Derived, ...] = ()  # axis geometry and tool pose at the nominal zero (kincal.analysis.derived)

    @property
    def success(self) -> bool:
        return self.status == "converged"

    def estimate(self, name: str) -> Estimate:
        for e in self.estimates:
            if e.name == name:
                return e
        raise KeyError(name)

    def values(self) -> dict[str, float]:
        return {e.name: e.value for e in self.estimates}

    def predict(self, q, arm: str, *, register: bool = True, register_tool: bool = False,
                noise: Noise | None = None) -> Prediction:
        """Predicted accuracy of the calibrated tool pose of ``arm`` at joint readings q (N, n): standard
        deviations, dependence on what the data cannot determine, and the RMS error to expect
        (``position_rms_predicted``, ``orientation_rms_predicted``) with the model error the calibration could
        not explain and, given ``noise``, the stated noise of measurements there (``kincal.analysis.prediction``)."""
        return predicted_accuracy(self, q, arm, register=register, register_tool=register_tool, noise=noise)

    def summary(self) -> str:
        lines = [f"status: {self.status} after {self.iterations} outer iterations ({self.evaluations} evaluations)"]
        lines.append(f"rank {self.identifiability.rank} of {len(self.identifiability.names)} free parameters; "
                     f"residual variance factor {self.sigma2:.3g}")
        lines += self.messages
        return "\n".join(lines)


def in_gauge(result: Result) -> Result:
    """``result`` with its estimates split in the ``min-change`` gauge and the derived quantities (axis geometry,
    tool pose at the nominal zero) with standard deviations in that gauge. A degenerate solve is returned as is."""
    problem = result.problem
    if problem is None or result.status == "degenerate" or not len(problem.free_idx):
        return result
    free = problem.free_idx
    disp, D = displacement(result.state, problem.nominal, result.layout)
    view = min_change(disp[free], D[np.ix_(free, free)], result.identifiability.null_space, result.covariance,
                      weights(result.layout, free))
    estimates = tuple(replace(e, determined=float(d), std_determined=float(s), gauge_move=float(g))
                      for e, d, s, g in zip(result.estimates, view.determined, view.std, view.gauge_move))
    quantities = derived(result.state, problem.nominal, result.layout, free, view.local_covariance,
                         result.identifiability.null_space)
    return replace(result, estimates=estimates, gauge=view, derived=quantities)
