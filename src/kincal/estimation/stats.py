"""Typed residual statistics of a calibration: per data set at a model, and before/after on validation sets."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kincal.analysis.linalg import norms
from kincal.noise import ORIENTATION, PIXEL, POSITION


@dataclass(frozen=True)
class ResidualStats:
    """Residuals of one data set at one model. Position and orientation errors are norms per sample (per point
    where a sample has several), in m and rad; None when the data set has no such component. ``chi2``: the
    whitened sum of squares, over ``dof`` residual components."""

    experiment: str
    kind: str
    samples: int
    position_rms: float | None
    position_max: float | None
    orientation_rms: float | None
    orientation_max: float | None
    chi2: float
    dof: int
    pixel_rms: float | None = None  # image residuals (px), when the data set has them
    pixel_max: float | None = None


@dataclass(frozen=True)
class ValidationStats:
    """One held-out data set at the nominal model (``before``) and at the calibrated one (``after``); unknown
    frames of the set are fitted with every arm parameter fixed."""

    experiment: str
    kind: str
    samples: int
    before: ResidualStats
    after: ResidualStats


def residual_norms(r: np.ndarray, components) -> dict:
    """RMS and max over samples of the position-part and orientation-part norms (m, rad):
    ``{position_rms, position_max, orientation_rms, orientation_max}``, None for a part the residual lacks."""
    st = dict.fromkeys(("position_rms", "position_max", "orientation_rms", "orientation_max", "pixel_rms", "pixel_max"))
    components = tuple(components)
    for key, q in (("position", POSITION), ("orientation", ORIENTATION), ("pixel", PIXEL)):
        if q not in components:  # (``in`` tries identity first: the quantities are module constants)
            continue
        rows = [c is q or c == q for c in components]
        count = rows.count(True)
        # every column of one quantity: r[:, mask] would be r's C-ordered copy, which a C-ordered r is already
        part = np.ascontiguousarray(r) if count == len(rows) else r[:, np.array(rows, bool)]
        if count % 3 == 0 and key == "position" and count > 1:
            e = norms(part.reshape(len(r), -1, 3), -1).ravel()
        elif key in ("orientation", "pixel"):
            e = norms(part, -1)
        else:
            e = np.abs(part).ravel()
        st[f"{key}_rms"] = math.sqrt(mean(e * e))  # np.sqrt's bits: both round correctly
        st[f"{key}_max"] = float(e.max())
    return st


def mean(x: np.ndarray, axis: int | None = None):
    """``np.mean(x, axis)`` of a float array: numpy's own sum over the count, without its wrapper (the same bits)."""
    return np.add.reduce(x, axis=axis) / (x.size if axis is None else x.shape[axis])
