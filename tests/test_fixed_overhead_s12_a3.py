"""Session 12 (a3, round 3): the linearization's triangular factor by LAPACK's blocked QR (``geqrt``).

``triangular_factor(..., panels=True)`` is numpy's R to round-off (C-ordered, +0.0 below the diagonal; numpy's
bit for bit below ``QR_TALL`` rows); whole calibrations (markers, pose, socket, clamp, dual arm, elastic) with it
on every linearization (the row threshold lowered) and with the unblocked ``geqrf`` give the same rank, status,
messages and iterations, estimates and std within 1e-10 relative (the covariance of the coordinates an elastic
solve holds is round-off around zero in both, ~1e-48 against ~1e-7 for the others, and not compared entry by
entry)."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.estimation import problem as P
from kincal.estimation import steps
from test_fixed_overhead_s12_a import _cases
from test_fixed_overhead_s12_a2 import _elastic
from test_structure_cache import ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)


SHAPES = [(600, 46), (3000, 53), (256, 8), (300, 7), (150, 45), (20, 45), (300, 1), (400, 129)]


@pytest.mark.parametrize("shape", SHAPES)
def test_blocked_triangular_factor_is_numpys_r_to_round_off(shape):
    rng = np.random.default_rng(sum(shape))
    A = rng.normal(size=shape) * np.exp(rng.normal(size=shape[1]))
    A[:, 0] *= -1.0
    expected = np.linalg.qr(A, mode="r")
    R = P.triangular_factor([A[:, :-1], A[:, -1]] if shape[1] > 1 else [A], panels=True)
    assert R.flags.c_contiguous and R.shape == expected.shape
    assert np.abs(R - expected).max() <= 1e-13 * np.abs(expected).max()
    below = R[np.tril_indices(R.shape[0], -1, R.shape[1])]
    assert not below.any() and not np.signbit(below).any()
    if shape[0] < P.QR_TALL or shape[1] < P.QR_PANEL:  # not tall enough to pay: the unblocked factor, numpy's
        assert R.tobytes() == np.ascontiguousarray(expected).tobytes()


def _unblocked(columns, panels=False):
    _unblocked.calls += 1
    return P.triangular_factor(columns)


@pytest.mark.parametrize("case", ["markers", "pose", "socket", "clamp", "dual", "elastic"])
def test_calibrations_with_the_blocked_factor_agree_to_1e_10(monkeypatch, ur10_sets, case):
    run = _elastic if case == "elastic" else _cases(ur10_sets)[case]
    with monkeypatch.context() as m:
        m.setattr(P, "QR_TALL", P.QR_PANEL)  # these solves' few rows: the blocked QR wherever a panel fits
        fast = run()
    _unblocked.calls = 0
    with monkeypatch.context() as m:
        m.setattr(steps, "triangular_factor", _unblocked)
        slow = run()
    assert _unblocked.calls > 0
    assert (fast.status, fast.messages, fast.iterations, fast.identifiability.rank) == \
        (slow.status, slow.messages, slow.iterations, slow.identifiability.rank)
    assert [(e.name, e.identifiable) for e in fast.estimates] == [(e.name, e.identifiable) for e in slow.estimates]
    for a, b in zip(fast.estimates, slow.estimates):
        assert a.value == pytest.approx(b.value, rel=1e-10, abs=1e-10 * b.std if np.isfinite(b.std) else 1e-15)
        assert a.std == pytest.approx(b.std, rel=1e-10, nan_ok=True)
    d = np.sqrt(np.abs(np.diag(slow.covariance)))
    k = d > 1e-12 * d.max()  # held gauges (elastic): zero variance, round-off of ~1e-48 that either may move
    assert np.all(np.abs(fast.covariance - slow.covariance)[np.ix_(k, k)] <= 1e-10 * np.outer(d[k], d[k]))
    for C in (fast.covariance, slow.covariance):
        assert np.abs(C[~k]).max(initial=0.0) <= 1e-16 * d.max() ** 2
