"""Outlying configurations (rows): found after a robust pass, named, left out of the final solve.

The rule (docs/calibration.md "Outliers"): per configuration, the whitened residual's chi^2 over its ``k``
components, divided by a robust scale (the median row's chi^2 over the chi^2 median at ``k`` dof, at least 1: a
model error shared by all rows is not an outlier, stated noise that is too large is not shrunk). A row whose
scaled chi^2 has a tail probability below ``threshold`` (default ``DEFAULT_THRESHOLD``) is an outlier; in a data
set of more than ``REFERENCE_ROWS`` rows the threshold shrinks by ``REFERENCE_ROWS / N`` (``row_threshold``), so
that clean Gaussian rows give at most ``threshold * REFERENCE_ROWS`` false alarms per data set whatever its size
(a fixed per-row threshold flags ``N * threshold`` of them: one in ten solves at N = 100,000).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kincal._memo import remember
from kincal.errors import ModelError
from kincal.experiments import KINDS
from kincal.params.layout import on_clear

# Tail probability below which a row is an outlier: one false alarm in a million clean rows.
DEFAULT_THRESHOLD = 1e-6
# The robust first pass: a Cauchy loss with this scale in whitened units (sigmas).
ROBUST_LOSS, ROBUST_F_SCALE = "cauchy", 3.0
# At most this fraction of a data set's rows is rejected: beyond it the model, not the rows, is wrong.
MAX_FRACTION = 0.5
# Rows up to which the threshold is per row; beyond, it is per this many rows (Bonferroni), see the module doc.
REFERENCE_ROWS = 1000


@dataclass(frozen=True)
class Outlier:
    """One rejected configuration: data set name, sample index in it, CSV line (header = line 1; None for
    in-memory data), file (None likewise) and standardized residual (the row's whitened residual norm over the
    robust scale, in sigmas)."""

    experiment: str
    sample: int
    line: int | None
    file: str | None
    standardized: float


def outlier_threshold(outliers) -> float | None:
    """``"reject"`` -> ``DEFAULT_THRESHOLD``, ``"keep"`` -> None, a number in (0, 1) -> itself (tail probability)."""
    if outliers == "reject":
        return DEFAULT_THRESHOLD
    if outliers == "keep":
        return None
    if isinstance(outliers, (int, float)) and not isinstance(outliers, bool) and 0 < outliers < 1:
        return float(outliers)
    raise ModelError(f"outliers must be 'reject', 'keep' or a tail probability in (0, 1), got {outliers!r}")


def row_chi2(problem, state) -> list[np.ndarray]:
    """Per experiment of ``problem``, the whitened chi^2 of each configuration (N,) at ``state``."""
    out = []
    for W, res in zip(problem.whiteners(state), problem.residuals(state)):
        d = problem.cache.diagonal(W)  # one diagonal for every sample: it scales rows, as the solve whitens them
        out.append(((res.r * d if d is not None else np.einsum("nij,nj->ni", W, res.r)) ** 2).sum(axis=1))
    return out


def scaled_chi2(c: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(scaled chi^2, tail probability) of rows with chi^2 ``c`` (N,) over ``k`` components each: the robust
    scale of the module doc (the median row over the chi^2 median at ``k`` dof, at least 1)."""
    # here, not at the top: scipy.special (through scipy's array-API layer) costs more than importing kincal
    from scipy.special import chdtrc
    scaled = c / _scale(c, k)
    return scaled, chdtrc(k, scaled)  # upper tail probability


def _scale(c: np.ndarray, k: int) -> float:
    """The robust scale of rows with chi^2 ``c`` over ``k`` components (``scaled_chi2``)."""
    return max(median(c) / chi2_quantile(k, 0.5), 1.0) if len(c) else 1.0  # chi^2 median at k dof


def chi2_quantile(k: int, p: float) -> float:
    """``chdtri(k, p)``: the chi^2 value at ``k`` dof with upper tail probability ``p``; remembered per (k, p) for
    a Python int ``k`` and float ``p`` (a function of them alone: the components of a residual, a threshold)."""
    from scipy.special import chdtri
    if type(k) is not int or type(p) is not float:
        return chdtri(k, p)
    hit = _QUANTILES.get((k, p))
    return hit if hit is not None else remember(_QUANTILES, (k, p), chdtri(k, p), QUANTILE_ENTRIES)


# chi2_quantile's memory: (dof, tail probability) -> chdtri's value (a numpy float, as chdtri returns it)
_QUANTILES: dict[tuple, np.floating] = {}
QUANTILE_ENTRIES = 64


