"""The outcome of a calibration: estimates with uncertainty, identifiability in words, statistics, model."""

from __future__ import annotations

from dataclasses import MISSING, dataclass, field, fields, replace
from functools import cached_property, partial
from typing import Mapping

import numpy as np

from kincal.analysis import Identifiability, Linearization, covariance, identify
from kincal.analysis.carried import CarriedAnalysis
from kincal.analysis.derived import Derived, derived
from kincal.analysis.gauge import GaugeView, min_change, representative, weights
from kincal.analysis.identifiability import DeferredReport, named
from kincal.analysis.prediction import Prediction, predicted_accuracy
from kincal.estimation.crossval import CrossValidation
from kincal.estimation import steps
from kincal.estimation.iterate import scale_test_needed
from kincal.estimation.outliers import Outlier
from kincal.estimation.plausibility import NegativeCompliance
from kincal.estimation.problem import Problem
from kincal.estimation.sandwich import Sandwich
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


def estimates_of(names, units, idx, values, nominals, stds, identifiable) -> list[Estimate]:
    """``Estimate(names[i], value, nominal, std, units[i], ok)`` per layout index ``i`` of ``idx`` with the matching
    items of the other lists: the instances' fields set at once (a frozen dataclass' ``__init__`` sets them one
    ``object.__setattr__`` call each; equal instances)."""
    new, out = object.__new__, []
    for i, v, n, s, o in zip(idx, values, nominals, stds, identifiable):
        e = new(Estimate)
        d = e.__dict__  # one item at a time: no keyword dict built per instance
        d["name"] = names[i]
        d["value"] = v
        d["nominal"] = n
        d["std"] = s
        d["unit"] = units[i]
        d["identifiable"] = o
        out.append(e)
    return out


@dataclass(frozen=True)
class TwistEstimate:
    """One derived coordinate of a joint twist (``arm.joint.xi.v_x`` .. ``w_z``): value and standard deviation,
    propagated from the estimated tangent coordinates (nan where they are not determined)."""

    name: str
    value: float
    std: float


def low_redundancy(dof: int, rank: int) -> bool:
    """Fewer redundant equations than identifiable parameters (but some): the residual variance rests on few
    degrees of freedom and the fit barely checks the model."""
    return 0 < dof < rank


@dataclass(frozen=True)
class StageRecord:
    """One stage of a staged solve (``kincal.estimation.stages``): its free set as given, its free coordinates
    and their rank, whitened chi^2 (``cost``), residual variance factor, status, outer iterations and residual
    statistics per data set at its end."""

    name: str
    free: str | tuple[str, ...]
    fixed: tuple[str, ...]
    parameters: int
    rank: int
    cost: float
    sigma2: float
    status: str
    iterations: int
    after: tuple[ResidualStats, ...]

    def rms(self, part: str) -> float | None:
        """``position`` or ``orientation`` RMS over the samples of every data set that has it (m, rad)."""
        rows = [(s.samples, getattr(s, f"{part}_rms")) for s in self.after if getattr(s, f"{part}_rms") is not None]
        return float(np.sqrt(sum(n * v**2 for n, v in rows) / sum(n for n, _ in rows))) if rows else None


@dataclass(frozen=True, eq=False)
class FinalReport:
    """The final identifiability report and the messages that carry its words, named when first read: a solve's
    steps and estimates need only the analysis (``analysis``: ``identify(report=False)`` of ``lin``); the words
    (row reduction, forward kinematics for the joint axes, each direction described) are for reports. ``head``
    and ``tail``: the solve's messages before and after the report's own. A carried analysis
    (``analysis.carried``: no spectrum, no words) is made afresh for the report, with the same rank."""

    analysis: Identifiability | CarriedAnalysis
    lin: Linearization
    layout: Layout
    experiments: tuple
    order: tuple[int, ...]
    structural: np.ndarray | None
    head: tuple[str, ...]
    tail: tuple[str, ...]

    @cached_property
    def report(self) -> Identifiability:
        """``named``'s report of ``analysis``, computed once."""
        ana = self.analysis
        if isinstance(ana, CarriedAnalysis):  # the loop's own call (a carried analysis held nothing)
            ana = identify(self.lin, self.layout, self.experiments, rtol=ana.rtol, priority=list(self.order),
                           report=False)
        return named(ana, self.lin, self.layout, self.experiments, list(self.order), self.structural)

    @property
    def messages(self) -> tuple[str, ...]:
        return self.head + tuple(self.report.messages) + self.tail


