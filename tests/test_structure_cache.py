"""What a calibration remembers between calls of the same structure (nominal arm values per model, layout
selections, joint-screw exponential terms, the identifiability structure): the remembered path gives the same
Result as a cold one, bit for bit, and a changed structure (free set, experiment kind, number of rows, values of
the model) never reuses a stale entry."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.analysis import symmetries
from kincal.estimation import calibrate
from kincal.kinematics.twists import conform_twists
from kincal.lie import se3
from kincal.noise import Noise
from kincal.params import ArmValues, Prior, State, build_layout, clear_caches
from kincal.simulate import generate_markers, generate_pose, perturb_robot
from kincal.workflow import study as S

NOISE = Noise(position=1e-5, orientation=1e-5, joint=0.0, backlash=0.0)


def _cold(fn):
    """``fn()`` with every structure cache emptied first."""
    clear_caches()
    se3.clear_caches()
    symmetries.clear_structure_cache()
    return fn()


def _same(a, b) -> None:
    """Every Result field a calibration reports, equal bit for bit."""
    assert [(e.name, e.identifiable) for e in a.estimates] == [(e.name, e.identifiable) for e in b.estimates]
    assert np.array_equal([(e.value, e.nominal, e.std) for e in a.estimates],
                          [(e.value, e.nominal, e.std) for e in b.estimates], equal_nan=True)  # std nan: gauge
    assert np.array_equal(a.covariance, b.covariance)
    assert (a.status, a.messages, a.sigma2, a.iterations, a.evaluations) == \
        (b.status, b.messages, b.sigma2, b.iterations, b.evaluations)
    assert a.before == b.before and a.after == b.after and a.twists == b.twists and a.correlated == b.correlated
    for x, y in ((a.identifiability, b.identifiability), (a.identifiability_before, b.identifiability_before)):
        assert (x.rank, x.names, x.messages, x.weak, x.degenerate) == \
            (y.rank, y.names, y.messages, y.weak, y.degenerate)
        assert np.array_equal(x.singular_values, y.singular_values) and np.array_equal(x.null_space, y.null_space)
        assert [(d.pivot, d.partners, d.words) for d in x.directions] == \
            [(d.pivot, d.partners, d.words) for d in y.directions]
    for arm in a.robot.arms:
        for field in ("screws", "offsets", "base", "home", "tool"):
            assert np.array_equal(getattr(a.robot[arm], field), getattr(b.robot[arm], field))
    assert a.extras.keys() == b.extras.keys()
    for k in a.extras:
        assert np.array_equal(np.asarray(a.extras[k]), np.asarray(b.extras[k]))


def test_table1_repeats_remembered_and_cold_give_the_same_results():
    """The Monte Carlo case: the same structure with new data at every repeat, both variants (markers, pose)."""
    s = S.load("table1")
    fixed = S.fixed_parts(s)
    for seed in range(3):
        ds = S.repeat_data(s, fixed.true, fixed, np.random.default_rng(seed))
        for v in s.variants:
            cold = _cold(lambda: S.calibrate_variant(s, v, ds))
            warm = S.calibrate_variant(s, v, ds)  # every cache filled by the cold call (and earlier seeds)
            _same(cold, warm)
            _same(cold, S.calibrate_variant(s, v, ds))


@pytest.fixture(scope="module")
def ur10_sets():
    from kincal.robots import load

    nominal = load("ur10")
    true = perturb_robot(nominal, "fine", rng=np.random.default_rng(5))
    markers = generate_markers(true, n=14, rng=6, noise=NOISE)[0]
    pose = generate_pose(true, n=14, rng=7, noise=NOISE)[0]
    return nominal, markers, pose


def test_gauged_structure_remembered_and_cold_give_the_same_results(ur10_sets):
    """The bench's structure (full kinematic model, unknown tracker and marker: exact gauges, named directions)."""
    nominal, markers, _ = ur10_sets
    run = lambda: calibrate(nominal, [markers], "kinematic", noise=NOISE)  # noqa: E731
    cold = _cold(run)
    assert cold.identifiability.deficiency > 0 and cold.identifiability.directions
    _same(cold, run())


