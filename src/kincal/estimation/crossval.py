"""K-fold cross-validation of a calibration: folds by configuration, nothing refitted on the held-out fold.

Every data set's configurations are split into ``k`` folds (one random permutation per set, ``seed``); fold
``i`` holds out the ``i``-th part of every set. The calibration is run on the other folds; the held-out
residuals are evaluated at the training solution, with the frames (tracker, markers, fixture, ...) the
training folds estimated: what a user of the calibrated model would see on new configurations.

Next to each fold's actual held-out error stands its prediction from the training fit alone
(``held_out_prediction``): per residual component, the parameter uncertainty ``diag(J C J^T)`` (frames
included, so the unrefitted frames' uncertainty counts), the stated noise (encoders and backlash through the
joint Jacobian) and the model error the training fit's variance factor shows (``unexplained_error``).
The *cross-validated model error* is what the held-out mean square has beyond the predicted parameter
uncertainty and noise; ``calibrate(..., cv=K)`` uses it for the predictions instead of the variance factor's.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Callable, Sequence

import numpy as np

from kincal.analysis.columns import scatter_columns
from kincal.analysis.error_budget import component_noise, unexplained_error
from kincal.data import Dataset
from kincal.errors import ModelError
from kincal.estimation.outliers import DEFAULT_THRESHOLD, beyond, scaled_chi2, states_noise
from kincal.estimation.memory import chunk_rows
from kincal.estimation.problem import VARIANCE_FLOOR
from kincal.noise import ORIENTATION, POSITION


@dataclass(frozen=True)
class HeldOut:
    """Sums over held-out residuals of one quantity (position or orientation), outlying rows left out:
    ``squares`` the actual squared components, ``predicted`` the predicted variances (parameters + noise +
    model error), ``parameters`` and ``noise`` those parts, ``components`` how many, ``groups`` how many error
    vectors (3-vectors for points, scalars for distances, one per configuration for orientation: what an RMS
    is taken over); ``squares_all`` and ``groups_all`` the same with the outlying rows, ``flagged`` how many
    rows the outlier rule flagged (``estimation.outliers``)."""

    squares: float = 0.0
    predicted: float = 0.0
    parameters: float = 0.0
    noise: float = 0.0
    components: int = 0
    groups: int = 0
    squares_all: float = 0.0
    groups_all: int = 0
    flagged: int = 0

    def __add__(self, other: "HeldOut") -> "HeldOut":
        return HeldOut(*(a + b for a, b in zip(self.astuple(), other.astuple())))

    def astuple(self) -> tuple:
        return tuple(getattr(self, f.name) for f in fields(self))

    @property
    def rms(self) -> float:
        """Actual RMS length of the held-out error vectors (m or rad); nan without any."""
        return float(np.sqrt(self.squares / self.groups)) if self.groups else float("nan")

    @property
    def rms_all(self) -> float:
        """The actual RMS with the outlying rows."""
        return float(np.sqrt(self.squares_all / self.groups_all)) if self.groups_all else float("nan")

    @property
    def rms_predicted(self) -> float:
        return float(np.sqrt(self.predicted / self.groups)) if self.groups else float("nan")

    @property
    def model_error(self) -> float:
        """Cross-validated model error, RMS length of a 3-vector (m or rad, as ``Prediction.position_model``):
        the held-out mean square per component beyond the parameter uncertainty and the noise, times 3."""
        if not self.components:
            return float("nan")
        return float(np.sqrt(3 * max(self.squares - self.parameters - self.noise, 0.0) / self.components))


@dataclass(frozen=True)
class Fold:
    """One fold: held-out configurations per data set, the training solve's status and variance factor, and
    the held-out position and orientation sums (``HeldOut``)."""

    index: int
    held_out: dict
    status: str
    sigma2: float
    position: HeldOut
    orientation: HeldOut


@dataclass(frozen=True, eq=False)
class CrossValidation:
    """``k`` folds (``Fold``) and their results; overall figures pool every fold's held-out residuals."""

    k: int
    seed: int
    folds: tuple[Fold, ...]
    results: tuple = ()  # the training Result of each fold

    def pooled(self, quantity: str) -> HeldOut:
        return sum((getattr(f, quantity) for f in self.folds), HeldOut())

    @property
    def position_model(self) -> float:
        """Cross-validated position model error (m, 3-vector RMS); 0 when nothing is beyond the prediction."""
        return _finite(self.pooled("position").model_error)

    @property
    def orientation_model(self) -> float:
        return _finite(self.pooled("orientation").model_error)


def folds(datasets: Sequence[Dataset], k: int, seed: int = 0) -> list[list[np.ndarray]]:
    """Per data set, ``k`` disjoint held-out index sets covering its configurations (one permutation each)."""
    if not isinstance(k, int) or isinstance(k, bool) or k < 2:
        raise ModelError(f"cv: expected a number of folds >= 2, found {k!r}")
    small = [f"'{d.name}' ({d.size})" for d in datasets if d.size < k]
    if small:
        raise ModelError(f"cv: {k} folds need at least {k} configurations per data set; {', '.join(small)} "
                         "have fewer")
    rng = np.random.default_rng(seed)
    return [permuted_folds(d.size, k, rng) for d in datasets]


def permuted_folds(n: int, k: int, rng: np.random.Generator) -> list[np.ndarray]:
    """``k`` disjoint index sets covering ``range(n)``, from one random permutation."""
    return np.array_split(rng.permutation(n), k)


