"""Exact gauges under noise (issue 9, findings 1 and 2), over 20 seeds each with encoder noise 1e-5 rad.

Finding 1: an exact symmetry of the noise-free problem that the residuals left lift off the null space (turning
a last joint together with an unknown clamp's fixture, or arm B's last joint with an unknown dual clamp) must
be held and reported unidentifiable, named with its partners. Finding 2: a Jacobian column zero up to round-off
(a tool point on the last joint's axis: Panda in a socket, UR10 on a plane) is zero, not rescaled to look
identifiable. Genuinely identifiable offsets stay identifiable, and the calibrated model is not worse than the
nominal one on fresh configurations.

Data are simulated once per case noise-free with the nominal robot; a seed's true robot has offsets ``o``, whose
readings of the same configurations are ``theta - o`` (plus encoder noise): no inverse kinematics per seed.
"""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from kincal import robots
from kincal.data import Dataset
from kincal.estimation import calibrate
from kincal.kinematics import Robot, forward_kinematics
from kincal.noise import Noise
from kincal.simulate import generate_clamp, generate_dual, generate_socket

SEEDS = range(20)
JOINT = 1e-5
STATED = Noise(position=1e-9, orientation=1e-9, joint=JOINT)
MUKCA_URDF = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "mukca-fixed-point" / "urdf" / "panda.urdf"


def _plane_data(robot: Robot, n: int, rng) -> Dataset:
    """Noise-free configurations of the arm with its tool point on a tilted plane (Newton on the shoulder)."""
    normal = np.array([0.2, 0.1, 1.0]) / np.linalg.norm([0.2, 0.1, 1.0])
    q = rng.uniform(-2, 2, (n, 6))
    for _ in range(30):
        z = forward_kinematics(robot["arm"], q)[:, :3, 3] @ normal - 0.3
        q2 = q.copy()
        q2[:, 1] += 1e-6
        q[:, 1] -= z / ((forward_kinematics(robot["arm"], q2)[:, :3, 3] @ normal - 0.3 - z) / 1e-6)
    q[:, 1] = (q[:, 1] + np.pi) % (2 * np.pi) - np.pi  # the same pose; readings a controller would report
    assert np.abs(forward_kinematics(robot["arm"], q)[:, :3, 3] @ normal - 0.3).max() < 1e-12
    return Dataset("plane", robot.name, ("arm",), {"arm": q}, name="plane")


def _panda(urdf: bool) -> Robot:
    if not urdf:
        return robots.load("panda")
    if not MUKCA_URDF.exists():
        pytest.skip("../shared/datasets (MUKCa URDF) not available")
    from kincal.io.urdf import from_urdf

    return Robot("panda", {"arm": from_urdf(MUKCA_URDF, "panda_link0", "ball_link", name="arm")})


_CACHE: dict = {}


def _case(name: str):
    """(nominal robot, training data, fresh validation data), noise-free at the nominal offsets; cached."""
    if name not in _CACHE:
        if name == "clamp":
            robot = robots.load("frida")
            make = lambda n, rng: generate_clamp(robot, "right", n=n, rng=rng)[0]  # noqa: E731
        elif name == "dual":
            robot = robots.load("frida")
            make = lambda n, rng: generate_dual(robot, n=n, rng=rng, known_clamp=False, n_validation=1)[0]  # noqa: E731
        elif name.startswith("socket"):
            robot = _panda(name == "socket-urdf")
            make = lambda n, rng: generate_socket(robot, n=n, rng=rng)[0]  # noqa: E731
        else:
            robot = robots.load("ur10")
            make = lambda n, rng: _plane_data(robot, n, np.random.default_rng(rng))  # noqa: E731
        _CACHE[name] = robot, make(50, 1), make(30, 2)
    return _CACHE[name]


def _truth_readings(ds: Dataset, offsets: dict, rng, noise: float) -> Dataset:
    """The readings of ``ds``'s configurations on a robot with these offsets, with encoder noise."""
    return replace(ds, q={a: ds.q[a] - offsets[a] + rng.normal(0, noise, ds.q[a].shape) for a in ds.arms})


# case: (the gauge joints, the identifiable ones), as (arm, joint index)
CASES = {
    "clamp": ([("right", 0), ("right", 6)], [("right", k) for k in range(1, 6)]),
    "dual": ([("right", 6), ("left", 6)], [(a, k) for a in ("left", "right") for k in range(6)]),
    "socket": ([("arm", 0), ("arm", 6)], [("arm", k) for k in range(1, 6)]),
    # the MUKCa URDF's ball sits 0.09 mm off j7's axis: j7 is (weakly) identifiable there, not a zero column
    "socket-urdf": ([("arm", 0)], [("arm", k) for k in range(1, 6)]),
    "plane": ([("arm", 0), ("arm", 5)], [("arm", k) for k in range(1, 5)]),  # UR10: shoulder_pan, wrist_3
}


