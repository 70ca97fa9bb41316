"""The identifiability report at the start of a solve (``Result.identifiability_before``) is named only when read
(``analysis.identifiability.DeferredReport``), and then says exactly what naming it at once says."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.analysis import identify
from kincal.estimation import Problem, calibrate, steps
from kincal.estimation.gauge import priority
from kincal.estimation.iterate import scale_test_needed
from test_structure_cache import NOISE, ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)

def _eager(nominal, ds, free):
    """The start's report named at once, as the solver named it before it was deferred."""
    problem = Problem.build(nominal, [ds], free, noise=NOISE)
    lin = steps.linearize(problem, problem.start, None, scale_test_needed(problem))
    return identify(lin, problem.layout, problem.experiments, priority=priority(problem, "min-change"))


@pytest.mark.parametrize("free", ["kinematic", "offsets"])
def test_start_report_is_named_on_first_read_and_equals_the_eager_one(ur10_sets, free):
    nominal, ds, _ = ur10_sets
    res = calibrate(nominal, [ds], free, noise=NOISE)
    deferred = res.start_identifiability
    assert "report" not in vars(deferred)  # the solve never asked for its words
    assert deferred.analysis.directions == () and deferred.degenerate is False
    got, want = res.identifiability_before, _eager(nominal, ds, free)
    assert "report" in vars(deferred) and res.identifiability_before is got  # named once
    assert (got.rank, got.names, got.messages, got.weak, got.degenerate) == \
        (want.rank, want.names, want.messages, want.weak, want.degenerate)
    assert [(d.pivot, d.partners, d.words) for d in got.directions] == \
        [(d.pivot, d.partners, d.words) for d in want.directions]
    assert np.array_equal(got.null_space, want.null_space) and np.array_equal(got.range_space, want.range_space)
    if free == "kinematic":  # gauged: there is something to name
        assert got.directions and got.deficiency == len(got.directions) + int(got.scale_unidentifiable)


def test_a_solve_that_stops_at_its_start_reports_the_start_report():
    """Degenerate data (one configuration repeated, fixture unknown): the loop stops at its first linearization,
    and the final report is the start's, named (as when the start's report was named at once)."""
    from kincal.data import Dataset
    from kincal.kinematics import Robot
    from kincal.testing import random_arm

    rng = np.random.default_rng(3)
    arm = random_arm(rng, 6, name="arm")
    ds = Dataset("clamp", "r", ("arm",), {"arm": np.repeat(rng.uniform(-1, 1, (1, 6)), 10, axis=0)})
    res = calibrate(Robot("r", {"arm": arm}), [ds], "offsets", noise=NOISE)
    assert res.status == "degenerate" and res.start_identifiability.degenerate
    assert res.identifiability is res.identifiability_before and res.identifiability.degenerate
    want = _eager(Robot("r", {"arm": arm}), ds, "offsets")
    assert res.identifiability.messages == want.messages and res.identifiability.rank == want.rank