def cross_validate(datasets: Sequence[Dataset], k: int, fit: Callable, seed: int = 0,
                   threshold: float | None = DEFAULT_THRESHOLD) -> CrossValidation:
    """Calibrate with ``fit(training data sets) -> Result`` on ``k - 1`` folds and evaluate the held-out fold at
    the training solution, for each of ``k`` folds (module docstring); ``threshold``: the outlier rule's for
    held-out rows (None: keep all)."""
    parts = folds(datasets, k, seed)
    out, results = [], []
    for i in range(k):
        train = [d.subset(np.setdiff1d(np.arange(d.size), p[i])) for d, p in zip(datasets, parts)]
        test = [d.subset(np.sort(p[i])) for d, p in zip(datasets, parts)]
        res = fit(train)
        pos, rot = held_out_prediction(res, test, threshold)
        out.append(Fold(i, {d.name: len(p[i]) for d, p in zip(datasets, parts)}, res.status, res.sigma2, pos, rot))
        results.append(res)
    return CrossValidation(k, seed, tuple(out), tuple(results))


def held_out_prediction(result, datasets: Sequence[Dataset],
                        threshold: float | None = DEFAULT_THRESHOLD) -> tuple[HeldOut, HeldOut]:
    """Actual and predicted held-out residuals of ``datasets`` at ``result``'s solution and frames (each set
    evaluated as the calibration's experiment of the same name), pooled per quantity: (position, orientation).
    Rows beyond the outlier rule's ``threshold`` (whitened by the stated noise; None, or no noise stated: keep
    all) are left out of the sums and counted (``HeldOut.flagged``), as calibration leaves them out of its fit."""
    problem = result.problem
    by_name = {e.name: (e, nz) for e, nz in zip(problem.experiments, problem.noise)}
    model = dict(zip((POSITION, ORIENTATION), unexplained_error(result)))
    sums = {POSITION: HeldOut(), ORIENTATION: HeldOut()}
    for ds in datasets:
        if ds.name not in by_name:
            raise ModelError(f"held-out data set '{ds.name}' was not calibrated from: no frames for it")
        exp, nz = by_name[ds.name]
        r, param, noise = _held_out_rows(result, type(exp)(ds, exp.frames), nz)
        N, c = r.shape
        keep = np.ones(N, bool)
        if threshold is not None and states_noise(ds, nz):
            keep[beyond(scaled_chi2(np.sum(r**2 / np.maximum(noise, VARIANCE_FLOOR), axis=1), c)[1],
                        threshold)] = False
        for q in sums:
            mask = np.array([x == q for x in exp.components()], bool)
            if mask.any():
                sums[q] = sums[q] + _sums(r[:, mask], param[:, mask], noise[:, mask], keep,
                                          _finite(model[q]) ** 2 / 3, _groups(q, int(mask.sum())))
    return sums[POSITION], sums[ORIENTATION]


def _sums(r, param, noise, keep, model2: float, groups: int) -> HeldOut:
    """``HeldOut`` of one quantity's components (N, c) of one data set; ``model2``: model error per component."""
    n = int(keep.sum())
    return HeldOut(float(np.sum(r[keep] ** 2)), float(np.sum(param[keep] + noise[keep]) + model2 * r[keep].size),
                   float(np.sum(param[keep])), float(np.sum(noise[keep])), int(r[keep].size), n * groups,
                   float(np.sum(r**2)), len(r) * groups, len(r) - n)


def _groups(q, count: int) -> int:
    """Error vectors per configuration in ``count`` components of ``q``, as ``estimation.stats.residual_norms``
    takes norms: 3-vectors of points, one orientation vector, else scalars."""
    if q == POSITION:
        return count // 3 if count % 3 == 0 and count > 1 else count
    return 1


def _held_out_rows(result, exp, nz) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per held-out row and component of ``exp`` at ``result``: residual, parameter variance ``diag(J C J^T)``
    and noise variance (N, c) each; evaluated in blocks of ``memory.chunk_rows`` rows, so the Jacobian of a
    large held-out set is never held whole."""
    problem = result.problem
    step = max(chunk_rows(len(problem.free_idx)) // len(exp.components()), 1)
    out = []
    for a in range(0, exp.size, step):
        part = exp if step >= exp.size else type(exp)(exp.dataset.subset(slice(a, a + step)), exp.frames)
        res = part.residual(result.state, want=problem.want, jq=True)
        J = scatter_columns(res.jac, problem.layout, problem.free_idx, res.r.shape)
        out.append((res.r, np.sum((J @ result.covariance) * J, axis=-1).clip(0), component_noise(part, nz, res.jq)))
    return tuple(np.concatenate(x) for x in zip(*out))


def _finite(x: float) -> float:
    return x if np.isfinite(x) else 0.0


def with_cross_validation(result, cv: CrossValidation):
    """``result`` with its cross-validation and a message saying what it found (the model error it carries
    into the predictions)."""
    parts = []
    for name, scale, unit in (("position", 1e3, "mm"), ("orientation", 180 / np.pi, "deg")):
        h = cv.pooled(name)
        if not h.groups_all:
            continue
        outl = f" ({h.rms_all * scale:.3g} {unit} with the {h.flagged} outlying row(s))" if h.flagged else ""
        parts.append(f"{name} RMS {h.rms * scale:.3g} {unit}{outl} against {h.rms_predicted * scale:.3g} {unit} "
                     f"predicted from the training folds, model error {getattr(cv, f'{name}_model') * scale:.3g} "
                     f"{unit}")
    note = (f"cross-validated over {cv.k} folds by configuration (frames from the training folds, nothing refitted "
            f"on the held-out fold): held-out {'; '.join(parts)}; the predictions carry the cross-validated model "
            "error")
    return replace(result, cross_validation=cv, messages=result.messages + (note,))