@pytest.mark.parametrize("order", [0, 1])
def test_a_changed_structure_never_reuses_a_stale_entry(ur10_sets, order):
    """Same robot, one call after another: a different free set, experiment kind, number of rows or prior gives
    what a cold call gives, whichever order the calls come in."""
    nominal, markers, pose = ur10_sets
    calls = [
        lambda: calibrate(nominal, [markers], "offsets", noise=NOISE),
        lambda: calibrate(nominal, [markers], "kinematic", noise=NOISE),
        lambda: calibrate(nominal, [pose], "kinematic", noise=NOISE),
        lambda: calibrate(nominal, [markers.subset(np.arange(10))], "kinematic", noise=NOISE),
        lambda: calibrate(nominal, [markers], "kinematic", fixed=["arm.wrist_3.xi"], noise=NOISE),
        lambda: calibrate(nominal, [markers], "offsets", priors={"arm.elbow.offset": Prior(1e-4)}, noise=NOISE),
    ]
    calls = calls if order == 0 else calls[::-1]
    cold = [_cold(fn) for fn in calls]
    clear_caches()
    warm = [fn() for fn in calls]  # each after the others' entries were remembered
    for a, b in zip(cold, warm):
        _same(a, b)
    sizes = {(len(r.estimates), r.layout.free.sum(), len(r.linearization.r)) for r in cold}
    assert len(sizes) == len(calls)  # the structures really differ


def test_layout_selection_memory_follows_its_arguments():
    from kincal.robots import load

    state = State.from_robot(load("ur10"))
    a = build_layout(state, "offsets")
    b = build_layout(state, "kinematic")
    c = build_layout(state, "offsets", fixed=["arm.elbow.offset"])
    d = build_layout(state, "offsets", priors={"arm.elbow.xi": Prior(0.1, 0.2)})
    assert a.free.sum() == 6 and b.free.sum() > 6 and c.free.sum() == 5 and d.free.sum() == 10
    assert np.isinf(a.prior_sigma).all() and np.isfinite(d.prior_sigma).sum() == 4
    d.free[:] = False  # a caller's change to its own layout does not reach the next one
    assert build_layout(state, "offsets", priors={"arm.elbow.xi": Prior(0.1, 0.2)}).free.sum() == 10
    assert build_layout(state, "offsets").free.sum() == 6


def test_arm_values_are_remembered_per_model_object_not_per_name():
    from kincal.robots import load

    nominal = load("ur10")
    other = perturb_robot(nominal, "fine", rng=np.random.default_rng(1))
    a, b = ArmValues.from_model(nominal["arm"]), ArmValues.from_model(other["arm"])
    assert a is ArmValues.from_model(nominal["arm"])  # the same model object: remembered
    assert not np.array_equal(a.screws, b.screws)  # the same names, other values: not reused
    assert np.array_equal(b.screws, other["arm"].screws) and np.array_equal(b.offsets, other["arm"].offsets)
    assert np.allclose(a.basis_pinv, np.linalg.pinv(a.basis), atol=1e-14)


def test_joint_screw_terms_follow_the_screws():
    """The remembered exponential terms belong to one screw array: another arm's screws get their own."""
    rng = np.random.default_rng(2)
    theta = rng.uniform(-2, 2, (5, 6))
    for _ in range(3):
        screws = conform_twists(rng.standard_normal((6, 6)), ["revolute"] * 5 + ["prismatic"])
        assert se3.exact_joint_screws(screws)
        expected = se3.exp(screws * theta[..., None])
        np.testing.assert_allclose(se3.exp_joint_screws(screws, theta), expected, atol=1e-12)
        np.testing.assert_allclose(se3.exp_joint_screws(screws, theta), expected, atol=1e-12)  # remembered
    assert not se3.exact_joint_screws(2.0 * screws)
