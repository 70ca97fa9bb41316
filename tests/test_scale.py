"""Scale (issue #15): a large problem is evaluated in blocks of configurations (``kincal.estimation.blocks``) and
gives the stacked solve's answer: estimates to 1e-9 relative, the same rank, null space and outlier verdicts,
with working memory that does not grow with the number of configurations. A tiny block size is forced so the
block path runs on a small Frida dual problem."""

import tracemalloc
from dataclasses import fields, replace

import numpy as np
import pytest

from kincal.analysis import identify
from kincal.estimation import blocks, calibrate, memory, steps
from kincal.estimation.crossval import held_out_prediction
from kincal.estimation.gauge import gauge_basis, priority
from kincal.estimation.problem import Problem
from kincal.estimation.outliers import REFERENCE_ROWS, beyond, row_threshold
from kincal.io.datasets import load_scenario, scenario_path
from kincal.simulate.scenario import build_scenario, run

FREE = ["kinematic", "clamp"]
TINY = 600_000  # bytes of working memory per block: about 10 Frida dual configurations (by blocks from 90)


def frida(n: int, seed: int = 0):
    """The frida_dual_bracket scenario with ``n`` configurations and the clamp unknown: (nominal robot, data)."""
    scenario = build_scenario(load_scenario(scenario_path("frida_dual_bracket")))
    scenario = replace(scenario, options=dict(scenario.options, n=n, known_clamp=False), n_validation=1, seed=seed)
    return scenario.robot, run(scenario)[1]


@pytest.fixture(scope="module")
def small():
    return frida(120)


def solve_both(robot, ds, monkeypatch, **kw):
    stacked = calibrate(robot, [ds], FREE, **kw)
    with monkeypatch.context() as m:
        m.setattr(memory, "CHUNK_BYTES", TINY)
        blocked = calibrate(robot, [ds], FREE, **kw)
    return stacked, blocked


def values(result) -> np.ndarray:
    return np.array([e.value for e in result.estimates])


def test_the_block_path_gives_the_stacked_solve(small, monkeypatch):
    stacked, blocked = solve_both(*small, monkeypatch)
    assert not stacked.problem.blocked and blocked.problem.blocked and len(blocked.problem.parts()) >= 5
    np.testing.assert_allclose(values(blocked), values(stacked), rtol=1e-9, atol=0)
    a, b = stacked.identifiability, blocked.identifiability
    assert a.rank == b.rank == 55 and len(a.names) == len(b.names) == 88
    assert [d.pivot for d in a.directions] == [d.pivot for d in b.directions]
    assert [d.words for d in a.directions] == [d.words for d in b.directions]
    # the same null space: each basis spans the other's
    assert np.allclose(a.null_space @ (a.null_space.T @ b.null_space), b.null_space, atol=1e-8)
    assert stacked.status == blocked.status and stacked.iterations == blocked.iterations
    assert np.isclose(stacked.sigma2, blocked.sigma2, rtol=1e-9)
    np.testing.assert_allclose(blocked.covariance, stacked.covariance, rtol=1e-6,
                               atol=1e-9 * np.max(np.abs(stacked.covariance)))
    for x, y in zip(stacked.after, blocked.after):
        assert np.isclose(x.chi2, y.chi2, rtol=1e-9) and x.position_rms == pytest.approx(y.position_rms, rel=1e-9)


def test_the_blocked_jacobian_reads_as_the_stacked_one(small, monkeypatch):
    stacked, blocked = solve_both(*small, monkeypatch)
    J = blocked.linearization.J
    assert isinstance(J, blocks.BlockJacobian) and J.shape == stacked.linearization.J.shape
    X = np.random.default_rng(1).normal(size=(J.shape[1], 3))
    # the two solves end at states 1e-12 apart: the Jacobians agree to that
    scale = np.max(np.abs(stacked.linearization.J))
    np.testing.assert_allclose(J @ X, stacked.linearization.J @ X, atol=1e-7 * scale * np.abs(X).sum(0).max())
    np.testing.assert_allclose(np.asarray(J), stacked.linearization.J, atol=1e-7 * scale)
    m = J.shape[0]
    for rows in (slice(0, 5), slice(37, 200), slice(m - 61, None), slice(None), slice(m, None), slice(9, 9)):
        np.testing.assert_allclose(J[rows], stacked.linearization.J[rows], atol=1e-7 * scale)
        assert J[rows].shape == stacked.linearization.J[rows].shape
    # the triangular factors have the same Gram matrix
    Ra, Rb = stacked.linearization.Rf, blocked.linearization.Rf
    np.testing.assert_allclose(Rb.T @ Rb, Ra.T @ Ra, atol=1e-7 * np.max(np.abs(Ra.T @ Ra)))


def test_outlier_verdicts_are_the_same_by_blocks(small, monkeypatch):
    robot, ds = small
    q = {a: v.copy() for a, v in ds.q.items()}
    arm = sorted(q)[0]
    bad = [7, 50, 101]
    q[arm][bad, 1] += 0.02  # a joint reading 1.1 deg off: far beyond 0.005 deg of encoder noise
    stacked, blocked = solve_both(robot, replace(ds, q=q), monkeypatch)
    assert sorted(o.sample for o in stacked.outliers) == bad
    assert [(o.experiment, o.sample) for o in blocked.outliers] == [(o.experiment, o.sample) for o in stacked.outliers]
    np.testing.assert_allclose([o.standardized for o in blocked.outliers], [o.standardized for o in stacked.outliers],
                               rtol=1e-6)
    np.testing.assert_allclose(values(blocked), values(stacked), rtol=1e-9, atol=0)


