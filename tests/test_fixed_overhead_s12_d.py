"""Session 12 (helper d): what ``calibrate`` does around the outer loop, in fewer numpy calls, bit for bit.

``outliers.median`` is ``np.median`` (nan, ties, odd and even sizes); ``estimates_of`` builds the Estimates the
dataclass does; ``plausibility._within`` and ``spread`` give the verdicts and numbers they gave; the finalize
helpers (``variance_factor``, ``_joint_sensitivity``, ``_estimates``, ``_uncertainty``) are their numpy-function
forms; ``_compliance_fields`` flags a compliance below 0 as before."""

from __future__ import annotations

import dataclasses
import importlib
import math

import numpy as np
import pytest

from kincal.estimation import Problem, SolverOptions, calibrate, solve
from kincal.estimation.result import Estimate, estimates_of
from kincal.noise import Noise
from test_structure_cache import ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)

outliers = importlib.import_module("kincal.estimation.outliers")
plausibility = importlib.import_module("kincal.estimation.plausibility")
finalize_module = importlib.import_module("kincal.estimation.finalize")
values_module = importlib.import_module("kincal.params.values")


def _bits(x) -> bytes:
    return np.asarray(x, float).tobytes()


@pytest.mark.parametrize("n", [1, 2, 3, 4, 7, 8, 50, 51, 1000, 5001])
def test_median_is_numpys_bit_for_bit(n):
    rng = np.random.default_rng(n)
    cases = [rng.chisquare(3, n), rng.chisquare(1, n) * 1e-300, rng.chisquare(6, n) * 1e300,
             rng.integers(0, 3, n).astype(float), np.full(n, 2.5)]
    nan = rng.chisquare(3, n)
    nan[rng.integers(n)] = np.nan
    inf = rng.chisquare(3, n)
    inf[rng.integers(n)] = np.inf
    for c in cases + [nan, inf]:
        want, got = float(np.median(c)), outliers.median(c)
        assert _bits(got) == _bits(want) or (math.isnan(got) and math.isnan(want))


def test_median_leaves_its_input_alone():
    c = np.array([3.0, 1.0, 2.0, 5.0])
    outliers.median(c)
    assert c.tolist() == [3.0, 1.0, 2.0, 5.0]


def test_scaled_chi2_is_the_median_rule():
    from scipy.special import chdtrc, chdtri
    c = np.random.default_rng(3).chisquare(3, 40) * 4.0
    scale = max(float(np.median(c)) / chdtri(3, 0.5), 1.0)
    got, p = outliers.scaled_chi2(c, 3)
    assert _bits(got) == _bits(c / scale) and _bits(p) == _bits(chdtrc(3, c / scale))


def test_estimates_of_equals_the_dataclass():
    names, units = ["a", "b", "c"], ["m", "rad", "m"]
    got = estimates_of(names, units, [2, 0], [1.5, -0.0], [0.0, 2.0], [float("nan"), 0.1], [False, True])
    want = [Estimate("c", 1.5, 0.0, float("nan"), "m", False), Estimate("a", -0.0, 2.0, 0.1, "m", True)]
    assert [e.__dict__.keys() for e in got] == [e.__dict__.keys() for e in want]
    assert [repr(e) for e in got] == [repr(e) for e in want]
    assert got[1] == want[1] and hash(got[1]) == hash(want[1])
    with pytest.raises(dataclasses.FrozenInstanceError):
        got[0].value = 2.0
    assert dataclasses.replace(got[1], value=3.0) == Estimate("a", 3.0, 2.0, 0.1, "m", True)


def _within_reference(flat, bound):
    with np.errstate(invalid="ignore"):
        hi, lo = flat.max(axis=0), flat.min(axis=0)
        return bool(np.all(hi - lo <= bound) and np.all(np.abs(hi) <= 1e300) and np.all(np.abs(lo) <= 1e300))


def test_within_gives_the_verdict_it_gave_without_warnings():
    rng = np.random.default_rng(5)
    base = rng.normal(size=(30, 6))
    cases = [base, base * 1e3]
    for value in (np.nan, np.inf, -np.inf, 1e301, -1e301, 1e300, -1e300, 99.0, 101.0):
        x = base.copy()
        x[4, 2] = value
        cases.append(x)
        cases.append(np.full_like(base, value))  # every value of a column beyond (or at) the limit
    big = base.copy()
    big[:, 1] = [1e300, -1e300] * 15  # finite, span 2e300: no overflow on the way
    cases += [big, np.zeros((5, 0))]  # and no column at all
    with np.errstate(all="raise"):  # the span is taken of finite columns only
        for x in cases:
            assert plausibility._within(x, 100.0) == _within_reference(x, 100.0)


