"""The parts of a predicted validation error that are not parameter uncertainty: the measurement noise of the
validation data, and the model error the calibration could not explain.

A validation residual at a configuration is the calibrated model's error there plus the measurement's own
noise. The model's error has two parts: the parameters' uncertainty (``Prediction.position_std``) and what
the model cannot represent at all, which the calibration data show as residuals beyond their stated noise
(a variance factor above 1). Their mean squares add (``Prediction.position_rms_predicted``).
"""

from __future__ import annotations

import numpy as np

from kincal.noise import ORIENTATION, POSITION, Noise

# A variance factor this many of its standard errors (sqrt(2 / dof)) above 1 shows a model error; below, the
# excess is the noise's own scatter.
SIGNIFICANT = 3.0


def measurement_noise(Eq: np.ndarray, noise: Noise | None) -> tuple[np.ndarray, np.ndarray]:
    """Per configuration, the RMS length (m, rad) of the position and orientation error that the stated
    ``noise`` of a measurement adds: ``3 sigma^2`` per 3-vector, plus the encoders' ``sigma_joint^2 |E_q|_F^2``
    through the tool point's and orientation's joint Jacobian ``Eq`` (N, 6, n). Zero without ``noise``."""
    if noise is None:
        return np.zeros(len(Eq)), np.zeros(len(Eq))
    sj2 = noise.joint_sigma() ** 2
    pos = 3 * (noise.position or 0.0) ** 2 + sj2 * np.sum(Eq[:, :3] ** 2, axis=(1, 2))
    rot = 3 * (noise.orientation or 0.0) ** 2 + sj2 * np.sum(Eq[:, 3:] ** 2, axis=(1, 2))
    return np.sqrt(pos), np.sqrt(rot)


def unexplained_error(result) -> tuple[float, float]:
    """The RMS length (m, rad) of the position and orientation error the calibrated model cannot represent,
    from its calibration residuals: per residual component, the mean square beyond what the stated noise
    explains (``Sigma``'s diagonal, from the whiteners), with the fit's degrees of freedom restored
    (``m / (m - rank)``, as in the variance factor) and the robust loss' weights; times 3 for a 3-vector.
    0 when the variance factor is within ``SIGNIFICANT`` standard errors of 1 (the residuals are within the
    noise); nan for a quantity the calibration data do not measure."""
    lin = result.linearization
    if lin is None or result.problem is None:
        return float("nan"), float("nan")
    dof = len(lin.r) - result.identifiability.rank
    if dof <= 0 or not result.sigma2 > 1 + SIGNIFICANT * np.sqrt(2 / dof):
        return 0.0, 0.0  # the residuals are within the noise: no model error to speak of
    inflate = len(lin.r) / dof
    sums = {POSITION: np.zeros(3), ORIENTATION: np.zeros(3)}  # (sum w r^2, sum w sigma^2, sum w)
    start = 0
    for exp, W, r in zip(result.problem.experiments, lin.W, lin.residuals):
        N, k = r.shape
        w = np.ones(N) if result.weights is None else result.weights[start: start + N * k].reshape(N, k).mean(1)
        start += N * k
        L = np.linalg.inv(W)  # Sigma = L L^T per sample
        var = np.sum(L**2, axis=-1)  # (N, k) diagonal of Sigma
        for q, acc in sums.items():
            mask = np.array([c == q for c in exp.components()], bool)
            if mask.any():
                acc += [np.sum(w[:, None] * r[:, mask] ** 2), np.sum(w[:, None] * var[:, mask]), w.sum() * mask.sum()]
    out = []
    for r2, s2, count in sums.values():
        out.append(float(np.sqrt(3 * max(r2 * inflate - s2, 0.0) / count)) if count else float("nan"))
    return out[0], out[1]
