"""Steps between two rank analyses (``steps.carried_step``, ``iterate._carried``).

A Gauss-Newton step at a linearization without a rank analysis of its own carries the null space from the last
analysis. It must be the step a fresh rank analysis would give (the same identifiable subspace, the same step, the
same predicted cost and convergence decision, to round-off), refuse where the factor has lost an identifiable
direction or gained one, and leave whole calibrations where they were: the same status, rank, iterations and
messages, estimates and standard deviations within round-off."""

from __future__ import annotations

import sys
from types import SimpleNamespace

import numpy as np
import pytest

from kincal.analysis import identify
from kincal.estimation import SolverOptions, calibrate, steps
from test_fixed_overhead_s12_c import cases  # noqa: F401 (the structures: markers, pose, clamp, dual, elastic)

ITERATE = sys.modules["kincal.estimation.iterate"]
RTOL = SolverOptions().rank_rtol
CARRIED = steps.carried_step  # the function itself (the tests below spy on it while a calibration runs)


def _carried_at(monkeypatch, nominal, data, free, noise):
    """Every (linearization, analysis) a calibration carried a step between, with the problem."""
    seen = []

    def spy(lin, ana, rtol):
        seen.append((lin, ana))
        return CARRIED(lin, ana, rtol)

    monkeypatch.setattr(steps, "carried_step", spy)
    res = calibrate(nominal, data, free, noise=noise)
    monkeypatch.undo()
    return seen, res


def _fresh(lin, res):
    """The rank analysis of ``lin`` itself, as the solver's loop makes it."""
    problem = res.problem
    return identify(lin, problem.layout, problem.experiments, rtol=RTOL, report=False)


def _angle(A, B) -> float:
    """Sine of the largest principal angle between the spans of two orthonormal bases."""
    return float(np.linalg.norm(A - B @ (B.T @ A), 2)) if A.size else 0.0


def test_a_carried_step_is_the_step_of_a_fresh_rank_analysis(monkeypatch, cases):
    compared = 0
    for name, nominal, data, free, noise in cases:
        seen, res = _carried_at(monkeypatch, nominal, data, free, noise)
        for lin, ana in seen:
            out = steps.carried_step(lin, ana, RTOL)
            if out is None:
                continue
            V, z, r1sq = out
            fresh = _fresh(lin, res)
            assert fresh.rank == ana.rank and V.shape == fresh.range_space.shape, name
            assert _angle(V, fresh.range_space) < 1e-12, name
            zf, r1f = steps.gauss_newton(lin, fresh.range_space, fresh.factor)
            np.testing.assert_allclose(V @ z, fresh.range_space @ zf, rtol=0,
                                       atol=1e-10 * np.abs(fresh.range_space @ zf).max(), err_msg=name)
            assert r1sq == pytest.approx(r1f, rel=1e-10), name
            assert steps.negligible(lin, V, z, r1sq) == steps.negligible(lin, fresh.range_space, zf, r1f), name
            compared += 1
    assert compared >= 3, "too few carried steps to compare"


def _first(monkeypatch, case):
    name, nominal, data, free, noise = case
    seen, _ = _carried_at(monkeypatch, nominal, data, free, noise)
    lin, ana = seen[0]
    assert steps.carried_step(lin, ana, RTOL) is not None
    return lin, ana


def _like(lin, Rf):
    return SimpleNamespace(Rf=Rf, qtr=lin.qtr, cost2=lin.cost2, p=lin.p)


def test_a_collapsed_direction_is_not_carried(monkeypatch, cases):
    lin, ana = _first(monkeypatch, cases[0])
    V = ana.range_space
    u = V[:, 3]  # an identifiable direction of the analysis, (nearly) lost at the new point
    for keep in (0.0, 1e-6):
        fake = _like(lin, lin.Rf - (1.0 - keep) * np.outer(lin.Rf @ u, u))
        assert steps.carried_step(fake, ana, RTOL) is None, keep
    slight = _like(lin, lin.Rf - 0.5 * np.outer(lin.Rf @ u, u))
    assert steps.carried_step(slight, ana, RTOL) is not None  # half its singular value: still identifiable


def test_a_newly_identifiable_direction_is_not_carried(monkeypatch, cases):
    """A direction the analysed linearization could not see and ``lin`` does (a compliance lifting the gauges it
    couples at its first move from 0): the carried null space would hold it."""
    lin, ana = _first(monkeypatch, cases[0])
    null = ana.null_space[:, 0]
    a = np.random.default_rng(0).standard_normal(lin.p)
    a /= np.linalg.norm(a)
    scale = np.linalg.norm(lin.Rf, 2)
    for size in (1e-3, 1e-7):
        assert steps.carried_step(_like(lin, lin.Rf + size * scale * np.outer(a, null)), ana, RTOL) is None, size
    # round-off is no new direction
    assert steps.carried_step(_like(lin, lin.Rf + 1e-14 * scale * np.outer(a, null)), ana, RTOL) is not None