def test_spread_is_the_numpy_function_form():
    rng = np.random.default_rng(6)
    for x in (rng.normal(size=(50, 1, 3)), rng.normal(size=(7, 3)) * 1e-3, rng.normal(size=(200, 2, 3))[:, :, :]):
        want = float(np.sqrt(np.mean(np.sum((x - x.mean(axis=0)) ** 2, axis=-1))))
        assert _bits(plausibility.spread(x)) == _bits(want)


def test_variance_factor_is_the_function_form():
    rng = np.random.default_rng(7)
    r = rng.normal(size=90)
    for loss in ("linear", "huber", "cauchy", "soft_l1", "arctan"):
        w, s = finalize_module.robust_weights(r, loss, 0.7)
        dof = float(np.sum(s)) - 10
        want = float(np.sum((w * r) ** 2)) / dof
        assert _bits(finalize_module.variance_factor(r, w, s, 10)) == _bits(want)
    assert math.isnan(finalize_module.variance_factor(r[:5], np.ones(5), np.ones(5), 5))


def _problem(ur10_sets, level="kinematic"):
    nominal, ds = ur10_sets[0], ur10_sets[1]
    return Problem.build(nominal, [ds], level, (), None, Noise(position=1e-5, joint=0.0))


def test_estimates_and_uncertainty_are_the_function_forms(ur10_sets):
    """``_estimates``' std (``diag(Df cov Df^T)``) as ``np.ix_``, ``np.sum`` and ``np.clip`` gave it: the result's
    (``_uncertainty`` no longer takes the covariance's own diagonal, which no caller read)."""
    from kincal.params import displacement
    problem = _problem(ur10_sets)
    res = solve(problem, SolverOptions())
    state, cov, free = res.state, res.covariance, problem.free_idx
    ok = np.array([e.identifiable for e in res.estimates])
    _, D = displacement(state, problem.nominal, problem.layout, free)
    Df = D[np.ix_(free, free)]
    want = np.where(ok, np.sqrt(np.clip(np.sum((Df @ cov) * Df, axis=1), 0, None)), np.nan)
    got = [e.std for e in finalize_module._estimates(problem, state, ok, cov)]
    assert _bits(got) == _bits(want)
    assert _bits([e.std for e in res.estimates]) == _bits(want)  # the result's: of the displacements, from cov


def _sensitivity_reference(jq, comps) -> dict:
    out = {}
    for q in dict.fromkeys(comps):
        rows = np.array([c == q for c in comps], bool)
        out[q] = float(np.sqrt(np.mean([np.mean(j[:, rows] ** 2) for j in jq.values()]))) if jq else 0.0
    return out


def test_joint_sensitivity_is_the_mean_of_means(ur10_sets, monkeypatch):
    problem = _problem(ur10_sets)
    exp, state = problem.experiments[0], problem.nominal
    comps = exp.components()
    jq = exp.residual(state, want=set(), jq=True).jq
    got = finalize_module._joint_sensitivity(exp, state, comps)
    assert {q: _bits(v) for q, v in got.items()} == {q: _bits(v) for q, v in _sensitivity_reference(jq, comps).items()}
    j = next(iter(jq.values()))
    for more in ({"a": j, "b": 2 * j[::-1]}, {}):  # more than one arm: np.mean of the means; none: 0
        monkeypatch.setattr(finalize_module, "offset_columns", lambda *a, more=more: more)
        got = finalize_module._joint_sensitivity(exp, state, comps)
        want = _sensitivity_reference(more, comps)
        assert {q: _bits(v) for q, v in got.items()} == {q: _bits(v) for q, v in want.items()}