def _rms(res) -> float:
    return float(np.sqrt(np.mean([s.position_rms**2 for s in res.after])))


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("case", list(CASES))
def test_exact_gauges_are_held_under_noise(case, seed):
    robot, train, fresh = _case(case)
    gauges, identifiable = ([f"{a}.{robot[a].joint_names[k]}" for a, k in js] for js in CASES[case])
    rng = np.random.default_rng(seed)
    offsets = {a: rng.uniform(-0.01, 0.01, len(robot[a].joint_names)) for a in train.arms}
    res = calibrate(robot, [_truth_readings(train, offsets, rng, JOINT)], "offsets", noise=STATED)
    assert res.status == "converged"
    for j in gauges:
        e = res.estimate(f"{j}.offset")
        assert not e.identifiable and np.isnan(e.std), (j, e)
        words = [m for m in res.messages if m.startswith(f"{j}.offset cannot be identified")]
        assert len(words) == 1, (j, res.messages)
        # named with its partners (the unknown frame it turns with), or as moving nothing at all
        assert "trades off against" in words[0] or "does not affect any residual" in words[0]
    truth = {f"{a}.{jn}": o for a in train.arms for jn, o in zip(robot[a].joint_names, offsets[a])}
    for j in identifiable:
        e = res.estimate(f"{j}.offset")
        assert e.identifiable and 0 < e.std < 1e-3, (j, e)
        assert abs(e.value - truth[j]) < 6 * e.std + 1e-6, (j, e.value, truth[j], e.std)
    # fresh configurations of the true robot (their frame unknown and estimated): not worse than nominal
    check = _truth_readings(fresh, offsets, rng, 0.0)
    before = calibrate(robot, [check], [], noise=STATED)
    after = calibrate(res.robot, [check], [], noise=STATED)
    assert _rms(after) <= _rms(before) + 1e-9


def _counting_consistent_nulls(monkeypatch):
    """Calls of the consistent linearization (``symmetries._consistent_nulls``), counted in a list."""
    from kincal.analysis import symmetries

    calls, real = [], symmetries._consistent_nulls
    monkeypatch.setattr(symmetries, "_consistent_nulls", lambda *a: calls.append(1) or real(*a))
    return calls


def test_structure_cache_remembers_a_gauged_structure_by_its_nullity(monkeypatch):
    """Exact gauges the residuals do not lift (an unknown tracker and marker with the full kinematic model): the
    structure's number of gauges is remembered, later linearizations of it skip the consistent one, and the
    results are the same bit for bit as without the cache (issue 15)."""
    from kincal.analysis import symmetries
    from kincal.simulate import generate_markers

    nominal = robots.load("ur10")
    ds, _, _ = generate_markers(nominal, n=40, rng=3, noise=Noise(position=5e-5, joint=0.0), markers=1)
    fit = lambda: calibrate(nominal, [ds], "kinematic", noise=Noise(position=5e-5, joint=0.0))  # noqa: E731
    calls = _counting_consistent_nulls(monkeypatch)
    symmetries.clear_structure_cache()
    # every linearization analysed (no step carried between analyses: tests/test_carried_step.py counts those)
    monkeypatch.setattr(sys.modules["kincal.estimation.iterate"], "_carried", lambda *a: None)
    monkeypatch.setattr(symmetries, "NULLITY_ENTRIES", 0)  # nothing remembered: every linearization tests
    cold = fit()
    uncached = len(calls)
    assert uncached == cold.iterations and len(symmetries._NULLITY) == 0  # each linearization (finalize reuses the last)
    monkeypatch.setattr(symmetries, "NULLITY_ENTRIES", 256)
    del calls[:]
    first = fit()
    assert 1 <= len(calls) < uncached
    assert list(symmetries._NULLITY.values()) == [cold.identifiability.deficiency] and cold.identifiability.deficiency
    del calls[:]
    again = fit()
    assert calls == []  # the structure is known: no consistent linearization at all
    for res in (first, again):
        assert res.identifiability.rank == cold.identifiability.rank == 27
        assert [e.value for e in res.estimates] == [e.value for e in cold.estimates]
        assert np.array_equal(res.covariance, cold.covariance) and res.status == cold.status == "converged"
        assert res.messages == cold.messages and res.identifiability_before.messages == cold.identifiability_before.messages


def test_structure_cache_keeps_testing_a_structure_whose_residuals_lift_gauges(monkeypatch):
    """An unknown clamp's fixture turning with the last joint: noise lifts that gauge off the plain null space,
    so the structure is marked (``LIFTS``) and every linearization takes the consistent one again; the gauge
    stays held."""
    from kincal.analysis import symmetries

    robot, train, _ = _case("clamp")
    rng = np.random.default_rng(0)
    offsets = {a: rng.uniform(-0.01, 0.01, len(robot[a].joint_names)) for a in train.arms}
    ds = _truth_readings(train, offsets, rng, JOINT)
    calls = _counting_consistent_nulls(monkeypatch)
    symmetries.clear_structure_cache()
    runs = []
    for _ in range(2):
        del calls[:]
        runs.append((calibrate(robot, [ds], "offsets", noise=STATED), len(calls)))
    assert list(symmetries._NULLITY.values()) == [symmetries.LIFTS]
    (a, n_a), (b, n_b) = runs
    assert n_b >= b.iterations and n_a == n_b  # every linearization
    assert [e.value for e in a.estimates] == [e.value for e in b.estimates]
    assert not b.estimate("right.j7.offset").identifiable