def test_a_non_finite_factor_is_not_carried(monkeypatch, cases):
    lin, ana = _first(monkeypatch, cases[0])
    Rf = lin.Rf.copy()
    Rf[0, 0] = np.nan
    assert steps.carried_step(_like(lin, Rf), ana, RTOL) is None


def test_calibrations_are_those_of_fresh_rank_analyses(monkeypatch, cases):
    carried = []
    real = ITERATE._carried

    def count(*args):
        out = real(*args)
        carried.append(out is not None)
        return out

    for name, nominal, data, free, noise in cases:
        with monkeypatch.context() as m:
            m.setattr(ITERATE, "_carried", lambda *a: None)
            want = calibrate(nominal, data, free, noise=noise)
        with monkeypatch.context() as m:
            m.setattr(ITERATE, "_carried", count)
            got = calibrate(nominal, data, free, noise=noise)
        assert (got.status, got.iterations, got.identifiability.rank) == \
            (want.status, want.iterations, want.identifiability.rank), name
        assert list(got.messages) == list(want.messages), name
        for a, b in zip(got.estimates, want.estimates):
            assert a.name == b.name and a.value == pytest.approx(b.value, rel=1e-9, abs=1e-13), (name, a.name)
            assert np.isnan(a.std) == np.isnan(b.std), (name, a.name)
            if not np.isnan(b.std):
                assert a.std == pytest.approx(b.std, rel=1e-9), (name, a.name)
    assert any(carried), "no case carried a step: the comparison above compared nothing"


def test_each_linearization_is_analysed_or_carried_and_the_structure_read_once(monkeypatch, cases):
    """The default path: every linearization has a rank analysis or a carried step, never both and never neither
    (finalize reuses the last linearization's analysis), and the solve reads its structure once."""
    made, seen, carried = [], [], []
    structure_of, identify_, carry = ITERATE.Structure.of, ITERATE.identify, ITERATE._carried
    monkeypatch.setattr(ITERATE.Structure, "of", classmethod(lambda cls, *a: made.append(structure_of(*a)) or made[-1]))
    monkeypatch.setattr(ITERATE, "identify", lambda *a, **k: seen.append(k["structure"]) or identify_(*a, **k))
    monkeypatch.setattr(ITERATE, "_carried", lambda *a: (lambda out: carried.append(out is not None) or out)(carry(*a)))
    name, nominal, data, free, noise = cases[0]
    res = calibrate(nominal, data, free, noise=noise)
    analysed_and_carried = [ok for ok in carried if ok]
    assert analysed_and_carried, "no step carried: the count below would not test the carried path"
    assert len(seen) + len(analysed_and_carried) == res.iterations and len(made) == 1
    assert all(s is made[0] for s in seen)


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_recovery_with_carried_steps_over_seeds(monkeypatch, seed):
    """End to end, with noise: a perturbed UR10 seen by a tracker, calibrated with steps carried between rank
    analyses, predicts fresh configurations of the true robot as the calibration without them does, and far
    better than nominal; the estimates agree to round-off."""
    from kincal import robots
    from kincal.estimation import Noise
    from kincal.simulate.generators import generate_markers
    from kincal.simulate.perturb import perturb_robot

    noise = Noise(position=5e-5, joint=0.0)
    ur = robots.load("ur10")
    true = perturb_robot(ur, "fine", rng=np.random.default_rng(seed))
    ds, _, val = generate_markers(true, n=60, rng=seed + 10, noise=noise)
    carried = []
    real = ITERATE._carried
    monkeypatch.setattr(ITERATE, "_carried", lambda *a: (lambda out: carried.append(out is not None) or out)(real(*a)))
    got = calibrate(ur, [ds], "kinematic", noise=noise, validation=list(val.values()))
    monkeypatch.setattr(ITERATE, "_carried", lambda *a: None)
    want = calibrate(ur, [ds], "kinematic", noise=noise, validation=list(val.values()))
    assert any(carried) and got.status == want.status == "converged"
    for a, b in zip(got.estimates, want.estimates):
        assert a.value == pytest.approx(b.value, rel=1e-9, abs=1e-13), a.name
    g, w = got.validation[0], want.validation[0]
    assert g.after.position_rms == pytest.approx(w.after.position_rms, rel=1e-9)
    assert g.after.position_rms < 0.05 * g.before.position_rms  # the calibration recovers the true robot
