"""Parameter kinds unpickle as the module's own instances: kincal compares them by identity (``b.kind is POSE``),
so a result sent back by a Dask worker, or pickled before its report was first read, would otherwise name its
null directions without their words (no frame motion found) and treat its blocks as of no known kind."""

from __future__ import annotations

import pickle

import numpy as np

from kincal import robots
from kincal.estimation import Noise, calibrate
from kincal.params import kinds
from kincal.simulate.generators import generate_markers
from kincal.simulate.perturb import perturb_robot
from test_fixed_overhead_s11_b import _pickled

EVERY_KIND = (*kinds.ARM_KINDS, *kinds.FRAME_KINDS.values())


def test_every_kind_unpickles_as_itself():
    for kind in EVERY_KIND:
        assert pickle.loads(pickle.dumps(kind)) is kind, kind.name
    assert len({k.name for k in EVERY_KIND}) == len(EVERY_KIND)  # the names tell them apart


def test_a_pickled_result_reports_as_the_original():
    noise = Noise(position=5e-5, joint=0.0)
    ur = robots.load("ur10")
    true = perturb_robot(ur, "fine", rng=np.random.default_rng(2))
    ds = generate_markers(true, n=30, rng=3, noise=noise)[0]
    res = calibrate(ur, [ds], "kinematic", noise=noise)
    back = pickle.loads(_pickled(res))  # before the report is first read: it is named after unpickling
    assert all(a.kind is b.kind for a, b in zip(back.layout.blocks, res.layout.blocks))
    assert list(back.messages) == list(res.messages)
    assert any("a rotation of the tracker about the axis of" in m for m in res.messages)