class _Named:
    """A ``Result`` field that may hold a ``FinalReport``: resolved (``report`` or ``messages``) on first read and
    kept. Stored in the instance's ``__dict__`` under the field's name (a data descriptor wins over it), so a
    Result pickles and copies with the report still unnamed."""

    def __init__(self, part: str):
        self.part = part

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:  # no class-level default: the dataclass field stays required
            raise AttributeError(self.name)
        value = obj.__dict__[self.name]
        if isinstance(value, FinalReport):
            value = obj.__dict__[self.name] = getattr(value, self.part)
        return value

    def __set__(self, obj, value) -> None:
        obj.__dict__[self.name] = value


class Deferred(partial):
    """A ``Result`` field's value computed when first read (``_Lazy``): a call of a module-level function on
    values the result holds anyway (it pickles as such)."""


_REQUIRED = object()


class _Lazy:
    """A ``Result`` field that may hold a ``Deferred``: computed on first read and kept, as ``_Named`` (stored in
    the instance's ``__dict__``; ``dataclasses.replace``, pickling and copying see the same value)."""

    def __init__(self, default=_REQUIRED):
        self.default = default

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:  # the dataclass field's default (none: required)
            if self.default is _REQUIRED:
                raise AttributeError(self.name)
            return self.default
        value = obj.__dict__[self.name]
        if isinstance(value, Deferred):
            value = obj.__dict__[self.name] = value()
        return value

    def __set__(self, obj, value) -> None:
        obj.__dict__[self.name] = value


