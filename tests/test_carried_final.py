"""The result's rank analysis carried from an earlier one (``analysis.carried``, ``iterate._final``).

Where the step carried to the last linearization is negligible, the result's rank, null space, identifiable
coordinates and covariance come from the carried factor. They must be those of a fresh rank analysis of that
linearization (to round-off), whole calibrations must not change (status, iterations, rank, messages, estimates
and standard deviations), and the carried analysis must refuse where it cannot prove itself: a weak direction, a
scale test, a lifted symmetry."""

from __future__ import annotations

import pickle
import sys

import numpy as np
import pytest

from kincal.analysis import covariance, identify
from kincal.analysis.carried import CarriedAnalysis, carried_analysis
from kincal.estimation import SolverOptions, calibrate, steps
from test_carried_step import _angle
from test_fixed_overhead_s11_b import _pickled
from test_fixed_overhead_s12_c import cases  # noqa: F401 (the structures: markers, pose, clamp, dual, elastic)

ITERATE = sys.modules["kincal.estimation.iterate"]
RTOL = SolverOptions().rank_rtol
FINAL = ITERATE._final


def _finals(monkeypatch, nominal, data, free, noise):
    """Every (linearization, earlier analysis, carrying, outcome) the loop tried to carry the result's analysis
    from, and the result."""
    seen = []

    def spy(problem, options, lin, ana, carrying, structure):
        out = FINAL(problem, options, lin, ana, carrying, structure)
        seen.append((lin, ana, carrying, out, problem))
        return out

    with monkeypatch.context() as m:
        m.setattr(ITERATE, "_final", spy)
        res = calibrate(nominal, data, free, noise=noise)
    return seen, res


def test_a_carried_analysis_is_that_of_a_fresh_rank_analysis(monkeypatch, cases):
    compared = 0
    for name, nominal, data, free, noise in cases:
        seen, res = _finals(monkeypatch, nominal, data, free, noise)
        for lin, ana, carrying, out, problem in seen:
            if out is None:
                continue
            fresh = identify(lin, problem.layout, problem.experiments, rtol=RTOL, report=False)
            assert isinstance(out, CarriedAnalysis) and out.rank == fresh.rank and not fresh.weak, name
            assert out.names == fresh.names and (out.identifiable == fresh.identifiable).all(), name
            assert _angle(out.null_space, fresh.null_space) < 1e-12, name
            assert _angle(out.range_space, fresh.range_space) < 1e-12, name
            want = covariance(lin.Rf, fresh.range_space)
            got = out.factor.covariance(out.range_space)
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max(), err_msg=name)
            assert np.allclose(np.diag(got), np.diag(want), rtol=1e-9, atol=0), name
            # the convergence decision made without the step is the step's (carried or fresh)
            step = carrying.step(lin)
            assert carrying.negligible(lin) == steps.negligible(lin, *step), name
            zf, r1f = steps.gauss_newton(lin, fresh.range_space, fresh.factor)
            assert carrying.negligible(lin) == steps.negligible(lin, fresh.range_space, zf, r1f), name
            compared += 1
    assert compared >= 2, "too few carried final analyses to compare"


def test_calibrations_with_a_carried_final_analysis_are_unchanged(monkeypatch, cases):
    carried = []
    for name, nominal, data, free, noise in cases:
        got = calibrate(nominal, data, free, noise=noise)  # carried where it can be
        carried.append(isinstance(got.__dict__["identifiability"].analysis, CarriedAnalysis))
        monkeypatch.setattr(ITERATE, "_final", lambda *a: None)
        want = calibrate(nominal, data, free, noise=noise)
        monkeypatch.undo()
        assert (got.status, got.iterations, got.evaluations, got.identifiability.rank) == \
            (want.status, want.iterations, want.evaluations, want.identifiability.rank), name
        assert list(got.messages) == list(want.messages), name
        assert got.identifiability.unidentifiable_names() == want.identifiability.unidentifiable_names(), name
        assert got.sigma2 == pytest.approx(want.sigma2, rel=1e-9), name
        for a, b in zip(got.estimates, want.estimates):
            assert a.name == b.name and a.value == b.value, (name, a.name)  # the same state: the same values
            assert np.isnan(a.std) == np.isnan(b.std), (name, a.name)
            if not np.isnan(b.std):
                assert a.std == pytest.approx(b.std, rel=1e-9), (name, a.name)
        np.testing.assert_allclose(got.covariance, want.covariance, rtol=0,
                                   atol=1e-9 * np.abs(want.covariance).max(), err_msg=name)
    assert any(carried), "no case carried its final analysis: the comparison above compared nothing"
    assert not all(carried), "every case carried: the refusals below are not exercised by a whole calibration"


