"""Session 14 (setup): the outlier screen and the calibration's set-up with fewer calls.

``outliers.any_beyond`` reads the largest scaled chi^2 against the threshold's chi^2 quantile (remembered per dof and
tail probability, ``outliers.chi2_quantile``) and every row's tail probability only near it. Each is held here to
the general path it replaces, on several structures (markers, pose, clamp, dual arm, elastic)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import chdtrc, chdtri

from kincal.estimation import calibrate
from kincal.estimation import outliers as O
from kincal.params import clear_caches
from test_fixed_overhead_s12_c import cases  # noqa: F401 (the structures: markers, pose, clamp, dual, elastic)


def _general_any_beyond(problem, state, threshold):
    """``any_beyond`` of 5329a76: every row's tail probability against the row threshold."""
    return any(bool((p < O.row_threshold(threshold, len(p))).any()) for _, p in O.standardized(problem, state))


@pytest.fixture(scope="module")
def results(cases):
    return [(name, calibrate(robot, sets, free, noise=noise, outliers="keep"))
            for name, robot, sets, free, noise in cases]


def test_the_outlier_screen_is_the_tail_probabilities_verdict(results):
    for name, res in results:
        P, S = res.problem, res.state
        ps = [p for _, p in O.standardized(P, S)]
        edges = sorted({float(q) for p in ps for q in (p.min(), p.max(), np.median(p))})
        near = [e * f for e in edges for f in (1 - 1e-12, 1.0, 1 + 1e-12, 1 - 1e-7, 1 + 1e-7, 0.5, 2.0)]
        thresholds = [t for t in [1e-12, 1e-6, 1e-3, 0.05, 0.5, 0.99] + near if 0 < t < 1]
        verdicts = set()
        for t in thresholds:
            want = _general_any_beyond(P, S, t)
            assert O.any_beyond(P, S, t) is want, (name, t)
            verdicts.add(want)
        # both answers met on each structure whose rows are not all exact fits (p = 1: noise-free data)
        assert verdicts == ({True, False} if min(p.min() for p in ps) < 0.99 else {False}), name


def test_the_outlier_screen_reads_a_nan_row_exactly(results):
    """A nan chi^2 fails the quick comparison: the tail probabilities decide (nan is below no threshold)."""
    class Exp:
        def components(self):
            return (0, 0, 0)

    class Problem:
        experiments = (Exp(),)

    for c in (np.array([1.0, np.nan, 2.0]), np.array([np.nan]), np.array([]), np.array([1.0, 1e9, 2.0])):
        import kincal.estimation.outliers as mod
        original = mod.row_chi2
        try:
            mod.row_chi2 = lambda problem, state: [c]
            want = any(bool((p < O.row_threshold(1e-6, len(p))).any()) for _, p in [O.scaled_chi2(c, 3)])
            assert O.any_beyond(Problem(), None, 1e-6) is want
        finally:
            mod.row_chi2 = original


def test_the_remembered_quantiles_are_chdtris_and_keyed_by_dof_and_probability():
    clear_caches()
    assert not O._QUANTILES
    for k in (1, 2, 3, 6, 9):
        for p in (0.5, 1e-6, 1e-9, 0.25):
            for _ in range(2):  # computed, then remembered
                got = O.chi2_quantile(k, p)
                assert got == chdtri(k, p) and type(got) is type(chdtri(k, p))
    assert len(O._QUANTILES) == 20
    assert O.chi2_quantile(3.0, 0.75) == chdtri(3, 0.75)  # not an int: computed, not remembered
    assert O.chi2_quantile(np.int64(3), 0.75) == chdtri(3, 0.75) and O.chi2_quantile(3, np.float64(0.75)) == chdtri(3, 0.75)
    assert len(O._QUANTILES) == 20
    clear_caches()  # ``params.clear_caches`` empties it too
    assert not O._QUANTILES


def test_scaled_chi2_is_the_earlier_forms_bit_for_bit():
    rng = np.random.default_rng(3)
    for k in (1, 3, 6):
        for n in (0, 1, 2, 7, 50):
            c = rng.chisquare(k, n) * rng.choice([0.1, 1.0, 10.0])
            scale = max(float(np.median(c)) / chdtri(k, 0.5), 1.0) if n else 1.0
            s, p = O.scaled_chi2(c, k)
            assert s.tobytes() == (c / scale).tobytes() and p.tobytes() == chdtrc(k, c / scale).tobytes()