# The fields ``finalize`` may leave ``Deferred``: computed for a pickle or a copy.
_DEFERRED = ("before", "after", "correlated", "twists")


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
    correlated: tuple[tuple[str, str, float], ...] = _Lazy()  # computed on first read (``Deferred``)
    identifiability: Identifiability = _Named("report")  # after solving (named on first read: ``FinalReport``)
    start_identifiability: DeferredReport | None  # at the start; read as ``identifiability_before``
    before: tuple[ResidualStats, ...] = _Lazy()  # per experiment at the start (computed on first read: ``Deferred``)
    after: tuple[ResidualStats, ...] = _Lazy()  # at ``state`` (computed on first read: ``Deferred``)
    sigma2: float  # residual variance factor (chi^2 / (m - rank)) that scales the covariance
    status: str  # converged | misfit | not converged | degenerate (docs/calibration.md "Statuses and exit codes")
    iterations: int  # outer iterations: linearizations, the one that confirmed convergence included
    evaluations: int  # residual evaluations spent on steps (Gauss-Newton trials, least_squares)
    messages: tuple[str, ...] = _Named("messages")  # with the final report's words (``FinalReport``)
    extras: Mapping[str, object] = field(default_factory=dict)  # final experiment frames
    problem: Problem | None = None
    linearization: Linearization | None = None  # at ``state``
    twists: tuple[TwistEstimate, ...] = _Lazy(())  # derived twist coordinates of every arm with free twists (lazy)
    validation: tuple[ValidationStats, ...] = ()
    predictions: tuple[tuple[str, Prediction], ...] = ()  # (validation set, prediction) per arm
    weights: np.ndarray | None = None  # robust loss: per whitened residual row, the weight the loss gave it
    outliers: tuple[Outlier, ...] = ()  # configurations left out of the solve (``calibrate(outliers=...)``)
    cross_validation: CrossValidation | None = None  # ``calibrate(..., cv=K)``: held-out errors per fold
    validation_outliers: tuple[Outlier, ...] = ()  # validation rows beyond the outlier rule (not in ``validation``)
    validation_all: tuple[ValidationStats, ...] = ()  # validation sets with such rows: their errors with every row
    covariance_scale: float | None = None  # what scaled ``covariance`` (None: ``sigma2``; ``finalize.covariance_scale``)
    stages: tuple[StageRecord, ...] = ()  # a staged solve's stages, the last one's being this result
    negative_compliances: tuple[NegativeCompliance, ...] = ()  # compliances estimated below 0 (``physical``)
    held: np.ndarray | None = None  # the rigid model's gauges the solve held (``estimation.gauge.rigid_gauges``)

    def __getstate__(self) -> dict:
        """Pickled and copied with the deferred fields computed: they compare parameter kinds by identity, which
        an unpickled problem's copies do not share."""
        state = dict(self.__dict__)
        for name in _DEFERRED:
            state[name] = getattr(self, name)
        return state

    @property
    def identifiability_before(self) -> Identifiability | None:
        """The identifiability report at the start (the nominal values), its null directions named on first
        access (``analysis.identifiability.DeferredReport``)."""
        return None if self.start_identifiability is None else self.start_identifiability.report

    @property
    def scale(self) -> float:
        """The factor that scaled ``covariance``: the residual variance factor, or 1 where low redundancy keeps a
        smaller one from shrinking the standard deviations (``low_redundancy``)."""
        return self.sigma2 if self.covariance_scale is None else self.covariance_scale

    @property
    def low_redundancy(self) -> bool:
        """Fewer redundant equations than identifiable parameters: the fit barely checks the model, so the
        result is trusted only where validation data confirm it."""
        lin, rank = self.linearization, self.identifiability.rank
        return lin is not None and low_redundancy(len(lin.r) - rank, rank)

    @property
    def trusted(self) -> bool:
        """Converged, ``physical``, and every validation prediction trusted (``Prediction.trusted``): nothing the
        data cannot determine moves the tool where the model was validated; with ``low_redundancy``, validated at
        all."""
        validated = bool(self.predictions) or not self.low_redundancy
        return (self.status == "converged" and self.physical and validated
                and all(p.trusted for _, p in self.predictions))

    @property
    def physical(self) -> bool:
        """No estimate a real robot cannot have: no compliance below 0 by more than
        ``plausibility.NEGATIVE_SIGMAS`` standard deviations (those within are warnings in ``messages``)."""
        return not any(c.significant for c in self.negative_compliances)

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

    @property
    def gauge(self) -> GaugeView | None:
        """Every estimate's change from nominal split into what the data determine in the ``min-change`` gauge
        (with standard deviations for every coordinate) and a gauge move (``GaugeView.split(name)``); None for a
        degenerate solve. Computed on first use (the walk to the min-change point takes a few linearizations)."""
        return self._in_gauge[0]

    @property
    def derived(self) -> tuple[Derived, ...]:
        """Axis geometry and tool pose at the nominal zero with standard deviations in the gauge of ``gauge``
        (``kincal.analysis.derived``); computed on first use."""
        return self._in_gauge[1]

    @cached_property
    def _in_gauge(self) -> tuple[GaugeView | None, tuple[Derived, ...]]:
        return in_gauge(self)

    def predict(self, q, arm: str, *, register: bool = True, register_tool: bool = False,
                noise: Noise | None = None, wrench=None) -> Prediction:
        """Predicted accuracy of the calibrated tool pose of ``arm`` at joint readings q (N, n): standard
        deviations, dependence on what the data cannot determine, and the RMS error to expect
        (``position_rms_predicted``, ``orientation_rms_predicted``) with the model error the calibration could
        not explain and, given ``noise``, the stated noise of measurements there; ``wrench`` (N, 6): the loads
        there, deflecting compliant joints (``kincal.analysis.prediction``)."""
        return predicted_accuracy(self, q, arm, register=register, register_tool=register_tool, noise=noise,
                                  wrench=wrench)

    def summary(self) -> str:
        lines = [f"status: {self.status} after {self.iterations} outer iterations ({self.evaluations} evaluations)"]
        lines.append(f"rank {self.identifiability.rank} of {len(self.identifiability.names)} free parameters; "
                     f"residual variance factor {self.sigma2:.3g}")
        lines += self.messages
        return "\n".join(lines)