def test_a_weak_direction_is_not_carried(monkeypatch, cases):
    """The elastic case has a direction at 1e-3 of the largest singular value: the bound cannot exclude a weak
    direction there, so the result's analysis is made afresh. Shrinking a carried case's smallest identifiable
    direction a hundredfold (in column-scaled coordinates; still carried as a step) makes it weak, and the
    analysis is refused; shrinking it by a tenth is not."""
    by_name = {c[0]: c for c in cases}
    seen, _ = _finals(monkeypatch, *by_name["elastic"][1:])
    assert seen and all(out is None for *_, out, _ in seen)
    seen, _ = _finals(monkeypatch, *by_name["markers"][1:])
    lin, ana, carrying, out, problem = seen[-1]
    assert out is not None
    fresh = identify(lin, problem.layout, problem.experiments, rtol=RTOL, report=False)
    u, c = fresh.factor.Vt[fresh.rank - 1], fresh.factor.c  # the smallest identifiable direction (scaled)
    Rs = lin.Rf / c
    for shrink, kept in ((1e-2, False), (0.9, True)):
        fake = _with(lin, (Rs - (1 - shrink) * np.outer(Rs @ u, u)) * c)
        carried = steps.carrying(fake, fresh, RTOL)  # from the analysis of lin itself
        assert carried is not None, shrink  # a step would still be carried
        null, V = carried.subspaces(fake)
        got = carried_analysis(fake, problem.layout, problem.experiments, RTOL, fresh.names, null, V, carried.VP,
                               carried.inverse)
        weak = identify(fake, problem.layout, problem.experiments, rtol=RTOL, report=False).weak
        assert (got is not None) == kept and bool(weak) == (not kept), shrink


def test_a_scale_test_or_a_lifted_symmetry_is_not_carried(monkeypatch, cases):
    by_name = {c[0]: c for c in cases}
    seen, _ = _finals(monkeypatch, *by_name["markers"][1:])
    lin, ana, carrying, out, problem = seen[-1]
    null, V = carrying.subspaces(lin)
    args = (problem.layout, problem.experiments, RTOL, ana.names, null, V, carrying.VP, carrying.inverse)
    assert carried_analysis(lin, *args) is not None
    assert carried_analysis(_with(lin, lin.Rf, every=True), *args) is None
    # a null direction the factor no longer annihilates (a gauge lifted by the residuals): the gap test refuses
    n = null[:, 0]
    u = np.linalg.qr(lin.Rf @ V)[0][:, 0]
    lifted = lin.Rf + 1e-9 * np.linalg.norm(lin.Rf, 2) * np.outer(u, n)
    assert carried_analysis(_with(lin, lifted), *args) is None


def _with(lin, Rf, every: bool = False):
    """``lin`` with its factor replaced (a copy: its column norms follow); ``every``: as if it carried the scale
    test's columns (``fixed`` given)."""
    from dataclasses import replace
    R = lin.R.copy()
    R[: Rf.shape[0], : Rf.shape[1]] = Rf
    return replace(lin, R=R, fixed=np.zeros(0, int) if every else lin.fixed)


def test_a_result_with_a_carried_analysis_pickles_and_reports(monkeypatch, cases):
    name, nominal, data, free, noise = cases[0]
    seen, res = _finals(monkeypatch, nominal, data, free, noise)
    assert any(out is not None for *_, out, _ in seen)
    back = pickle.loads(_pickled(res))  # the report not yet named: it holds the carried analysis
    assert list(back.messages) == list(res.messages)
    assert back.identifiability.rank == res.identifiability.rank
    assert [d.words for d in back.identifiability.directions] == [d.words for d in res.identifiability.directions]
    assert len(back.identifiability.singular_values) == len(res.estimates)
