"""Session 11 (e): per-linearization costs, bit for bit.

``problem.triangular_factor`` writes its zeros below the diagonal once (``np.triu``'s numbers, C-ordered);
``Problem.linearize`` finds the blocks its columns touch by one search of the blocks' starts (the per-block scan's
set); ``Linearization.colnorm`` and ``unit_columns`` take column norms without ``numpy.linalg.norm``'s dispatch
(its arithmetic)."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.analysis.linearization import unit_columns
from kincal.estimation import Problem
from kincal.estimation import problem as P
from kincal.estimation import steps
from kincal.noise import Noise
from test_structure_cache import ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)


@pytest.mark.parametrize("shape", [(150, 45), (45, 45), (20, 45), (1, 3), (7, 1)])
def test_triangular_factor_is_numpys_r_bit_for_bit(shape):
    rng = np.random.default_rng(sum(shape))
    A = rng.normal(size=shape) * np.exp(rng.normal(size=shape[1]) * 5)
    A[:, 0] *= -1.0  # negative entries below the diagonal: the zeros there are +0.0, as np.triu's
    expected = np.linalg.qr(A, mode="r")
    R = P.triangular_factor([A[:, :-1], A[:, -1]]) if shape[1] > 1 else P.triangular_factor([A])
    assert R.flags.c_contiguous and R.shape == expected.shape
    assert R.tobytes() == np.ascontiguousarray(expected).tobytes()
    assert not np.signbit(R[np.tril_indices(R.shape[0], -1, R.shape[1])]).any()


def _scanned(layout, cols):
    return frozenset(b.name for b in layout.blocks if np.any((cols >= b.start) & (cols < b.stop)))


def test_wanted_blocks_by_search_are_the_scans(ur10_sets):
    nominal, markers, _ = ur10_sets
    problem = Problem.build(nominal, [markers], "kinematic", noise=Noise(position=5e-5, joint=0))
    layout, rng = problem.layout, np.random.default_rng(3)
    picks = [problem.free_idx, np.arange(layout.size), np.zeros(0, int), np.array([layout.size - 1, 0])]
    picks += [rng.choice(layout.size, k, replace=False) for k in (1, 2, 5, 17)]
    picks += [np.array([b.start]) for b in layout.blocks] + [np.array([b.stop - 1]) for b in layout.blocks]
    for cols in picks:
        assert P._blocks_of(layout, cols) == _scanned(layout, cols), cols
    assert P._blocks_of(layout, problem.free_idx) != P._blocks_of(layout, np.array([0]))  # the test can fail


def test_column_norms_are_numpys(ur10_sets):
    nominal, markers, _ = ur10_sets
    problem = Problem.build(nominal, [markers], "kinematic", noise=Noise(position=5e-5, joint=0))
    lin = steps.linearize(problem, problem.start, None, True)
    assert lin.colnorm.tobytes() == np.linalg.norm(lin.Rf, axis=0).tobytes()
    J = lin.Rf.copy()
    J[:, 3] = 0.0  # a zero column: scale 1, left exactly zero
    Js, c = unit_columns(J)
    plain = np.linalg.norm(J, axis=0)
    assert c.tobytes() == np.where(plain == 0, 1.0, plain).tobytes()
    assert Js.tobytes() == np.where(plain == 0, 0.0, J / np.where(plain == 0, 1.0, plain)).tobytes()
