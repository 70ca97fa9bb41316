"""Session 12 (a2): the factor's covariance without a solve, and the blocks and default pivot order of the free
coordinates remembered per structure.

``Factor.covariance`` (closed form) is the earlier form (a solve with ``M``) to round-off, and whole calibrations
with either agree to 1e-10 relative (the same rank, status, messages, estimates); ``blocks_of`` and ``pivot_order``
remembered are the fresh answers, and another structure or other free coordinates miss; whole solves (markers,
pose, socket, clamp, dual arm, elastic) with the memory swapped for the fresh computation give the same Result
bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from kincal import robots
from kincal.analysis import factor, naming, symmetries
from kincal.estimation.gauge import priority
from kincal.params import build_layout
from kincal.params.layout import Layout
from test_fixed_overhead_s12_a import _cases, _first_linearization, _priority_before
from test_structure_cache import NOISE, _same, ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)


def _fresh(layout, idx):
    """``blocks_of`` and the default pivot order as they were computed before this session."""
    stops = np.array([b.stop for b in layout.blocks])
    blk = [layout.blocks[k] for k in np.searchsorted(stops, np.asarray(idx, dtype=int), side="right").tolist()]
    ranks = [b.kind.rank for b in blk]
    return blk, sorted(range(len(blk)), key=ranks.__getitem__)


def test_blocks_and_pivot_order_remembered_are_the_fresh_ones_and_another_structure_misses():
    symmetries.clear_structure_cache()
    frida, ur10 = robots.load("frida"), robots.load("ur10")
    from kincal.params import State

    layouts = [build_layout(State.from_robot(m), level) for m in (frida, ur10) for level in ("offsets", "kinematic")]
    for layout in layouts:
        free = np.flatnonzero(layout.free)
        for idx in (free, free[::2], free[:3], free[::-1], np.zeros(0, int)):
            blk, order = _fresh(layout, idx)
            for _ in range(2):  # fresh, then remembered
                got_blk, got_order = naming.blocks_of(layout, idx), naming.pivot_order(layout, idx)
                assert got_blk == blk and all(a is b for a, b in zip(got_blk, blk))
                assert got_order == order and type(got_order) is list
                got_blk.append(None)  # the caller's copy: the remembered answer is untouched
                got_order.append(-1)
    assert naming._BLOCKS_OF
    symmetries.clear_structure_cache()  # the bench's forget_structures empties it
    assert not naming._BLOCKS_OF


def test_blocks_of_an_unshared_blocks_list_are_not_remembered():
    from kincal.params import State

    layout = build_layout(State.from_robot(robots.load("ur10")), "kinematic")
    listed = Layout(layout.names, layout.units, list(layout.blocks), layout.free, layout.prior_mean,
                    layout.prior_sigma, layout.twist_joint)
    symmetries.clear_structure_cache()
    free = np.flatnonzero(layout.free)
    assert naming.blocks_of(listed, free) == _fresh(layout, free)[0]
    assert not naming._BLOCKS_OF


def test_priority_remembered_is_its_earlier_form(ur10_sets):
    nominal, markers, pose = ur10_sets
    for ds in (markers, pose):
        problem, _ = _first_linearization(nominal, ds, "kinematic", NOISE)
        for _ in range(2):
            assert priority(problem, "min-change") == _priority_before(problem)


# ------------------------------------------------------------------------------------------ whole solves


def _covariance_before(self, V, sigma2=1.0):
    r = self.rank
    M = self.S[:r, None] * (self.Vt[:r] @ (self.c[:, None] * V))
    Z = np.linalg.solve(M.T, V.T)  # (V M^-1)^T
    return sigma2 * (Z.T @ Z)


@pytest.mark.parametrize("spread", [0, 1, 2])  # columns graded over 1e-4 (``_deficient``) times 10^-spread
def test_covariance_without_a_solve_is_the_one_with_to_round_off(spread):
    from test_fixed_overhead_session10 import _deficient
    from kincal.analysis.identifiability import analyse

    rng = np.random.default_rng(spread)
    for low in (None, 1e-3):
        for _ in range(10):
            R = _deficient(rng, m=60, p=20, k=5, low=low) * np.logspace(0, -spread, 20)
            ana = analyse(R, [f"x{i}" for i in range(20)], name=False)
            assert ana.factor is not None
            V = ana.range_space
            got, want = ana.factor.covariance(V, 2.5), _covariance_before(ana.factor, V, 2.5)
            d = np.sqrt(np.diag(want))
            assert np.abs(got - want).max() <= 1e-11 * max(1.0, 10.0 ** spread) * np.outer(d, d).max()
            assert np.allclose(np.diag(got), np.diag(want), rtol=1e-9, atol=0)


@pytest.mark.parametrize("case", ["markers", "pose"])
def test_calibrations_with_the_covariance_without_a_solve_agree_to_1e_10(monkeypatch, ur10_sets, case):
    run = _cases(ur10_sets)[case]
    fast = run()
    with monkeypatch.context() as m:
        m.setattr(factor.Factor, "covariance", _covariance_before)
        slow = run()
    assert fast.identifiability.factor is not None  # the covariance came from the factor
    assert (fast.status, fast.messages, fast.iterations, fast.identifiability.rank) == \
        (slow.status, slow.messages, slow.iterations, slow.identifiability.rank)
    assert [(e.name, e.value, e.identifiable) for e in fast.estimates] == \
        [(e.name, e.value, e.identifiable) for e in slow.estimates]
    for a, b in zip(fast.estimates, slow.estimates):
        assert a.std == pytest.approx(b.std, rel=1e-10, nan_ok=True)
    d = np.sqrt(np.abs(np.diag(slow.covariance)))
    assert np.all(np.abs(fast.covariance - slow.covariance) <= 1e-10 * np.outer(d, d))


def _earlier_forms(m):
    """The memory of this branch swapped for the fresh computation (the covariance: above)."""
    m.setattr(naming, "remember", lambda cache, key, value, limit: value)  # nothing remembered: always fresh
    naming.clear_block_cache()


def _elastic():
    """An elastic solve that holds the rigid model's gauges (``identify``'s ``hold``)."""
    from test_slow_path import _sagging_ur10
    from kincal.estimation import calibrate
    from kincal.noise import Noise
    from kincal.simulate.generators import generate_markers

    nominal, true, _ = _sagging_ur10()
    ds = generate_markers(true, n=20, rng=1, markers=3, noise=Noise(position=2e-5), known_tracker=True,
                          known_markers=True)[0]
    return calibrate(nominal, [ds], ["kinematic", "elastic"], outliers="keep")


@pytest.mark.parametrize("case", ["markers", "pose", "socket", "clamp", "dual", "elastic"])
def test_whole_solves_are_those_of_the_earlier_forms(monkeypatch, ur10_sets, case):
    run = _elastic if case == "elastic" else _cases(ur10_sets)[case]
    results = []
    for swapped in (False, True, False):  # the fast paths, the earlier forms, the fast paths again
        with monkeypatch.context() as m:
            if swapped:
                _earlier_forms(m)
            results.append(run())
    assert case != "elastic" or results[0].held is not None
    _same(results[0], results[1])
    _same(results[2], results[1])
