"""The sandwich covariance and the expected chi^2 of a least-squares fit whose residual covariance is Omega
rather than the identity (``kincal.analysis.covariance``), checked on a linear model by simulation."""

import numpy as np

from kincal.analysis.covariance import covariance, sandwich, weighted_fit_dof


def _problem(rng, m=40, p=5):
    J = rng.normal(size=(m, p))
    A = rng.normal(size=(m, m)) * 0.3 + np.diag(rng.uniform(0.2, 3.0, m))
    return J, A @ A.T  # Omega: far from the identity


def test_sandwich_and_expected_chi2_match_simulation():
    """20000 draws of e ~ N(0, Omega): the estimates' covariance is the sandwich, the chi^2 of the residuals
    whitened by Omega averages m - 2 rank + tr(F C). Sampling error: about 1 % on variances and on the mean
    chi^2 (its std is about sqrt(2 dof / n)), so 5 % is far outside it."""
    rng = np.random.default_rng(0)
    J, Om = _problem(rng)
    m, p = J.shape
    V = np.eye(p)
    e = rng.multivariate_normal(np.zeros(m), Om, size=20000)
    x = np.linalg.lstsq(J, e.T, rcond=None)[0].T  # fit weighted by the identity
    r = e - x @ J.T
    C = sandwich(J, J.T @ Om @ J, V)
    np.testing.assert_allclose(np.cov(x.T), C, rtol=0.05, atol=0.05 * np.abs(C).max())
    Oi = np.linalg.inv(Om)
    chi2 = np.einsum("ni,ij,nj->n", r, Oi, r)
    dof = weighted_fit_dof(J, J.T @ Om @ J, J.T @ Oi @ J, V, m, p)
    assert dof > m - p + 0.5  # a fit not weighted by the noise loses chi^2 against the best one
    assert abs(chi2.mean() / dof - 1) < 0.02, (chi2.mean(), dof)


def test_with_the_identity_it_is_the_usual_covariance_on_a_subspace():
    rng = np.random.default_rng(1)
    J, _ = _problem(rng)
    V = np.linalg.qr(rng.normal(size=(J.shape[1], 3)))[0]
    np.testing.assert_allclose(sandwich(J, J.T @ J, V, 2.0), covariance(J, V, 2.0), rtol=1e-9, atol=1e-12)
    assert np.isclose(weighted_fit_dof(J, J.T @ J, J.T @ J, V, J.shape[0], 3), J.shape[0] - 3)
