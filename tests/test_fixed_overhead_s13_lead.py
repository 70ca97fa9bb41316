"""Session 13 (lead): ``Result.before``, the residual statistics at the start, computed on first read.

The solve keeps the whiteners of its first linearization (``Iteration.start_whiteners``) and the result computes
the statistics from them when read (``Deferred``, as ``after``): the values the eager computation at the start
gave, bit for bit, also after pickling, copying and ``dataclasses.replace``, and with encoder noise, where the
solve whitens again at its first estimate (so the start's whiteners are not the final ones)."""

from __future__ import annotations

import copy
import dataclasses
import pickle

import numpy as np

from kincal.estimation import Noise, calibrate
from kincal.estimation.result import Deferred
from test_fixed_overhead_s11_b import _pickled
from test_structure_cache import NOISE, ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)


def _eager(res):
    """The statistics at the start as the solve computed them before: its first linearization's whiteners."""
    problem = res.problem
    from kincal.estimation import steps
    from kincal.estimation.iterate import scale_test_needed

    lin = steps.linearize(problem, problem.start, None, scale_test_needed(problem))
    return tuple(problem.statistics(problem.start, lin.W))


def test_before_reads_as_computed_at_the_start(ur10_sets):
    nominal, markers, pose = ur10_sets
    for data, noise in (([markers], NOISE), ([markers, pose], Noise(position=5e-5, orientation=1e-4, joint=1e-5))):
        res = calibrate(nominal, data, "kinematic", noise=noise)
        assert isinstance(res.__dict__["before"], Deferred)
        want = _pickled(_eager(res))
        pickled = pickle.loads(_pickled(res))  # before the first read: pickled computed
        copied = copy.copy(res)
        replaced = dataclasses.replace(res, status="converged")
        for r in (res, pickled, copied, replaced):
            assert _pickled(r.before) == want and len(r.before) == len(data)
        assert not isinstance(res.__dict__["before"], Deferred)  # kept once read
        chi2 = [s.chi2 for s in res.before]
        assert all(np.isfinite(chi2)) and sum(chi2) > sum(s.chi2 for s in res.after)  # the start fits worse
