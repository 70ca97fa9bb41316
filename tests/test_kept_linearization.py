"""What a solve keeps of its linearizations for its own report, and what a study remembers per structure: the
collapse test reads the joint sensitivity off the kept offset columns bit for bit as a fresh evaluation gives
it, never off another state's or another problem's; a study's remembered quantities and true tool positions
give every structure its own rows."""

from __future__ import annotations

import importlib
from dataclasses import replace

import numpy as np
import pytest

from kincal.estimation import calibrate
from kincal.simulate import generate_markers, perturb_robot
from kincal.workflow import study as S
from test_structure_cache import NOISE, ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)

F = importlib.import_module("kincal.estimation.finalize")  # the module, not the function of that name


@pytest.mark.parametrize("kind,free", [("markers", "kinematic"), ("markers", "offsets"), ("pose", "kinematic")])
def test_kept_offset_columns_give_the_fresh_sensitivity_bit_for_bit(ur10_sets, kind, free):
    nominal, markers, pose = ur10_sets
    res = calibrate(nominal, [markers if kind == "markers" else pose], free, noise=NOISE)
    problem = res.problem
    exp = problem.experiments[0]
    comps = exp.components()
    for state in (problem.nominal, res.state):
        kept = problem.cache.kept(state, problem.experiments)
        assert kept is not None and F.offset_columns(exp, state, kept[0]) is not None
        assert F._joint_sensitivity(exp, state, comps, kept[0]) == F._joint_sensitivity(exp, state, comps)


def test_nothing_is_read_off_another_state_or_problem(ur10_sets):
    nominal, markers, _ = ur10_sets
    res = calibrate(nominal, [markers], "kinematic", noise=NOISE)
    problem = res.problem
    other_state = problem.nominal.replace(extras=dict(problem.nominal.extras))  # equal values, another state
    assert problem.cache.kept(other_state, problem.experiments) is None
    subset = replace(problem, experiments=(type(problem.experiments[0])(markers.subset(np.arange(10)),
                                                                        problem.experiments[0].frames),))
    assert subset.cache is problem.cache  # a replaced problem shares the cache object ...
    assert subset.cache.kept(subset.nominal, subset.experiments) is None  # ... but not its entries
    # offsets not free: the kept blocks have no offset columns, the sensitivity is evaluated afresh
    held = calibrate(nominal, [markers], ["arm.*.xi", "arm.home"], noise=NOISE)
    kept = held.problem.cache.kept(held.state, held.problem.experiments)
    assert kept is not None and F.offset_columns(held.problem.experiments[0], held.state, kept[0]) is None


def test_large_problems_keep_nothing(ur10_sets):
    nominal, _, _ = ur10_sets
    true = perturb_robot(nominal, "fine", rng=np.random.default_rng(8))
    big = generate_markers(true, n=F.SENSITIVITY_SAMPLES + 1, rng=9, noise=NOISE)[0]
    res = calibrate(nominal, [big], "kinematic", noise=NOISE)
    assert res.status == "converged" and res.problem.cache.linearized is None
    assert res.problem.cache.kept(res.state, res.problem.experiments) is None


def test_study_memory_gives_each_structure_its_own_rows():
    """Both Table I variants (markers, pose: different layouts) through one ``Fixed`` whose memory the earlier
    repeats filled, against each repeat with a fresh one: the same outcomes bit for bit."""
    s = S.load("table1")
    warm = S.fixed_parts(s)
    for r in range(3):
        got, want = S.run_repeat(s, warm, r), S.run_repeat(s, S.fixed_parts(s), r)
        assert len(got) == len(s.variants) >= 2
        for a, b in zip(got, want):
            assert (a.status, a.names) == (b.status, b.names)
            for f in ("estimate", "truth", "std"):
                assert np.array_equal(getattr(a, f), getattr(b, f))
            assert a.validation == b.validation
    structures = {k for k in warm.memo if isinstance(k, tuple) and k[0] == "quantities"}
    assert len(structures) == len({v.data for v in s.variants}) == 2  # markers and pose layouts, one entry each
