"""The parts of a predicted validation error that are not parameter uncertainty: the measurement noise of the
validation data, and the model error the calibration could not explain.

A validation residual at a configuration is the calibrated model's error there plus the measurement's own
noise. The model's error has two parts: the parameters' uncertainty (``Prediction.position_std``) and what
the model cannot represent at all, which the calibration data show as residuals beyond their stated noise
(a variance factor above 1), measured as a configuration the fit did not see would show it (leave-one-
configuration-out residuals) or by cross-validation (``kincal.estimation.crossval``). Their mean squares add
(``Prediction.position_rms_predicted``). Noise is attributed to the data that state it: stated backlash is
measurement noise of the calibration data (whitening leaves it out), not a model error to carry elsewhere.
"""

from __future__ import annotations

import numpy as np

from kincal.noise import ORIENTATION, POSITION, Noise

# A variance factor this many of its standard errors (sqrt(2 / dof)) above 1 shows a model error; below, the
# excess is the noise's own scatter.
SIGNIFICANT = 3.0


def encoder_variance(noise: Noise | None) -> float:
    """Variance (rad^2) of a joint reading's error: the encoders' noise and the backlash's dead band (a reading
    off by ``+-b/2`` with the direction of motion: variance ``b^2 / 4``). Calibration whitens only the first;
    both are stated measurement noise, not model error."""
    if noise is None:
        return 0.0
    return noise.joint_sigma() ** 2 + (noise.backlash or 0.0) ** 2 / 4


def component_noise(exp, noise: Noise, jq) -> np.ndarray:
    """(N, k): per residual component of experiment ``exp``, the variance its stated ``noise`` gives: the
    quantity's sigma^2 (0 where not stated) plus ``encoder_variance`` through the joint Jacobians ``jq``
    (arm -> (N, k, n))."""
    sig = np.array([noise.sigma(q) or 0.0 for q in exp.components()], float) ** 2
    var = np.broadcast_to(sig, (exp.size, len(sig))).copy()
    ej = encoder_variance(noise)
    for j in jq.values():
        var += ej * np.sum(j**2, axis=-1)
    return var


def measurement_noise(Eq: np.ndarray, noise: Noise | None) -> tuple[np.ndarray, np.ndarray]:
    """Per configuration, the RMS length (m, rad) of the position and orientation error that the stated
    ``noise`` of a measurement adds: ``3 sigma^2`` per 3-vector, plus ``encoder_variance |E_q|_F^2`` (encoders
    and backlash) through the tool point's and orientation's joint Jacobian ``Eq`` (N, 6, n). Zero without
    ``noise``."""
    if noise is None:
        return np.zeros(len(Eq)), np.zeros(len(Eq))
    sj2 = encoder_variance(noise)
    pos = 3 * (noise.position or 0.0) ** 2 + sj2 * np.sum(Eq[:, :3] ** 2, axis=(1, 2))
    rot = 3 * (noise.orientation or 0.0) ** 2 + sj2 * np.sum(Eq[:, 3:] ** 2, axis=(1, 2))
    return np.sqrt(pos), np.sqrt(rot)


def model_error(result) -> tuple[float, float]:
    """The model error (m, rad; RMS length of a 3-vector) to carry into predictions: the cross-validated one
    when ``result`` has a cross-validation (``calibrate(..., cv=K)``), else ``unexplained_error``'s. The
    orientation part is nan (unknown) when the calibration data measure no orientation but show a model error
    in position: nothing in them bounds what the model gets wrong about orientation."""
    cv = getattr(result, "cross_validation", None)
    pos, rot = unexplained_error(result)
    if cv is not None:
        pos, rot = cv.position_model, (cv.orientation_model if np.isfinite(rot) else rot)
    if not np.isfinite(rot) and not pos > 0:
        rot = 0.0  # position within its noise: the parameters' uncertainty is all there is to predict
    return (pos if np.isfinite(pos) else 0.0), rot