def _peak(robot, ds) -> int:
    tracemalloc.start()
    try:
        calibrate(robot, [ds], FREE, outliers="keep")
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_block_memory_does_not_grow_with_the_jacobian(monkeypatch):
    """Peak traced memory at N and 4N configurations: by blocks it grows by less than one Jacobian row per
    residual row (what stays is residuals, whiteners and encoder Jacobians), stacked by several copies."""
    robot, ds = frida(400, seed=2)
    one = ds.subset(slice(0, 100))
    rows, row_bytes = 3 * 100 * 6, 8 * 88  # the residual rows added from N to 4N; one whitened Jacobian row
    stacked = (_peak(robot, ds) - _peak(robot, one)) / rows
    monkeypatch.setattr(memory, "CHUNK_BYTES", TINY)
    blocked = (_peak(robot, ds) - _peak(robot, one)) / rows
    assert stacked > 5 * row_bytes
    assert blocked < row_bytes
    assert blocked < memory.KEPT_PER_ROW * 8


def test_the_memory_estimate_of_a_blocked_solve_holds_one_block():
    free = 88
    block = memory.chunk_rows(free)
    assert memory.need_bytes(block, free) == memory.solve_bytes(block, free)
    assert not memory.by_blocks(memory.BLOCKS * block, free) and memory.by_blocks((memory.BLOCKS + 1) * block, free)
    big = 100 * block
    assert memory.need_bytes(big, free) == memory.solve_bytes(block, free) + 8 * big * memory.KEPT_PER_ROW
    assert memory.need_bytes(big, free) < memory.solve_bytes(big, free) / 5


def test_the_outlier_threshold_is_per_data_set_beyond_the_reference_size():
    assert row_threshold(1e-6, 10) == row_threshold(1e-6, REFERENCE_ROWS) == 1e-6
    assert row_threshold(1e-6, 100 * REFERENCE_ROWS) == pytest.approx(1e-8)
    # clean chi^2 rows: at a million rows a fixed 1e-6 flags about one; the rule flags none
    rng = np.random.default_rng(0)
    p = rng.uniform(size=1_000_000)  # tail probabilities of clean rows are uniform
    assert len(beyond(p, 1e-6)) == 0
    p[[5, 17]] = 1e-12  # gross outliers are still found
    assert list(beyond(p, 1e-6)) == [5, 17]


@pytest.mark.parametrize("loss", ["linear", "cauchy"])
def test_the_blocked_inner_solve_reaches_the_minimum_least_squares_finds(small, monkeypatch, loss):
    """From the start (far from the optimum) in the identifiable subspace: least_squares over the residuals and
    ``J V`` evaluated by blocks reaches the point it reaches on the stacked problem: the same cost, and steps
    whose difference moves the whitened residuals by a negligible fraction of one noise sigma. (Both stop at
    least_squares' own tolerances, so their steps agree to about 1e-4 relative along the least determined
    directions, not to round-off: the row order differs.)"""
    robot, ds = small
    found = {}
    for chunk in (memory.CHUNK_BYTES, TINY):
        monkeypatch.setattr(memory, "CHUNK_BYTES", chunk)
        problem = Problem.build(robot, [ds], FREE)
        lin = steps.linearize(problem, problem.start, None, True)
        order = priority(problem, "min-change")
        ana = identify(lin, problem.layout, problem.experiments, rtol=1e-9, priority=order)
        V = gauge_basis(lin.Rf, ana, "min-change", order)
        z, cost, _, _ = steps.inner_solve(problem, problem.start, lin, V, loss, 3.0)
        found[problem.blocked] = (V @ z, cost, lin.Rf)
    (d0, c0, R), (d1, c1, _) = found[False], found[True]
    assert c1 == pytest.approx(c0, rel=1e-9)
    moved = np.linalg.norm(R @ (d1 - d0))  # whitened units: one is the noise sigma of one residual
    assert moved < 0.1 and moved < 1e-5 * np.linalg.norm(R @ d0)
    if loss == "cauchy":  # TRF's robust solve stops where the cost changes by less than its ftol (1e-10)
        np.testing.assert_allclose(d1, d0, rtol=0, atol=1e-4 * np.max(np.abs(d0)))


def test_held_out_predictions_by_blocks_are_the_whole_sets(small, monkeypatch):
    robot, ds = small
    res = calibrate(robot, [ds.subset(slice(0, 80))], FREE)
    held = [ds.subset(slice(80, 120))]
    whole = held_out_prediction(res, held)
    monkeypatch.setattr(memory, "CHUNK_BYTES", TINY // 2)  # blocks of 5 configurations
    by_blocks = held_out_prediction(res, held)
    for a, b in zip(whole, by_blocks):
        for f in fields(a):
            np.testing.assert_allclose(getattr(b, f.name), getattr(a, f.name), rtol=1e-12)