@on_clear
def clear_quantiles() -> None:
    """Forget what ``chi2_quantile`` remembered (``kincal.params.clear_caches`` runs this)."""
    _QUANTILES.clear()


def median(c: np.ndarray) -> float:
    """``float(np.median(c))`` of a 1-d ``c`` (not empty), by numpy's own rule without its wrapper: the middle
    element(s) of one partition (the last position too: a nan sorts last and makes the median nan), the mean of
    two as ``(a + b) / 2``."""
    n = len(c)
    h = n // 2
    part = np.partition(c, [h - 1, h, n - 1] if n % 2 == 0 else [h, n - 1])
    if part[-1] != part[-1]:
        return float("nan")
    return float(part[h] if n % 2 else (part[h - 1] + part[h]) / 2)


def row_threshold(threshold: float, n: int) -> float:
    """The tail probability below which one of ``n`` rows is an outlier: ``threshold`` up to ``REFERENCE_ROWS``
    rows, ``threshold * REFERENCE_ROWS / n`` beyond (the expected false alarms on clean data stay bounded)."""
    return threshold * min(1.0, REFERENCE_ROWS / max(n, 1))


def beyond(p: np.ndarray, threshold: float) -> np.ndarray:
    """Sorted indices of the rows whose tail probability ``p`` is below ``row_threshold(threshold, len(p))``:
    the worst ``MAX_FRACTION`` of the rows at most."""
    bad = np.flatnonzero(p < row_threshold(threshold, len(p)))
    return np.sort(bad[np.argsort(p[bad])][: int(MAX_FRACTION * len(p))])


def standardized(problem, state) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per experiment: (scaled chi^2, tail probability) of each row, with the robust scale of the module doc."""
    return [scaled_chi2(c, len(exp.components())) for exp, c in zip(problem.experiments, row_chi2(problem, state))]


def find_outliers(problem, state, threshold: float) -> list[Outlier]:
    """The rows of ``problem``'s data sets beyond ``threshold`` at ``state`` (at most ``MAX_FRACTION`` of a set,
    the worst): the rule for calibration data and, at the calibrated model with its frames fitted, for
    validation data alike."""
    found = []
    for exp, (c, p) in zip(problem.experiments, standardized(problem, state)):
        lines, file = exp.dataset.meta.get("lines"), exp.dataset.meta.get("file")
        for i in beyond(p, threshold):
            found.append(Outlier(exp.name, int(i), None if lines is None else int(lines[i]), file,
                                 float(np.sqrt(c[i]))))
    return found


def states_noise(ds, noise) -> bool:
    """Whether ``noise`` states a positive standard deviation for a residual quantity of data set ``ds`` or its
    encoders: rows are standardized by it, so noise-free (simulated) data have no outliers to find."""
    return noise.joint_sigma() > 0 or any((noise.sigma(q) or 0.0) > 0 for q in KINDS[ds.kind](ds, {}).components())


def any_beyond(problem, state, threshold: float) -> bool:
    """Whether any row is beyond ``threshold`` at ``state`` (the screen before a robust pass): ``standardized``'s
    tail probabilities below ``row_threshold``, read from the largest scaled chi^2 where it is clearly below the
    threshold's quantile (the tail probability decreases with chi^2; the margin, 1e-6 relative, is far above
    the round-off of ``chdtrc`` and ``chdtri``), else from every row's tail probability."""
    from scipy.special import chdtrc
    for exp, c in zip(problem.experiments, row_chi2(problem, state)):
        if not len(c):
            continue
        k, t = len(exp.components()), row_threshold(threshold, len(c))
        scaled = c / _scale(c, k)
        if float(scaled.max()) < (1 - QUANTILE_MARGIN) * chi2_quantile(k, t):  # a nan row fails: read exactly
            continue
        if bool((chdtrc(k, scaled) < t).any()):
            return True
    return False


# any_beyond's relative margin below the threshold's chi^2 quantile within which it reads tail probabilities
QUANTILE_MARGIN = 1e-6


def kept(datasets, outliers: list[Outlier]):
    """``datasets`` without the ``outliers`` rows (a data set named by an outlier by its ``name``)."""
    out = []
    for ds in datasets:
        drop = [o.sample for o in outliers if o.experiment == ds.name]
        if not drop:
            out.append(ds)
            continue
        out.append(ds.subset(np.setdiff1d(np.arange(ds.size), drop)))
    return out
