"""What repeats of the same structure share (issue #13, "Speed"): the units check's verdict on the joint readings
is remembered per robot and readings, and a different robot or other readings are judged afresh; the check's
shortcut for measured values far from overflow gives the same verdict as its full test."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from kincal.estimation import plausibility as P
from kincal.io.models import load_builtin
from kincal.kinematics import forward_kinematics
from kincal.simulate.generators import generate_markers
from kincal.simulate.noise import Noise

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
