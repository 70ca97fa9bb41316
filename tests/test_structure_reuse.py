"""What repeats of the same structure share (issue #13, "Speed"): the units check's verdict on the joint readings
is remembered per robot and readings, and a different robot or other readings are judged afresh; the check's
shortcut for measured values far from overflow gives the same verdict as its full test. A problem rebuilt with new
measured values (``Problem.with_measurements``) is the one ``build`` makes, for data of the same structure only;
a study's variants solved through it give ``calibrate``'s results bit for bit, keyed by robot, options and noise."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from kincal.errors import DataFormatError
from kincal.estimation import Problem, Stage, solve
from kincal.estimation import plausibility as P
from kincal.io.models import load_builtin
from kincal.kinematics import forward_kinematics
from kincal.simulate.generators import generate_markers
from kincal.simulate.noise import Noise
from kincal.workflow import study as S

KEY = "p_tracker_marker"


@pytest.fixture(scope="module")
def arm():
    robot = load_builtin("klimchik3r")
    ds = generate_markers(robot, "arm", n=5, rng=3, noise=Noise(position=1e-5), known_markers=True,
                          n_validation=1)[0]
    return robot, ds


@pytest.fixture
def counted(monkeypatch):
    """Counts the nominal tool spreads computed (the forward kinematics the memory saves)."""
    calls = []
    real = P._tool_spread
    monkeypatch.setattr(P, "_tool_spread", lambda robot, ds: calls.append(ds) or real(robot, ds))
    P.clear_readings_cache()
    yield calls
    P.clear_readings_cache()


def _nominal_spread(robot, q):
    return P.spread(forward_kinematics(robot.arms["arm"], q)[:, :3, 3])


def test_the_same_readings_with_other_measurements_reuse_the_verdict(arm, counted):
    robot, ds = arm
    first = P.readings_verdict(robot, ds)
    moved = replace(ds, measured={**ds.measured, KEY: ds.measured[KEY] + 1e-4})
    assert P.readings_verdict(robot, moved) == first and len(counted) == 1
    assert P.implausible_units(robot, moved) is None and len(counted) == 1
    assert first == (None, _nominal_spread(robot, ds.q["arm"]))


def test_other_readings_or_another_robot_are_judged_afresh(arm, counted):
    robot, ds = arm
    P.readings_verdict(robot, ds)
    q = {"arm": ds.q["arm"] + 0.1}
    other = replace(ds, q=q)
    _, tool = P.readings_verdict(robot, other)
    assert len(counted) == 2
    assert tool == _nominal_spread(robot, q["arm"]) and tool != P.readings_verdict(robot, ds)[1]
    twin = load_builtin("klimchik3r")  # equal values, another object: judged again
    assert twin is not robot
    P.readings_verdict(twin, ds)
    assert len(counted) == 3
    P.readings_verdict(robot, ds)
    P.readings_verdict(twin, other)
    assert len(counted) == 4  # (twin, other) is new; (robot, ds) is remembered


def test_a_reading_beyond_4_pi_is_found_whatever_was_remembered(counted):
    robot = load_builtin("ur10")  # joints with limits: readings beyond +-4 pi are judged
    ds = generate_markers(robot, "arm", n=5, rng=3, noise=Noise(position=1e-5), known_markers=True,
                          n_validation=1)[0]
    assert P.implausible_units(robot, ds) is None
    q = ds.q["arm"].copy()
    q[2, 1] = 20.0  # rad: degrees declared as radians
    bad = P.implausible_units(robot, replace(ds, q={"arm": q}))
    assert bad is not None and bad.field == "q" and (bad.sample, bad.joint, bad.value) == (2, 1, 20.0)


def test_the_memory_is_bounded(arm, counted):
    robot, ds = arm
    for k in range(P.READINGS_ENTRIES + 5):
        P.readings_verdict(robot, replace(ds, q={"arm": ds.q["arm"] + 1e-3 * k}))
    assert len(P._READINGS) == P.READINGS_ENTRIES


def _full_test(key, arm, x, tool):
    """``_absurd_cell`` without its shortcut (the median test alone)."""
    flat = x.reshape(len(x), -1)
    median = np.median(flat, axis=0)
    with np.errstate(over="ignore", invalid="ignore"):
        typical = np.median(np.linalg.norm((flat - median).reshape(len(x), -1, 3), axis=-1))
        bound = P.CELL_FACTOR * max(tool, float(typical), P.MIN_SIZE)
        far = ~(np.abs(flat - median) <= bound)
    if not far.any():
        return None
    i, c = np.argwhere(far)[0]
    return P.Implausible(key, arm, float(flat[i, c]), sample=int(i), spread=bound, column=int(c))


@pytest.mark.parametrize("case", ["metres", "a cell at 150 m", "a span of exactly 100 m", "near overflow",
                                  "huge and close", "one inf", "mm as m", "two rows", "wide but plausible"])
def test_the_shortcut_gives_the_full_tests_verdict(case):
    rng = np.random.default_rng(7)
    x = rng.normal(scale=0.5, size=(6, 3, 3))
    if case == "a cell at 150 m":
        x[4, 1, 2] = 150.0
    elif case == "a span of exactly 100 m":
        x[:, 0, 0] = 0.0
        x[2, 0, 0] = 100.0
    elif case == "near overflow":
        x[1, 0, 0] = 1e308
    elif case == "huge and close":  # the median of two huge values overflows: inf, far
        x[:, 0, 0] = 1.5e308 + np.arange(6)
    elif case == "one inf":
        x[3, 2, 1] = np.inf
    elif case == "mm as m":
        x = x * 1e3
    elif case == "two rows":
        x = x[:2] + np.array([0.0, 0.0, 99.0])
    elif case == "wide but plausible":
        x[:, :, 0] = np.linspace(0.0, 200.0, 6)[:, None]
    with np.errstate(over="ignore", invalid="ignore"):
        assert P._absurd_cell(KEY, "arm", x, 0.5) == _full_test(KEY, "arm", x, 0.5)


# ------------------------------------------------------------------ a problem rebuilt with new measured values


@pytest.fixture(scope="module")
def table1():
    s = S.load("table1")
    fixed = S.fixed_parts(s)
    data = [S.repeat_data(s, fixed.true, fixed, np.random.default_rng(r)) for r in range(4)]
    return s, fixed, data


def _same_result(a, b) -> bool:
    """Bit for bit: status, messages, estimates and reported std, covariance, rank, the calibrated model."""
    return (a.status == b.status and a.messages == b.messages and a.iterations == b.iterations
            and [(e.name, e.value, e.std) for e in a.estimates] == [(e.name, e.value, e.std) for e in b.estimates]
            and a.covariance.tobytes() == b.covariance.tobytes()
            and a.identifiability.rank == b.identifiability.rank
            and all(np.array_equal(x, y) for x, y in zip(a.robot.arms["arm"].screws, b.robot.arms["arm"].screws)))


def test_a_problem_with_new_measurements_shares_the_structure(table1):
    s, _, data = table1
    noise = S.calibration_noise(s)
    free = s.variants[0].options["free"]
    first = Problem.build(s.robot, [data[0]], free, noise=noise)
    again = first.with_measurements([data[1]])
    built = Problem.build(s.robot, [data[1]], free, noise=noise)
    assert again is not None and again.experiments[0].dataset is data[1]
    assert again.layout is first.layout and again.nominal is first.nominal and again.start is first.start
    assert again.noise == built.noise and again.layout.names == built.layout.names
    assert np.array_equal(again.free_idx, built.free_idx) and again.want == built.want
    assert again.cache is not first.cache
    assert _same_result(solve(again), solve(built))


@pytest.mark.parametrize("change", ["readings", "readings' sign of zero", "known markers", "name", "frames",
                                    "stated noise", "another kind", "fewer rows", "two data sets"])
def test_other_structures_are_built_afresh(table1, change):
    s, _, data = table1
    ds = data[1]
    first = Problem.build(s.robot, [data[0]], "offsets", noise=S.calibration_noise(s))
    q = ds.q["arm"].copy()
    if change == "readings":
        q[1, 2] += 1e-12
        other = [replace(ds, q={"arm": q})]
    elif change == "readings' sign of zero":  # 0.0 and -0.0 compare equal but are not the same readings
        q[0, 0] = 0.0
        first = Problem.build(s.robot, [replace(data[0], q={"arm": q})], "offsets", noise=S.calibration_noise(s))
        q = q.copy()
        q[0, 0] = -0.0
        other = [replace(ds, q={"arm": q})]
    elif change == "known markers":
        other = [replace(ds, known={**ds.known, "p_tool_marker": ds.known["p_tool_marker"] * 1.01})]
    elif change == "name":
        other = [replace(ds, name="session2")]
    elif change == "frames":
        other = [replace(ds, frames={"tracker": "lab_tracker"})]
    elif change == "stated noise":
        other = [replace(ds, meta={**ds.meta, "noise": {"position_m": 2e-5}})]
    elif change == "another kind":
        other = [S.pose_data(ds, S.calibration_noise(s), "full")[0]]
    elif change == "fewer rows":
        other = [ds.subset(slice(0, 2))]
    else:
        other = [ds, replace(ds, name="second")]
    assert first.with_measurements(other) is None


def test_unknown_frames_or_a_corrected_start_are_built_afresh(table1):
    s, _, data = table1
    unknown = [replace(d, known={k: v for k, v in d.known.items() if k != "T_world_tracker"}) for d in data[:2]]
    noise = S.calibration_noise(s)
    p = Problem.build(s.robot, [unknown[0]], "offsets", noise=noise)
    assert p.unknown and p.with_measurements([unknown[1]]) is None


def test_new_measurements_are_checked_as_build_checks_them(table1):
    s, _, data = table1
    noise = S.calibration_noise(s)
    first = Problem.build(s.robot, [data[0]], "offsets", noise=noise)
    y = data[1].measured["p_tracker_marker"].copy()
    y[2, 1, 0] = np.nan
    bad = replace(data[1], measured={"p_tracker_marker": y})
    with pytest.raises(DataFormatError) as built:
        Problem.build(s.robot, [bad], "offsets", noise=noise)
    with pytest.raises(DataFormatError) as reused:
        first.with_measurements([bad])
    assert str(reused.value) == str(built.value)


def test_the_study_gives_calibrates_results_bit_for_bit(table1):
    """Every variant through the problem of the structure (``calibrate_variant`` with a memo) gives what
    ``calibrate`` gives; the memo holds one problem per variant, reused from the second repeat on."""
    s, fixed, data = table1
    memo = {}
    for ds in data:
        for v in s.variants:
            assert _same_result(S.calibrate_variant(s, v, ds, memo), S.calibrate_variant(s, v, ds))
    assert {k for k in memo if k[0] == "problem"} == {("problem", v.name) for v in s.variants}


def test_the_studys_problem_is_keyed_by_robot_options_and_noise(table1, monkeypatch):
    s, fixed, data = table1
    built = []
    real = Problem.build
    monkeypatch.setattr(Problem, "build", classmethod(lambda cls, *a, **k: built.append(a) or real(*a, **k)))
    v = s.variants[0]
    memo = {}
    S.calibrate_variant(s, v, data[0], memo)
    S.calibrate_variant(s, v, data[1], memo)
    assert len(built) == 1
    narrower = replace(v, options={**v.options, "free": ["arm.*.offset", "arm.base.v_z"]})  # the same name
    res = S.calibrate_variant(s, narrower, data[2], memo)
    assert len(built) == 2 and len(res.estimates) == 4
    twin = replace(s, robot=load_builtin("klimchik3r"))  # equal values, another object
    S.calibrate_variant(twin, narrower, data[2], memo)
    assert len(built) == 3
    louder = replace(s, noise=S.Noise(position=2e-5))
    S.calibrate_variant(louder, narrower, data[3], memo)
    assert len(built) == 4
    S.calibrate_variant(louder, narrower, data[0], memo)
    assert len(built) == 4
    moved = replace(data[1], q={"arm": data[1].q["arm"] + 0.01})  # other configurations: built afresh
    S.calibrate_variant(louder, narrower, moved, memo)
    assert len(built) == 5


def test_variants_with_other_options_go_through_calibrate(table1, monkeypatch):
    """Options beyond the solver's, free, fixed and outliers (stages here) and a solve with rows beyond the
    outlier rule go through ``calibrate`` itself, with the same result."""
    s, fixed, data = table1
    calls = []
    real = S.calibrate
    monkeypatch.setattr(S, "calibrate", lambda *a, **k: calls.append(k) or real(*a, **k))
    v = s.variants[0]
    staged = replace(v, name="staged", options={"stages": (Stage(free=tuple(v.options["free"])),)})
    memo = {}
    S.calibrate_variant(s, staged, data[0], memo)
    assert len(calls) == 1 and "stages" in calls[0] and not memo
    S.calibrate_variant(s, v, data[0], memo)
    assert len(calls) == 1 and ("problem", v.name) in memo
    y = data[1].measured["p_tracker_marker"].copy()
    y[1, 0] += 1e-3  # 100 sigma: an outlier
    bad = replace(data[1], measured={"p_tracker_marker": y})
    res = S.calibrate_variant(s, v, bad, memo)
    assert len(calls) == 2  # a row beyond the rule at the plain solve: calibrate's robust pass decides
    assert _same_result(res, real(s.robot, [bad], noise=S.calibration_noise(s), **v.options))
    keep = replace(v, name="keep", options={**v.options, "outliers": "keep"})
    res = S.calibrate_variant(s, keep, bad, memo)
    assert len(calls) == 2
    assert _same_result(res, real(s.robot, [bad], noise=S.calibration_noise(s), **keep.options))