def test_compliance_fields_flag_a_compliance_below_zero(ur10_sets):
    problem = _problem(ur10_sets, ["kinematic", "elastic"])
    a = problem.nominal.arms["arm"]
    assert "allow_negative_compliance" not in values_module._compliance_fields(a)
    k = np.zeros(a.dof)
    k[2] = -1e-9
    assert values_module._compliance_fields(dataclasses.replace(a, compliance=k))["allow_negative_compliance"]
    lateral = np.zeros((a.dof, 2))
    lateral[1, 0] = -1e-9
    fields = values_module._compliance_fields(dataclasses.replace(a, compliance=np.zeros(a.dof), lateral=lateral,
                                                                  lateral_axes=np.zeros((a.dof, 2, 6))))
    assert fields["allow_negative_compliance"] and fields["lateral"] is lateral
    fields = values_module._compliance_fields(dataclasses.replace(a, lateral=np.abs(lateral),
                                                                  lateral_axes=np.zeros((a.dof, 2, 6))))
    assert "allow_negative_compliance" not in fields


def test_calibrate_with_an_outlier_finds_it():
    """The screen (``any_beyond`` with the partition median) still sends a corrupted row to the robust pass."""
    from kincal.robots import load
    from kincal.simulate import generate_markers, perturb_robot
    from kincal.simulate.noise import Noise as Simulated
    nominal = load("ur10")
    ds = generate_markers(perturb_robot(nominal, "fine", 3), "arm", n=40, rng=4, markers=1,
                          noise=Simulated(position=5e-5))[0]
    measured = {k: v.copy() for k, v in ds.measured.items()}
    measured["p_tracker_marker"][7, 0, 1] += 0.01
    stated = Noise(position=5e-5, joint=0.0)
    res = calibrate(nominal, [dataclasses.replace(ds, measured=measured)], "kinematic", noise=stated)
    assert [o.sample for o in res.outliers] == [7]
    assert calibrate(nominal, [ds], "kinematic", noise=stated).outliers == ()


def _effective_chained(explicit, stated):
    from kincal.noise import DEFAULT, NONE
    return (explicit or NONE).over(Noise.from_si(stated or {})).over(DEFAULT)


@pytest.mark.parametrize("explicit", [None, Noise(), Noise(position=5e-5, joint=0.0),
                                      Noise(orientation=1e-3, backlash=1e-4, other={"pixel": 0.5, "force": 2.0})])
@pytest.mark.parametrize("stated", [None, {}, {"position_m": 1e-4}, {"joint_rad": 0.0, "pixel_px": 1.0},
                                    {"backlash_rad": 2e-4, "force_si": 3.0, "orientation_rad": 0.0}])
def test_effective_is_the_chained_rule(explicit, stated):
    from kincal.noise import effective
    got, want = effective(explicit, stated), _effective_chained(explicit, stated)
    assert got == want and list(got.other.items()) == list(want.other.items())


@pytest.mark.parametrize("stated", [{"position_m": -1.0}, {"joint_rad": float("nan")}])
def test_effective_refuses_a_bad_stated_noise_as_before(stated):
    from kincal.errors import ModelError
    from kincal.noise import effective
    with pytest.raises(ModelError) as want:
        _effective_chained(None, stated)
    with pytest.raises(ModelError) as got:
        effective(None, stated)
    assert str(got.value) == str(want.value)


def test_residual_norms_are_numpys():
    from kincal.estimation.stats import residual_norms
    from kincal.noise import ORIENTATION, PIXEL, POSITION
    rng = np.random.default_rng(8)
    comps = (POSITION,) * 6 + (ORIENTATION,) * 3 + (PIXEL,) * 2
    for r in (rng.normal(size=(17, 11)), rng.normal(size=(1, 11)) * 1e-7):
        got = residual_norms(r, comps)
        e = np.linalg.norm(r[:, :6].reshape(len(r), -1, 3), axis=-1).ravel()
        o, p = np.linalg.norm(r[:, 6:9], axis=-1), np.linalg.norm(r[:, 9:], axis=-1)
        for key, x in (("position", e), ("orientation", o), ("pixel", p)):
            assert _bits(got[f"{key}_rms"]) == _bits(float(np.sqrt(np.mean(x**2))))
            assert _bits(got[f"{key}_max"]) == _bits(float(np.max(x)))
    one = residual_norms(r[:, :1], (POSITION,))  # a lone length component: its absolute values
    assert _bits(one["position_rms"]) == _bits(float(np.sqrt(np.mean(np.abs(r[:, :1]).ravel() ** 2))))


