"""Session 10's cuts of a small calibration's fixed cost (docs/performance.md "Fixed overhead: session 10").

The rank analysis' own SVD reused (``kincal.analysis.factor``): the Gauss-Newton step and the covariance on the
identifiable subspace from it equal the least-squares solve and the SVD they replace to round-off, it is offered
only where the null space is that SVD's own, and whole calibrations give the same results with it as without it.
The smaller cuts give what they replace bit for bit: ``linalg.norm``, block columns scattered by slices, one
batched exponential per retraction."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.analysis import analyse, covariance, identify, scatter_columns
from kincal.analysis import factor as factor_module
from kincal.analysis.linalg import lstsq, norm
from kincal.estimation import Problem, calibrate, steps
from kincal.estimation.gauge import priority
from kincal.estimation.iterate import scale_test_needed
from kincal.params import TWISTS, retract
from kincal.params.values import retract_twists
from test_structure_cache import NOISE, ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)


def _deficient(rng, m=40, p=9, k=3, low=None):
    """The triangular factor of a whitened-Jacobian-like (m, p) matrix of graded columns with k exact null
    directions (and, with ``low``, one more direction at that relative singular value)."""
    A = rng.standard_normal((m, p - k)) @ rng.standard_normal((p - k, p))
    if low is not None:
        U, S, Vt = np.linalg.svd(A, full_matrices=False)
        S[p - k - 1] = low * S[0]
        A = (U * S) @ Vt
    A *= np.logspace(0, -4, p)  # columns of different sizes (units)
    return np.linalg.qr(A, mode="r")


def test_step_and_covariance_from_the_factor_equal_the_least_squares_and_svd_they_replace():
    rng = np.random.default_rng(3)
    for _ in range(20):
        R = _deficient(rng)
        ana = analyse(R, [f"x{i}" for i in range(R.shape[1])], name=False)
        assert ana.rank == 6 and ana.factor is not None
        V, b = ana.range_space, rng.standard_normal(R.shape[0])
        want = lstsq(R @ V, b)
        np.testing.assert_allclose(V.T @ ana.factor.step(b), want, rtol=1e-9, atol=1e-12 * np.abs(want).max())
        cov = covariance(R, V, 2.5)
        np.testing.assert_allclose(ana.factor.covariance(V, 2.5), cov, rtol=1e-9, atol=1e-12 * np.abs(cov).max())


def test_no_factor_where_the_null_space_is_not_the_svds_own():
    rng = np.random.default_rng(4)
    names = [f"x{i}" for i in range(9)]
    R = _deficient(rng, low=1e-10)  # a direction just under the rank threshold: not negligible against the rest
    assert analyse(R, names, name=False).factor is None
    R = _deficient(rng)
    ana = analyse(R, names, name=False)
    outside = ana.range_space[:, 0]  # a symmetry held although the data determine it: the null space grows
    held = analyse(R, names, held=[outside], name=False)
    assert held.rank == ana.rank - 1 and held.factor is None
    tall = rng.standard_normal((40, 9))  # more than twice as many rows as columns: the SVD is of its R
    assert analyse(tall, names, name=False).factor is None


def test_solver_steps_use_the_factor_and_agree_with_least_squares(ur10_sets):
    nominal, markers, _ = ur10_sets
    problem = Problem.build(nominal, [markers], "kinematic", noise=NOISE)
    lin = steps.linearize(problem, problem.start, None, scale_test_needed(problem))
    ana = identify(lin, problem.layout, problem.experiments, priority=priority(problem, "min-change"), report=False)
    assert ana.deficiency > 0 and ana.factor is not None
    V = ana.range_space
    z, r1sq = steps.gauss_newton(lin, V, ana.factor)
    z0, r1sq0 = steps.gauss_newton(lin, V)
    np.testing.assert_allclose(z, z0, rtol=1e-9, atol=1e-12 * np.abs(z0).max())
    assert r1sq == pytest.approx(r1sq0, rel=1e-9)


@pytest.mark.parametrize("data", [0, 1])
def test_calibrations_with_and_without_the_factor_agree(ur10_sets, monkeypatch, data):
    nominal, *sets = ur10_sets
    run = lambda: calibrate(nominal, [sets[data]], "kinematic", noise=NOISE)  # noqa: E731
    fast = run()
    assert fast.identifiability.factor is not None
    monkeypatch.setattr(factor_module.Factor, "of", classmethod(lambda cls, *args: None))
    slow = run()
    assert slow.identifiability.factor is None
    assert (fast.status, fast.iterations, fast.identifiability.rank) == \
        (slow.status, slow.iterations, slow.identifiability.rank)
    # the same messages naming the same directions with the same partners; the order of partners of equal weight
    # (+1, +1), and so which of them a message lists before "and N more", round-off decides
    assert [m.split(" it trades off")[0] for m in fast.messages] == [m.split(" it trades off")[0] for m in slow.messages]
    assert [(d.pivot, sorted((n, f"{c:.7g}") for n, c in d.partners)) for d in fast.identifiability.directions] == \
        [(d.pivot, sorted((n, f"{c:.7g}") for n, c in d.partners)) for d in slow.identifiability.directions]
    for a, b in zip(fast.estimates, slow.estimates):
        assert (a.name, a.identifiable) == (b.name, b.identifiable)
        assert a.value == pytest.approx(b.value, rel=1e-9, abs=1e-15)
        assert a.std == pytest.approx(b.std, rel=1e-9, nan_ok=True)
    np.testing.assert_allclose(fast.covariance, slow.covariance, rtol=1e-9, atol=1e-12 * np.abs(slow.covariance).max())



def test_norm_is_numpys_bit_for_bit():
    rng = np.random.default_rng(5)
    for shape in ((1,), (7,), (45,), (300,), (6, 5)):
        x = rng.standard_normal(shape) * 10.0 ** rng.integers(-12, 12)
        assert norm(x) == np.linalg.norm(x)
        assert norm(x[..., ::2]) == np.linalg.norm(x[..., ::2])  # a strided view
    assert norm(np.zeros(3)) == 0.0 and norm(np.zeros(0)) == 0.0


def test_scattered_columns_equal_the_fancy_indexed_ones(ur10_sets):
    nominal, markers, _ = ur10_sets
    problem = Problem.build(nominal, [markers], "kinematic", noise=NOISE)
    layout = problem.layout
    blocks = {b.name: np.random.default_rng(k).standard_normal((4, 3, b.stop - b.start))
              for k, b in enumerate(layout.blocks)}
    rng = np.random.default_rng(6)
    for cols in (problem.free_idx, np.arange(layout.size), np.sort(rng.choice(layout.size, 20, replace=False)),
                 rng.permutation(layout.size)[:30], np.array([3])):
        want = np.zeros((4, 3, len(cols)))
        for j, i in enumerate(cols):
            b = layout.block_at(int(i))
            want[..., j] = blocks[b.name][..., i - b.start]
        assert np.array_equal(scatter_columns(blocks, layout, cols, (4, 3)), want)


@pytest.mark.parametrize("tangents", [True, False])
def test_one_batched_exponential_retracts_as_block_by_block(ur10_sets, tangents):
    """``params.retract`` takes the joint screws' and the poses' exponentials in one batch: the same values, bit for
    bit, as each block retracted on its own (``kind.retract``)."""
    nominal, markers, _ = ur10_sets
    res = calibrate(nominal, [markers], "kinematic", noise=NOISE)
    state, layout, free = res.state, res.layout, res.problem.free_idx
    rng = np.random.default_rng(2)
    for scale in (1e-8, 1e-3, 0.3):
        delta = np.zeros(layout.size)
        delta[free] = rng.standard_normal(len(free)) * scale
        got = retract(state, layout, delta, tangents)
        arms, extras = dict(state.arms), dict(state.extras)
        for b in layout.blocks:
            d = delta[b.slice]
            if not d.any():
                continue
            if b.kind is TWISTS:
                arms[b.arm] = retract_twists(arms[b.arm], d, tangents)
            elif b.arm is not None:
                arms[b.arm] = b.kind.retract(arms[b.arm], d)
            else:
                extras[b.name] = b.kind.retract(extras[b.name], d)
        for name, a in arms.items():
            g = got.arms[name]
            for f in ("screws", "offsets", "home", "base", "tool", "compliance"):
                assert np.array_equal(getattr(g, f), getattr(a, f)), f
            if tangents:
                assert all(np.array_equal(x, y) for x, y in zip(g.bases, a.bases))
                assert all(np.array_equal(x, y) for x, y in zip(g.generators, a.generators))
            else:
                assert g.bases is None and g.generators is None
        for name, v in extras.items():
            assert np.array_equal(np.asarray(got.extras[name]), np.asarray(v)), name
