"""The scale test remembered within a solve (issue 15): data that see the robot's scale by a wide margin at the
first linearization (a tracker measures lengths) are not tested again, so later linearizations skip the test's
fixed columns; data that cannot see it (a clamp: joint readings only) keep the test at every linearization.
Either way the solve's result is the one of testing at every linearization, to round-off."""

import numpy as np
import pytest

from kincal import robots
from kincal.analysis import symmetries
from kincal.estimation import calibrate, steps
from kincal.noise import Noise
from kincal.simulate import generate_clamp, generate_markers
from kincal.workflow.study import fixed_parts, repeat_data
from kincal.workflow.study import load as load_study


def _recording(monkeypatch) -> list:
    """The ``every`` flag of each linearization the solver makes from here on."""
    flags, original = [], steps.linearize

    def linearize(problem, state, W, every):
        flags.append(every)
        return original(problem, state, W, every)

    monkeypatch.setattr(steps, "linearize", linearize)
    return flags


def _markers(seed: int):
    robot = robots.load("ur10")
    rng = np.random.default_rng(seed)
    ds = generate_markers(robot, n=40, rng=rng, noise=Noise(position=5e-5, joint=0.0))[0]
    return robot, ds


def _same(a, b, rtol=1e-9):
    assert a.status == b.status and a.iterations == b.iterations
    assert a.identifiability.rank == b.identifiability.rank
    assert tuple(a.messages) == tuple(b.messages)
    assert [(e.name, e.identifiable) for e in a.estimates] == [(e.name, e.identifiable) for e in b.estimates]
    np.testing.assert_allclose([e.value for e in a.estimates], [e.value for e in b.estimates], rtol=rtol, atol=1e-12)
    np.testing.assert_allclose([e.std for e in a.estimates], [e.std for e in b.estimates], rtol=rtol, equal_nan=True)


@pytest.mark.parametrize("seed", range(3))
def test_a_tracker_sees_scale_so_later_linearizations_skip_the_test(monkeypatch, seed):
    robot, ds = _markers(seed)
    noise = Noise(position=5e-5, joint=0.0)
    with monkeypatch.context() as m:
        m.setattr(symmetries, "SCALE_VISIBLE_MARGIN", np.inf)  # tested at every linearization, as before
        every = _recording(m)
        reference = calibrate(robot, [ds], "kinematic", noise=noise)
    assert every and all(every)
    flags = _recording(monkeypatch)
    res = calibrate(robot, [ds], "kinematic", noise=noise)
    assert flags[0] and not any(flags[1:]) and len(flags) >= 2
    assert res.linearization.fixed is None  # the final analysis read the free columns only
    assert not res.identifiability.scale_unidentifiable
    _same(res, reference)


def test_a_clamp_cannot_see_scale_so_every_linearization_tests_it(monkeypatch):
    robot = robots.load("frida")
    ds = generate_clamp(robot, "right", n=40, rng=np.random.default_rng(3))[0]
    flags = _recording(monkeypatch)
    res = calibrate(robot, [ds], ["right.*"], noise=Noise(position=1e-9, orientation=1e-9, joint=1e-5))
    assert len(flags) >= 2 and all(flags)
    assert res.identifiability.scale_unidentifiable  # joint readings alone never give the robot's size
    assert res.linearization.fixed is not None


def test_scale_visible_needs_a_free_length_and_the_margin():
    robot, ds = _markers(0)
    res = calibrate(robot, [ds], "kinematic", noise=Noise(position=5e-5, joint=0.0))
    problem = res.problem
    lin = steps.linearize(problem, problem.start, None, True)
    gap, tolerance, _, _ = symmetries._scale_gap(lin, problem.layout)
    assert gap > symmetries.SCALE_VISIBLE_MARGIN * tolerance  # metres against a 0.05 mm noise
    assert symmetries.scale_visible(lin, problem.layout)
    assert symmetries.scale_null(lin, problem.layout) is None
    study = load_study("table1")  # known tracker and markers: with offsets alone free, nothing scales
    data = repeat_data(study, fixed_parts(study).true, fixed_parts(study), np.random.default_rng(0))
    offsets = calibrate(study.robot, [data], ["arm.*.offset"], noise=Noise(position=1e-5, joint=0.0)).problem
    assert not offsets.layout.lengths[offsets.free_idx].any()
    assert not symmetries.scale_visible(steps.linearize(offsets, offsets.start, None, True), offsets.layout)