def test_spread_of_every_row_needs_no_copy():
    """``implausible_units`` takes a C-contiguous set of at most ``SPREAD_ROWS`` rows as it is: the copy by
    ``_spread_rows`` (every row) holds the same values in the same layout, so the spread is the same bits; a strided
    view (pose translations) is still copied."""
    rng = np.random.default_rng(9)
    for n in (1, 2, 50, plausibility.SPREAD_ROWS):
        x = rng.normal(size=(n, 2, 3))
        assert np.array_equal(plausibility._spread_rows(n), np.arange(n))
        assert _bits(plausibility.spread(x)) == _bits(plausibility.spread(x[plausibility._spread_rows(n)]))
    poses = rng.normal(size=(50, 4, 4))
    view = poses[:, :3, 3]
    assert not view.flags.c_contiguous


def test_implausible_units_verdicts_are_unchanged(ur10_sets):
    nominal, markers, pose = ur10_sets
    for ds in (markers, pose):
        assert plausibility.implausible_units(nominal, ds) is None
        key = next(iter(plausibility._measured_lengths(ds)))
        measured = {k: v.copy() for k, v in ds.measured.items()}
        scaled = dataclasses.replace(ds, measured={**measured, key: measured[key] * 1000.0})  # mm read as m
        bad = plausibility.implausible_units(nominal, scaled)
        assert bad is not None and bad.field == key
        lengths = plausibility._measured_lengths(scaled)[key]
        if bad.column < 0:  # a spread verdict: the ratio of the copied rows' spread
            x = lengths[plausibility._spread_rows(len(lengths))]
            assert _bits(bad.spread) == _bits(plausibility.spread(x))


def test_mean_square_is_numpys_mean():
    rng = np.random.default_rng(10)
    big = rng.normal(size=(40, 7, 9))
    for x in (big, big[:, ::2, 1:], big[::3].transpose(2, 0, 1), rng.normal(size=(1, 1)) * 1e-200, big[:, [0, 3]]):
        assert _bits(finalize_module._mean_square(x)) == _bits(np.mean(x ** 2))
        assert _bits(math.sqrt(finalize_module._mean_square(x))) == _bits(float(np.sqrt(np.mean(x ** 2))))


def test_stats_mean_is_numpys():
    from kincal.estimation.stats import mean
    rng = np.random.default_rng(11)
    big = rng.normal(size=(33, 5, 3))
    for x in (big, big[:, 1:4], big.transpose(1, 2, 0), big[:, 0, 0], rng.normal(size=1) * 1e300):
        assert _bits(mean(x)) == _bits(np.mean(x))
        for axis in range(x.ndim):
            assert _bits(mean(x, axis)) == _bits(np.mean(x, axis=axis))


def _batch_ok(T, tol) -> bool:
    from kincal._validate import check_rotation
    try:
        check_rotation(T[None, :3, :3], "T", tol)
    except Exception:  # noqa: BLE001
        return False
    return bool(np.all(np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]) <= tol))


@pytest.mark.parametrize("tol", [1e-9, 1e-6])
def test_one_transform_passes_only_what_lapacks_determinant_passes(tol):
    """The closed-form determinant passes a transform only where ``np.linalg.det`` (the batch path) does, also
    at the tolerance's edge; what it leaves to the batch path gets the batch path's verdict."""
    from kincal._validate import _one_transform_ok, check_transform
    from kincal.lie import se3
    rng = np.random.default_rng(12)
    for _ in range(400):
        T = se3.exp(rng.standard_normal(6))
        f = rng.choice([0.0, 0.5, 1.0 - 1e-5, 1.0 - 1e-9, 1.0, 1.0 + 1e-9, 1.0 + 1e-5, 2.0])
        T[:3, :3] *= (1 + f * tol * rng.choice([-1.0, 1.0])) ** (1 / 3)  # det 1 +- f tol, |R^T R - I| ~ 2/3 f tol
        if _one_transform_ok(T, tol):
            assert _batch_ok(T, tol)
            assert abs(np.linalg.det(T[:3, :3]) - 1.0) <= tol
        ok = _batch_ok(T, tol)
        try:
            check_transform(T, "T", tol)
            assert ok
        except Exception:  # noqa: BLE001
            assert not ok