def unexplained_error(result) -> tuple[float, float]:
    """The RMS length (m, rad) of the position and orientation error the calibrated model cannot represent, as
    new configurations would show it: per residual component, the mean square of the *leave-one-configuration-
    out* residuals (``loo_residuals``: what each configuration's residual would be had the fit not seen it)
    beyond what the stated noise (with the backlash that whitening leaves out) and the parameter uncertainty at
    the configuration explain, with the robust loss' weights; times 3 for a 3-vector. A model error shared
    by all configurations shrinks the in-sample residuals by more than the degrees of freedom say when the
    free parameters absorb part of it; the held-out configurations see it whole. 0 when the variance
    factor, counted against all stated noise, is within ``SIGNIFICANT`` standard errors of 1 (the residuals
    are within the noise); nan for a quantity the calibration data do not measure."""
    lin = result.linearization
    if lin is None or result.problem is None:
        return float("nan"), float("nan")
    dof = len(lin.r) - result.identifiability.rank
    if dof <= 0:
        return 0.0, 0.0
    sums = _residual_sums(result)
    whitened = sum(acc[1] for acc in sums.values())
    stated = sum(acc[3] for acc in sums.values())
    if not result.sigma2 * whitened / max(stated, 1e-300) > 1 + SIGNIFICANT * np.sqrt(2 / dof):
        return 0.0, 0.0  # the residuals are within the noise: no model error to speak of
    out = []
    for r2, _, count, s2, p2 in sums.values():
        out.append(float(np.sqrt(3 * max(r2 - s2 - p2, 0.0) / count)) if count else float("nan"))
    return out[0], out[1]


def loo_residuals(J: np.ndarray, r: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Leave-one-configuration-out residuals (N, k) of a linear least-squares fit from whitened per-configuration
    Jacobians ``J`` (N, k, p), residuals ``r`` (N, k) and the fit's pseudo-inverse normal matrix ``A``
    (``(J^T J)^+`` on the identifiable subspace): ``(I - H_ii)^-1 r_i`` with ``H_ii = J_i A J_i^T``, exact for
    a linear model (the block version of the PRESS residual)."""
    H = J @ A @ np.swapaxes(J, -1, -2)
    eye = np.broadcast_to(np.eye(r.shape[1]), H.shape)
    return np.linalg.solve(eye - H, r[..., None])[..., 0]


def _residual_sums(result) -> dict:
    """Per quantity (position, orientation): [sum w r_loo^2, sum w sigma^2 whitened, sum w, sum w sigma^2
    stated (with backlash), sum w diag(J C J^T)] over the calibration residuals' components (unwhitened;
    ``w``: the robust loss' weight per row)."""
    lin, problem = result.linearization, result.problem
    sums = {POSITION: np.zeros(5), ORIENTATION: np.zeros(5)}
    scale = result.scale
    A = result.covariance / scale if np.isfinite(scale) and scale > 0 else result.covariance
    start = 0
    for exp, nz, W, r in zip(problem.experiments, problem.noise, lin.W, lin.residuals):
        N, k = r.shape
        w = np.ones(N) if result.weights is None else result.weights[start: start + N * k].reshape(N, k).mean(1)
        Jw = lin.J[start: start + N * k].reshape(N, k, -1)
        start += N * k
        L = np.linalg.inv(W)  # Sigma = L L^T per sample
        var = np.sum(L**2, axis=-1)  # (N, k) diagonal of Sigma
        loo = np.einsum("nij,nj->ni", L, loo_residuals(Jw, np.einsum("nij,nj->ni", W, r), A))
        J = L @ Jw
        param = np.sum((J @ result.covariance) * J, axis=-1).clip(0)
        extra = np.zeros_like(var)
        if nz.backlash:  # stated but not whitened: a measurement noise of these data, not a model error
            for j in exp.residual(lin.state, want=set(), jq=True).jq.values():
                extra += nz.backlash**2 / 4 * np.sum(j**2, axis=-1)
        for q, acc in sums.items():
            mask = np.array([c == q for c in exp.components()], bool)
            if mask.any():
                wv = w[:, None] * var[:, mask]
                acc += [np.sum(w[:, None] * loo[:, mask] ** 2), np.sum(wv), w.sum() * mask.sum(),
                        np.sum(wv + w[:, None] * extra[:, mask]), np.sum(w[:, None] * param[:, mask])]
    return sums
