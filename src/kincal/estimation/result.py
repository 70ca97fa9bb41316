"""The outcome of a calibration: estimates with uncertainty, identifiability in words, statistics, model."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from kincal.analysis import Identifiability, Linearization
from kincal.analysis.prediction import Prediction, predicted_accuracy
from kincal.estimation.crossval import CrossValidation
from kincal.estimation.outliers import Outlier
from kincal.estimation.problem import Problem
from kincal.estimation.stats import ResidualStats, ValidationStats
from kincal.kinematics import Robot
from kincal.noise import Noise
from kincal.params import Layout, State


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
    cross_validation: CrossValidation | None = None  # ``calibrate(..., cv=K)``: held-out errors per fold
    validation_outliers: tuple[Outlier, ...] = ()  # validation rows beyond the outlier rule (not in ``validation``)
    validation_all: tuple[ValidationStats, ...] = ()  # validation sets with such rows: their errors with every row

    @property
    def trusted(self) -> bool:
        """Converged, and every validation prediction trusted (``Prediction.trusted``): nothing the data cannot
        determine moves the tool where the model was validated."""
        return self.status == "converged" and all(p.trusted for _, p in self.predictions)

    @property
    def success(self) -> bool:
        """A model to use: converged and ``trusted`` (a model that cannot vouch for itself is no success)."""
        return self.trusted

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
