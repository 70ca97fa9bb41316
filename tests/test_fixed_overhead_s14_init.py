"""Session 14 (init): the start values of a calibration and the calibrated robot with fewer numpy calls.

``fit_transform`` of one set of points takes a path without the batch axes' handling (one sum and one
subtraction of both sets side by side); held here to the batch path (a stack of one) bit for bit, reflected
best fits included."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.experiments._kernel import fit_transform


@pytest.mark.parametrize("K", [1, 2, 3, 4, 7, 50, 300])
def test_one_fit_is_the_batch_fit(K):
    rng = np.random.default_rng(K)
    for trial in range(60):
        a = rng.normal(size=(K, 3)) * rng.uniform(0.01, 3)
        Q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        b = a @ Q.T + rng.normal(size=3) + rng.normal(size=(K, 3)) * rng.uniform(0, 1)
        if trial % 3 == 0:  # a mirror image: the best orthogonal fit is a reflection, made proper
            b[:, 0] *= -1
        one = fit_transform(a, b)
        assert one.shape == (4, 4)
        assert one.tobytes() == fit_transform(a[None], b[None])[0].tobytes()
        if K >= 3:
            assert np.linalg.det(one[:3, :3]) > 0


def test_one_fit_recovers_a_transform():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(20, 3))
    Q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    Q *= np.sign(np.linalg.det(Q))
    T = fit_transform(a, a @ Q.T + [0.1, -0.2, 0.3])
    np.testing.assert_allclose(T[:3, :3], Q, atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], [0.1, -0.2, 0.3], atol=1e-12)
    assert T[3].tolist() == [0.0, 0.0, 0.0, 1.0]


# --- the calibrated robot: an arm's transforms and screws checked on Python floats ------------------------------

from dataclasses import replace as dc_replace  # noqa: E402

from kincal import robots  # noqa: E402
from kincal._validate import check_transform  # noqa: E402
from kincal.errors import KincalError  # noqa: E402
from kincal.estimation import calibrate  # noqa: E402
from kincal.kinematics import model as M  # noqa: E402
from kincal.noise import Noise  # noqa: E402
from kincal.params import State  # noqa: E402
from kincal.params.values import arm_replace  # noqa: E402
from kincal.simulate.generators import generate_clamp, generate_dual, generate_markers, generate_pose  # noqa: E402


def _near_rigid(rng, scale):
    """Transforms whose rotation is off by about ``scale`` (around ``check_transform``'s tolerance 1e-6)."""
    Q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    Q *= np.sign(np.linalg.det(Q))
    T = np.eye(4)
    T[:3, :3] = Q + rng.normal(size=(3, 3)) * scale
    T[:3, 3] = rng.normal(size=3)
    return T


def _outcome(fn):
    try:
        return "ok", fn()
    except KincalError as e:
        return type(e).__name__, str(e)


def test_rigid_accepts_only_what_check_transform_accepts():
    rng = np.random.default_rng(0)
    seen = set()
    for k in range(3000):
        T = _near_rigid(rng, 10.0 ** rng.uniform(-9, -5))
        if k % 50 == 0:
            T[3, rng.integers(4)] += 10.0 ** rng.uniform(-9, -5)
        if k % 97 == 0:
            T[rng.integers(3), rng.integers(4)] = rng.choice([np.nan, np.inf, -np.inf])
        fast = M._rigid(T.tolist())
        general = _outcome(lambda: check_transform(T, "x", tol=M._RIGID_TOL))[0]
        assert not fast or general == "ok"
        seen.add((fast, general))
    assert {(True, "ok"), (False, "ok")} <= seen and any(g != "ok" for _, g in seen)


def _ur10_state():
    nominal = robots.load("ur10")
    return nominal, State.from_robot(nominal)


@pytest.mark.parametrize("field,value", [
    ("home", np.nan), ("home", np.inf), ("home", 1e-3), ("home", 2e-6), ("home", 5e-7), ("home", 1e-7),
    ("screws", np.nan), ("screws", np.inf), ("offsets", np.nan), ("tool", np.nan), ("base", 1e-3),
])
def test_to_robot_raises_what_the_general_path_raises(field, value):
    """Estimates that are not finite or not valid: ``to_robot`` raises the error a freshly built ArmModel raises
    (the general path, ``dataclasses.replace``), the same type and message; valid ones give the same model."""
    nominal, state = _ur10_state()
    key = next(iter(nominal.arms))
    a = state.arms[key]
    x = np.array(getattr(a, field), dtype=float)
    if field in ("home", "tool", "base") and np.isfinite(value):
        x[:3, :3] += value * np.array([[1, 0, 0], [0, -1, 0], [0, 0, 0.5]])  # off orthonormality by ~value
    else:
        x.flat[1] = value
    bad = state.replace(arms={key: arm_replace(a, **{field: x})})
    model = nominal.arms[key]

    def general():
        from kincal.kinematics import conform_twists
        b = bad.arms[key]
        return dc_replace(model, screws=conform_twists(b.screws, b.joint_types), offsets=b.offsets, base=b.base,
                          home=b.home, tool=b.tool)

    got, want = _outcome(lambda: bad.to_robot(nominal).arms[key]), _outcome(general)
    assert got[0] == want[0]
    if got[0] == "ok":
        assert got[1] == want[1]
        for f in ("screws", "home", "base", "tool", "offsets"):
            assert getattr(got[1], f).tobytes() == getattr(want[1], f).tobytes()
            assert not getattr(got[1], f).flags.writeable
    else:
        assert got[1] == want[1]


def test_replace_screws_checks_as_before():
    """``ArmModel.replace(screws=...)``: invalid screws (not unit, pitched, not finite, integer) give the errors
    and models the general path gives."""
    model = robots.load("ur10").arms[next(iter(robots.load("ur10").arms))]
    cases = []
    for i, v in [(3, 1.01), (0, 0.3), (2, np.nan), (5, np.inf)]:
        s = np.array(model.screws)
        s[1, i] = v
        cases.append(s)
    cases.append(np.rint(model.screws).astype(int))
    cases.append(np.array(model.screws) + 1e-12)
    for s in cases:
        got = _outcome(lambda: model.replace(screws=s))
        want = _outcome(lambda: dc_replace(model, screws=s))
        assert got[0] == want[0]
        if got[0] == "ok":
            assert got[1] == want[1] and got[1].screws.tobytes() == want[1].screws.tobytes()
        else:
            assert got[1] == want[1]


def _structures():
    frida = robots.load("frida")
    nominal = robots.load("ur10")
    from kincal.simulate import perturb_robot
    true = perturb_robot(nominal, "fine", rng=np.random.default_rng(5))
    noise = Noise(position=5e-5, orientation=1e-4, joint=0.0)
    return [
        (nominal, generate_markers(true, n=14, rng=6, noise=noise)[0], "kinematic"),
        (nominal, generate_pose(true, n=14, rng=7, noise=noise)[0], "kinematic"),
        (nominal, generate_markers(true, n=14, rng=8, noise=noise)[0], "elastic"),
        (frida, generate_clamp(frida, "right", n=30, rng=np.random.default_rng(2))[0], "kinematic"),
        (frida, generate_dual(frida, n=30, rng=0, noise=Noise(joint=1e-5), known_clamp=False)[0], "kinematic"),
    ]


@pytest.mark.parametrize("k", range(5))
def test_calibrated_robot_is_the_general_paths(k):
    """Whole calibrations (markers, pose, elastic, clamp, dual arm): the result's robot is the one a fresh
    ArmModel of the same values (``dataclasses.replace``, every field validated) gives, bit for bit."""
    nominal, ds, model = _structures()[k]
    try:
        res = calibrate(nominal, [ds], model)
    except KincalError as e:  # a structure this model cannot solve: nothing to compare
        pytest.skip(str(e))
    from kincal.params.values import _compliance_fields
    from kincal.kinematics import conform_twists
    for key, arm in res.robot.arms.items():
        if key not in res.state.arms:
            continue
        a, m = res.state.arms[key], nominal.arms[key]
        want = dc_replace(m, screws=conform_twists(a.screws, a.joint_types), offsets=a.offsets, base=a.base,
                          home=a.home, tool=a.tool, **_compliance_fields(a, m))
        assert arm == want
        for f in ("screws", "home", "base", "tool", "offsets", "compliance"):
            assert getattr(arm, f).tobytes() == getattr(want, f).tobytes()


def _old_screw_ok(x, revolute):
    """``_joint_screw_ok`` as it was (``not (... > tol or ...)``)."""
    v0, v1, v2, w0, w1, w2 = x
    nw = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if revolute:
        return not (abs(nw - 1) > M._UNIT_TOL or abs(w0 * v0 + w1 * v1 + w2 * v2) > M._UNIT_TOL)
    return not (nw > M._UNIT_TOL or abs(np.sqrt(v0 * v0 + v1 * v1 + v2 * v2) - 1) > M._UNIT_TOL)


def test_screw_test_is_the_old_one_on_finite_screws_and_fails_non_finite_ones():
    rng = np.random.default_rng(4)
    seen = set()
    for k in range(4000):
        revolute = bool(k % 2)
        v, w = rng.normal(size=3), rng.normal(size=3)
        if revolute:
            w /= np.linalg.norm(w)
            v -= (w @ v) * w
        else:
            v, w = v / np.linalg.norm(v), w * 0
        x = np.concatenate([v, w]) + rng.normal(size=6) * 10.0 ** rng.uniform(-12, -8)
        ok = M._joint_screw_ok(x.tolist(), revolute)
        assert ok == _old_screw_ok(x, revolute)
        seen.add(ok)
        for bad in (np.nan, np.inf, -np.inf):
            y = x.copy()
            y[k % 6] = bad
            assert not M._joint_screw_ok(y.tolist(), revolute)
            assert not M._valid_screws(y[None], ("revolute" if revolute else "prismatic",))
    assert seen == {True, False}
