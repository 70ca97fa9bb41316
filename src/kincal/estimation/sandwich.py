"""Covariance and variance factor of a fit weighted otherwise than by the noise (a reweighted pose's ``noise_cov``,
``kincal.experiments.pose.weighted``): the sandwich.

In the fit's whitened coordinates the residual's covariance is no longer the identity but ``Omega``, block
diagonal with ``M = W Sigma W^T`` per sample (``W`` the fit's whitener, ``Sigma`` the residual's actual covariance:
the data's noise covariance plus the same encoder term); prior and constraint rows keep the identity. The
estimate ``delta = (J^T J)^+ J^T r`` then has the covariance ``(J^T J)^+ J^T Omega J (J^T J)^+``
(``kincal.analysis.covariance.sandwich``), on the identifiable subspace as every covariance of kincal.

The variance factor keeps its meaning, the factor by which the stated noise must be scaled to explain the
residuals: it is the chi^2 of the residuals whitened by ``Sigma`` (``r^T Omega^-1 r``) over its expectation, which
for a fit not weighted by ``Sigma`` is ``m - 2 rank + tr(F C)`` (``F = J^T Omega^-1 J``, ``C`` the unscaled sandwich;
``m - rank`` when the weights are the noise's). The chi^2 of the fit's own weights would say nothing about the
noise: its scale is arbitrary (1 m = 1 rad).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kincal.analysis.covariance import sandwich, weighted_fit_dof
from kincal.estimation.problem import VARIANCE_FLOOR, Problem, stated_sigmas


@dataclass(frozen=True)
class Sandwich:
    """The sandwich's parts for one linearization: ``J`` the fit's whitened Jacobian (rows weighted by a robust
    loss), ``meat = J^T Omega J``, ``fisher = J^T Omega^-1 J``, ``chi2 = r^T Omega^-1 r`` and ``m`` rows."""

    J: np.ndarray
    meat: np.ndarray
    fisher: np.ndarray
    chi2: float
    m: int

    @classmethod
    def of(cls, problem: Problem, lin, weights: np.ndarray) -> "Sandwich | None":
        """The sandwich of ``lin`` (a ``Linearization`` of ``problem``) with robust row ``weights``, or None when
        every experiment is weighted by its noise (the usual covariance is then exact)."""
        Ms = noise_in_fit_units(problem, lin.W)
        if Ms is None:
            return None
        J = np.sqrt(weights)[:, None] * lin.J
        meat, fisher, chi2 = J.T @ J, J.T @ J, float(np.sum(weights * lin.r**2))
        start = 0
        for M, W in zip(Ms, lin.W):
            N, k = W.shape[:2]
            rows = slice(start, start + N * k)
            start += N * k
            if M is None:
                continue
            Jn, rn = J[rows].reshape(N, k, -1), (np.sqrt(weights[rows]) * lin.r[rows]).reshape(N, k, 1)
            Mi = np.linalg.inv(M)
            meat += np.einsum("nkp,nkq->pq", Jn, (M - np.eye(k)) @ Jn)
            fisher += np.einsum("nkp,nkq->pq", Jn, (Mi - np.eye(k)) @ Jn)
            chi2 += float(np.sum(rn * ((Mi - np.eye(k)) @ rn)))
        return cls(J, meat, fisher, chi2, len(lin.r))

    def variance_factor(self, range_space: np.ndarray, rank: int) -> float:
        """The chi^2 of the residuals whitened by the noise over its expectation (nan without redundancy)."""
        dof = weighted_fit_dof(self.J, self.meat, self.fisher, range_space, self.m, rank)
        return self.chi2 / dof if dof > 0 else float("nan")

    def covariance(self, V: np.ndarray, sigma2: float) -> np.ndarray:
        """The estimate's covariance in the gauge ``V`` (p, r), scaled by ``sigma2``."""
        return sandwich(self.J, self.meat, V, sigma2)


def noise_in_fit_units(problem: Problem, whiteners) -> list | None:
    """Per experiment, ``M = W Sigma W^T`` (N, k, k), the covariance of its fit-whitened residual under its actual
    noise, or None where the fit weights by that noise; None altogether when no experiment needs one.
    ``Sigma - C_fit`` is the noise covariance less the fit's measurement covariance (the encoder term is common)."""
    out = []
    for exp, nz, W in zip(problem.experiments, problem.noise, whiteners):
        true = exp.noise_covariance()
        if true is None:
            out.append(None)
            continue
        fit = exp.covariance()
        if fit is None:
            fit = np.diag(np.maximum(stated_sigmas(exp, nz) ** 2, VARIANCE_FLOOR))
        k = W.shape[-1]
        out.append(np.eye(k) + W @ (true - fit) @ np.swapaxes(W, -1, -2))
    return None if all(M is None for M in out) else out