def new_result(**values) -> Result:
    """``Result(**values)`` without the frozen dataclass' ``__init__`` (an ``object.__setattr__`` per field, 30 of
    them): every field's default, then ``values``, set in the instance's dict in the fields' order, where the lazy
    fields' descriptors (``_Lazy``, ``_Named``) keep theirs too. A field missing or unknown: ``Result``'s error."""
    if not _PLAIN or not values.keys() <= _FIELDS.keys() or not _REQUIRED_FIELDS <= values.keys():
        return Result(**values)
    r = object.__new__(Result)
    d = r.__dict__
    d.update(_FIELDS)
    d.update({name: make() for name, make in _FACTORIES if name not in values})
    d.update(values)
    return r


# ``new_result``'s defaults: field name -> default (None in a required field's place, set by ``values``), in order
_FIELDS = {f.name: None if f.default is MISSING else f.default for f in fields(Result)}
_FACTORIES = tuple((f.name, f.default_factory) for f in fields(Result) if f.default_factory is not MISSING)
_REQUIRED_FIELDS = frozenset(f.name for f in fields(Result) if f.default is MISSING and f.default_factory is MISSING)
# constructing one runs no check of its own and sets every field from its argument
_PLAIN = not hasattr(Result, "__post_init__") and all(f.init for f in fields(Result))


def in_gauge(result: Result) -> tuple[GaugeView | None, tuple[Derived, ...]]:
    """``result``'s estimates split in the ``min-change`` gauge and the derived quantities (axis geometry, tool
    pose at the nominal zero) with standard deviations in that gauge, both at the ``min-change`` point of the
    estimate's orbit (``kincal.analysis.gauge.representative``; with a robust loss, or where walking there would
    worsen the fit, at the estimate to first order). ``(None, ())`` for a degenerate solve."""
    problem = result.problem
    if problem is None or result.status == "degenerate" or not len(problem.free_idx):
        return None, ()
    free, layout = problem.free_idx, result.layout
    w = weights(layout, free)
    state, null, cov = result.state, result.identifiability.null_space, result.covariance
    found = _representative(result, w) if null.shape[1] and result.weights is None else None
    if found is not None:
        state, lin, ana = found
        null = ana.null_space
        s2, sw = result.scale if np.isfinite(result.scale) else 1.0, Sandwich.of(problem, lin, np.ones(len(lin.r)))
        cov = covariance(lin.Rf, ana.range_space, s2) if sw is None else sw.covariance(ana.range_space, s2)
    disp, D = displacement(state, problem.nominal, layout)
    view = min_change(disp[free], D[np.ix_(free, free)], null, cov, w)
    change = displacement(result.state, problem.nominal, layout, jacobian=False)[0][free]
    view = replace(view, change=change, gauge_move=change - view.determined, state=None if found is None else state,
                   names=tuple(e.name for e in result.estimates))
    return view, derived(state, problem.nominal, layout, free, view.local_covariance, null)


# Whitened chi^2 the walk to the min-change point may add (relative): exact gauges leave it unchanged; those the
# residuals lift (held all the same, kincal.analysis.symmetries) change it by the noise's share.
REPRESENTATIVE_COST_RTOL = 0.05


def _representative(result: Result, w: np.ndarray):
    """``kincal.analysis.gauge.representative`` for ``result``'s problem, or None where it would worsen the fit."""
    problem, lin0 = result.problem, result.linearization
    W = None if problem.joint_noise else lin0.W
    every = scale_test_needed(problem)

    def relinearize(state):
        lin = steps.linearize(problem, state, W, every)
        return lin, identify(lin, problem.layout, problem.experiments, rtol=result.identifiability.rtol, report=False,
                             hold=result.held)

    found = representative(result.state, problem.nominal, problem.layout, problem.free_idx, w, relinearize)
    if found is None or found[2].rank != result.identifiability.rank:
        return None
    ok = found[1].cost2 <= (1 + REPRESENTATIVE_COST_RTOL) * lin0.cost2 + 1e-12
    return found if ok else None
