"""LAPACK's gesdd (numpy's SVD) can fail with "SVD did not converge" on ill-conditioned Jacobians (issue 14: the
kinematic + elastic problem of DLR's Agile Justin); kincal then redoes the SVD with gesvd, and a least-squares
solve with gelsy (``kincal.analysis.linalg``)."""

import re
import sys
from pathlib import Path

import numpy as np
import pytest

from kincal.analysis import linalg
from kincal.estimation import calibrate
from kincal.noise import Noise as Stated
from kincal.robots import load
from kincal.simulate.generators import generate_markers
from kincal.simulate.noise import Noise
from kincal.simulate.perturb import perturb_robot

SRC = Path(linalg.__file__).resolve().parents[1]
NUMPY_SVD, NUMPY_LSTSQ = np.linalg.svd, np.linalg.lstsq


def _failing(original):
    """``original`` raising LinAlgError as gesdd/gelsd do when they do not converge, for kincal.analysis.linalg's
    calls only (lower layers, e.g. the rotation projection in kincal.lie, keep numpy's)."""
    def call(*args, **kwargs):
        if sys._getframe(1).f_globals.get("__name__") == linalg.__name__:
            call.failed += 1
            raise np.linalg.LinAlgError("SVD did not converge")
        return original(*args, **kwargs)
    call.failed = 0
    return call


@pytest.fixture
def gesdd_fails(monkeypatch):
    monkeypatch.setattr(np.linalg, "svd", _failing(NUMPY_SVD))
    monkeypatch.setattr(np.linalg, "lstsq", _failing(NUMPY_LSTSQ))
    monkeypatch.setattr(linalg, "_kernels", None)  # ``thin_svd`` and ``complete_q`` by numpy's calls too


def _matrices():
    rng = np.random.default_rng(0)
    tall = rng.standard_normal((40, 7)) * np.logspace(0, -12, 7)  # graded columns, like a whitened Jacobian
    wide = rng.standard_normal((5, 9))
    return [tall, wide, rng.standard_normal((4, 6, 3))]  # the last a stack, as kincal.analysis.prediction has


@pytest.mark.parametrize("full", [True, False])
def test_svd_falls_back_to_gesvd_with_numpy_shapes_and_values(gesdd_fails, full):
    for a in _matrices():
        U0, S0, Vt0 = NUMPY_SVD(a, full_matrices=full)
        U, S, Vt = linalg.svd(a, full_matrices=full)
        assert (U.shape, S.shape, Vt.shape) == (U0.shape, S0.shape, Vt0.shape)
        np.testing.assert_allclose(S, S0, rtol=1e-12, atol=1e-14 * S0.max())
        k = S.shape[-1]
        np.testing.assert_allclose((U[..., :k] * S[..., None, :]) @ Vt[..., :k, :], a, atol=1e-13)
        rows = Vt @ np.swapaxes(Vt, -1, -2)  # orthonormal rows
        np.testing.assert_allclose(rows, np.broadcast_to(np.eye(Vt.shape[-2]), rows.shape), atol=1e-13)
        np.testing.assert_allclose(linalg.svd(a, compute_uv=False), S0, rtol=1e-12, atol=1e-14 * S0.max())


def test_lstsq_falls_back_to_gelsy(gesdd_fails):
    rng = np.random.default_rng(1)
    A = rng.standard_normal((30, 6))
    A[:, 5] = A[:, 4]  # rank deficient: the minimum-norm solution, as numpy's
    b = rng.standard_normal(30)
    np.testing.assert_allclose(linalg.lstsq(A, b), NUMPY_LSTSQ(A, b, rcond=None)[0], rtol=1e-10, atol=1e-12)


def test_without_failure_numpy_is_used_and_bad_numbers_still_raise():
    a = _matrices()[0]
    for x, y in zip(linalg.svd(a, full_matrices=False), NUMPY_SVD(a, full_matrices=False)):
        np.testing.assert_array_equal(x, y)
    with pytest.raises(np.linalg.LinAlgError):
        linalg.svd(np.full((3, 3), np.nan))


def test_every_svd_and_least_squares_of_analysis_and_estimation_goes_through_the_fallback():
    direct = re.compile(r"(np|numpy|scipy)\.linalg\.(svd|lstsq)\(")
    offenders = [f"{p.relative_to(SRC)}:{i}" for pkg in ("analysis", "estimation") for p in (SRC / pkg).glob("*.py")
                 if p.name != "linalg.py"
                 for i, line in enumerate(p.read_text().splitlines(), 1) if direct.search(line)]
    assert offenders == []


def _calibration():
    r = load("klimchik3r")
    true = perturb_robot(r, "fine", 3)
    true = true.replace_arm("arm", true["arm"].replace(compliance=[1e-5, 3e-6, 2e-5]))
    ds, _, val = generate_markers(true, n=25, rng=5, markers=3, noise=Noise(position=2e-5), wrench=2500.0)
    return calibrate(r, [ds], ["kinematic", "elastic"], validation=[val["arm"]],
                     noise=Stated(position=2e-5, orientation=1e-5, joint=0.0))


def test_a_calibration_with_gesdd_failing_everywhere_gives_the_same_result(monkeypatch):
    """Rank, gauge, symmetries, covariance, steps, the min-change view and predictions: every decomposition on the
    fallback."""
    ref = _calibration()
    ref_gauge = ref.gauge
    svd, lstsq = _failing(NUMPY_SVD), _failing(NUMPY_LSTSQ)
    monkeypatch.setattr(np.linalg, "svd", svd)
    monkeypatch.setattr(np.linalg, "lstsq", lstsq)
    monkeypatch.setattr(linalg, "_kernels", None)  # the rank analysis' ``thin_svd`` by numpy's call, failing too
    res = _calibration()
    # the estimates in the min-change gauge, as ``kincal calibrate`` prints them: the walk to the min-change point
    # solves by least squares (the solve's own steps take theirs from the rank analysis' SVD, ``analysis.factor``)
    gauge = res.gauge
    assert svd.failed > 10 and lstsq.failed > 3  # the fallback did the work
    np.testing.assert_allclose(gauge.determined, ref_gauge.determined, rtol=1e-6, atol=1e-10)
    assert (res.status, res.trusted, res.identifiability.rank) == (ref.status, ref.trusted, ref.identifiability.rank)
    # the same messages naming the same directions; which partners of equal weight are listed first (and which
    # are left to "and N more") round-off decides
    assert [m.split(" it trades off")[0] for m in res.messages] == [m.split(" it trades off")[0] for m in ref.messages]
    for a, b in zip(res.estimates, ref.estimates):
        assert a.name == b.name and a.identifiable == b.identifiable
        assert a.value == pytest.approx(b.value, rel=1e-7, abs=1e-10)
        assert a.std == pytest.approx(b.std, rel=1e-6, nan_ok=True)
    (_, p), (_, p0) = res.predictions[0], ref.predictions[0]
    assert p.position_rms_predicted == pytest.approx(p0.position_rms_predicted, rel=1e-6)
