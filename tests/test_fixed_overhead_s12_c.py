"""Session 12 (helper c): the solver's plumbing with fewer numpy and Python calls, bit for bit.

``values.arm_replace`` (the kinds' too) is ``dataclasses.replace`` on ``ArmValues`` without its ``__init__``; ``layout.touched``
finds the blocks a mask touches by one reduction (``ops._moved_blocks``, ``Layout.holding``, ``Problem``'s
wanted blocks); ``ResidualCache.diagonal`` remembers the constant diagonal of the whiteners a problem made;
``Problem._stack`` hands a single residual part on without a copy; ``Problem.evaluate`` at no step evaluates at the
state itself; ``recentre`` skips the kinds that keep their values; ``TWISTS.scale`` is remembered for a model's
own (read-only) values. Each against the path it replaces, on several structures (markers, pose, clamp, dual
arm, elastic)."""

from __future__ import annotations

import dataclasses
import hashlib
import importlib

import numpy as np
import pytest

from kincal import robots
from kincal.estimation import Noise, Problem, calibrate
from kincal.estimation import problem as P
from kincal.params import (ARM_KINDS, TWISTS, ArmValues, State, build_layout, clear_caches, conform, layout as L,
                           recentre, retract)
from kincal.params import kinds as K
from kincal.simulate.generators import generate_clamp, generate_dual, generate_markers, generate_pose
from kincal.simulate.perturb import perturb_robot

OPS = importlib.import_module("kincal.params.ops")
NOISE = Noise(position=5e-5, orientation=1e-4, joint=0.0)


def _with_compliance(robot, rng):
    return robots.Robot(robot.name, {k: m.replace(compliance=rng.uniform(1e-6, 1e-5, m.dof))
                                     for k, m in robot.arms.items()})


@pytest.fixture(scope="module")
def cases():
    """(name, nominal robot, data sets, free, noise) of several structures."""
    ur10, frida = robots.load("ur10"), robots.load("frida")
    true = perturb_robot(ur10, "fine", rng=np.random.default_rng(5))
    markers = generate_markers(true, n=20, rng=6, noise=NOISE)[0]
    pose = generate_pose(true, n=20, rng=7, noise=NOISE)[0]
    ftrue = perturb_robot(frida, "thesis", 7)
    clamp = generate_clamp(ftrue, "right", n=25, rng=1, known_fixture=False)[0]
    dual = generate_dual(ftrue, n=25, rng=3, known_clamp=False)[0]
    soft = _with_compliance(true, np.random.default_rng(3))
    loaded = generate_markers(soft, n=40, rng=4, markers=3, wrench=2500.0)[0]
    joint = Noise(position=5e-5, joint=1e-5)
    return [("markers", ur10, [markers], "kinematic", NOISE), ("pose", ur10, [pose], "kinematic", NOISE),
            ("markers+pose, encoder noise", ur10, [markers, pose], "kinematic", joint),
            ("clamp", frida, [clamp], "offsets", None), ("dual", frida, [dual], "kinematic", None),
            ("elastic", ur10, [loaded], ["kinematic", "elastic"], None)]


def _bits(x) -> bytes:
    if isinstance(x, np.ndarray):
        return x.dtype.str.encode() + str(x.shape).encode() + np.ascontiguousarray(x).tobytes()
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return type(x).__name__.encode() + b"".join(_bits(getattr(x, f.name)) for f in dataclasses.fields(x))
    if isinstance(x, dict):
        return b"".join(k.encode() + _bits(v) for k, v in x.items())
    if isinstance(x, (list, tuple)):
        return b"[" + b"".join(_bits(v) for v in x) + b"]"
    if isinstance(x, float):
        return np.float64(x).tobytes()
    return repr(x).encode()


def _digest(res) -> str:
    """Every reported number and word of a result, bit for bit."""
    ana = res.identifiability
    parts = [res.estimates, res.covariance, res.sigma2, res.status, res.iterations, res.evaluations,
             tuple(res.messages), dict(res.state.arms), dict(res.extras), ana.rank, ana.singular_values,
             ana.null_space, tuple(res.before), tuple(res.after)]
    return hashlib.sha1(b"".join(_bits(p) for p in parts)).hexdigest()


def _scan_touched(layout, mask):
    return [b for b in layout.blocks if np.asarray(mask)[b.start: b.stop].any()]


def _plain_recentre(state, conformed=False):
    arms = {}
    for name, a in state.arms.items():
        for kind in ARM_KINDS:
            a = TWISTS.with_tangents(a) if conformed and kind is TWISTS else kind.recentre(a)
        arms[name] = a
    return state.replace(arms, {k: state.kinds[k].recentre(v) for k, v in state.extras.items()})


def _plain_paths(m):
    """Every replaced path back to what it replaced."""
    m.setattr(K, "arm_replace", lambda a, **ch: dataclasses.replace(a, **ch))
    m.setattr(L, "touched", _scan_touched)
    m.setattr(OPS, "touched", _scan_touched)
    m.setattr(L.Layout, "touched", lambda self, mask: _scan_touched(self, mask))
    m.setattr(P.ResidualCache, "diagonal", lambda self, W: P._constant_diagonal(W))
    m.setattr(P, "_joined", lambda parts: np.concatenate(parts))
    m.setattr(OPS, "recentre", _plain_recentre)
    m.setattr(importlib.import_module("kincal.estimation.iterate"), "recentre", _plain_recentre)
    m.setattr(K._Twists, "scale", K._Twists._scale)


def test_calibrations_give_what_the_replaced_paths_give(monkeypatch, cases):
    for name, robot, sets, free, noise in cases:
        clear_caches()
        shipped = [_digest(calibrate(robot, sets, free, noise=noise)) for _ in range(2)]  # cold, then remembered
        with monkeypatch.context() as m:
            _plain_paths(m)
            clear_caches()
            plain = _digest(calibrate(robot, sets, free, noise=noise))
        assert shipped == [plain, plain], name


def test_the_comparison_can_fail(monkeypatch, cases):
    _, robot, sets, free, noise = cases[0]
    shipped = _digest(calibrate(robot, sets, free, noise=noise))
    with monkeypatch.context() as m:
        m.setattr(P, "_joined", lambda parts: np.concatenate(parts) * (1 + 1e-15))
        assert _digest(calibrate(robot, sets, free, noise=noise)) != shipped


def test_arm_replace_is_dataclasses_replace(cases):
    a = ArmValues.from_model(robots.load("ur10")["arm"])
    a.basis  # cached on a: the copy must not keep it
    rng = np.random.default_rng(2)
    for changes in ({"offsets": rng.normal(size=a.dof)}, {"screws": a.screws + 1e-3, "bases": None},
                    {"home": np.eye(4), "tool": np.eye(4)}, {}):
        got, want = K.arm_replace(a, **changes), dataclasses.replace(a, **changes)
        assert type(got) is ArmValues and got is not a and _bits(got) == _bits(want)
        assert "basis" not in got.__dict__  # derived from the fields: computed again when read
    with pytest.raises(TypeError):  # not a field: dataclasses.replace's error
        K.arm_replace(a, basis=np.eye(2))


def test_touched_blocks_are_the_scanned_ones(cases, rng):
    from kincal.params.kinds import OFFSETS
    from kincal.params.layout import Block

    sizes = [0, 3, 0, 6, 1, 0, 4, 0]
    starts = np.cumsum([0] + sizes)
    fake = type("L", (), {"blocks": tuple(Block(f"b{i}", OFFSETS, int(a), int(a + s))
                                          for i, (a, s) in enumerate(zip(starts, sizes)))})()
    layouts = [fake] + [Problem.build(robot, sets, free, noise=noise).layout for _, robot, sets, free, noise in cases]
    for layout in layouts:
        size = layout.blocks[-1].stop
        for _ in range(100):
            mask = rng.random(size) < rng.choice([0.02, 0.2, 0.8])
            assert L.touched(layout, mask) == _scan_touched(layout, mask)
            if isinstance(layout, L.Layout):
                assert layout.touched(mask) == _scan_touched(layout, mask)
        assert L.touched(layout, np.zeros(size, bool)) == []
    assert L.touched(type("E", (), {"blocks": ()})(), np.zeros(0, bool)) == []
    # remembered per blocks tuple (shared by the layouts of one structure while its arms' values live: the blocks'
    # memory holds them weakly), forgotten with the params caches
    first = Problem.build(*cases[0][1:3], cases[0][3], noise=cases[0][4])
    again = Problem.build(*cases[0][1:3], cases[0][3], noise=cases[0][4]).layout
    assert again.blocks is first.layout.blocks and again.runs is first.layout.runs
    assert L._RUNS and id(fake.blocks) in L._RUNS
    clear_caches()
    assert not L._RUNS


def test_wanted_blocks_are_those_with_a_free_coordinate(cases):
    for _, robot, sets, free, noise in cases:
        problem = Problem.build(robot, sets, free, noise=noise)
        layout = problem.layout
        assert problem.want == frozenset(b.name for b in layout.blocks if layout.free[b.start: b.stop].any())


def test_diagonals_remembered_only_for_the_problems_own_whiteners(cases):
    _, robot, sets, free, noise = cases[0]
    problem = Problem.build(robot, sets, free, noise=noise)
    W = problem.whiteners(problem.start)
    for Wi in W:
        d = problem.cache.diagonal(Wi)
        assert d is problem.cache.diagonal(Wi) and not d.flags.writeable  # remembered
        assert np.array_equal(d, P._constant_diagonal(Wi))
    base = np.diag([1.0, 2.0, 3.0])
    outside = np.broadcast_to(base, (5, 3, 3))
    first = problem.cache.diagonal(outside)
    base[1, 1] = 7.0  # someone else's array may change: never remembered
    assert first.tolist() == [1.0, 2.0, 3.0] and problem.cache.diagonal(outside).tolist() == [1.0, 7.0, 3.0]


def test_linearize_and_evaluate_stack_as_concatenate_does(monkeypatch, cases):
    for _, robot, sets, free, noise in cases:
        problem = Problem.build(robot, sets, free, noise=noise)
        W = problem.whiteners(problem.start)
        z = np.zeros(len(problem.free_idx))
        step = 1e-6 * np.random.default_rng(0).normal(size=len(z))
        moved = conform(retract(problem.start, problem.layout, problem.full_delta(step), tangents=False))
        got = [problem.linearize(problem.start, W)[:2], problem.evaluate(problem.start, step, W),
               problem.evaluate(moved, z, W, jac=False)[:1], problem.evaluate(problem.start, z, W)]
        with monkeypatch.context() as m:
            m.setattr(P, "_joined", lambda parts: np.concatenate(parts))
            m.setattr(P.ResidualCache, "diagonal", lambda self, W: P._constant_diagonal(W))
            fresh = problem.__class__.assemble(problem.robot, problem.experiments, problem.layout, problem.nominal,
                                               problem.noise, problem.start, problem.constraints, problem.unknown)
            retracted = lambda s, d, jac: retract(s, fresh.layout, fresh.full_delta(d), tangents=jac)  # noqa: E731
            want = [fresh.linearize(fresh.start, W)[:2], fresh.evaluate(fresh.start, step, W),
                    (fresh._stack(moved, fresh._residuals(retracted(moved, z, False), False), W, None, {})[0],),
                    fresh._stack(retracted(fresh.start, z, True), [e.residual(fresh.start, want=fresh.want, jq=False)
                                                                    for e in fresh.experiments], W, fresh.free_idx,
                                 {})]
        for g, w in zip(got, want):
            assert [_bits(x) for x in g] == [_bits(x) for x in w]


def test_recentre_as_every_kind_recentres(cases):
    for _, robot, sets, free, noise in cases:
        problem = Problem.build(robot, sets, free, noise=noise)
        step = 1e-4 * np.random.default_rng(1).normal(size=len(problem.free_idx))
        moved = retract(problem.start, problem.layout, problem.full_delta(step), tangents=False)
        for conformed, state in ((True, conform(moved)), (False, moved)):
            got, want = recentre(state, conformed), _plain_recentre(state, conformed)
            assert _bits(dict(got.arms)) == _bits(dict(want.arms))
            assert _bits(dict(got.extras)) == _bits(dict(want.extras))


def test_twist_scale_remembered_for_a_models_own_values_only():
    clear_caches()
    ur10, frida = robots.load("ur10"), robots.load("frida")
    a, b = ArmValues.from_model(ur10["arm"]), ArmValues.from_model(frida["right"])
    first = TWISTS.scale(a)
    assert np.array_equal(first, TWISTS._scale(a)) and id(a.screws) in K._TWIST_SCALES
    shifted = K.arm_replace(a, offsets=a.offsets + 1.0)  # the same screws and bases: the same entry
    assert np.array_equal(TWISTS.scale(shifted), TWISTS._scale(shifted)) and len(K._TWIST_SCALES) == 1
    first[:] = 0.0  # the caller's copy
    assert np.array_equal(TWISTS.scale(a), TWISTS._scale(a))
    assert np.array_equal(TWISTS.scale(b), TWISTS._scale(b))  # another model: its own
    moved = retract(State.from_robot(ur10), build_layout(State.from_robot(ur10), "kinematic"),
                    np.full(build_layout(State.from_robot(ur10), "kinematic").size, 1e-3))
    c = moved.arms["arm"]
    assert np.array_equal(TWISTS.scale(c), TWISTS._scale(c)) and id(c.screws) not in K._TWIST_SCALES  # writeable
    other = K.arm_replace(a, bases=tuple(B * 2.0 for B in a.bases))  # other bases (writeable): computed afresh
    assert np.array_equal(TWISTS.scale(other), TWISTS._scale(other))
    assert not np.array_equal(TWISTS.scale(other), TWISTS.scale(a))  # the test can fail
    clear_caches()
    assert not K._TWIST_SCALES


def test_converged_is_numpys_formula(rng):
    from kincal.estimation import steps

    def numpys(step, r0_norm, cost, dof):
        return step < max(1e-6 * (1.0 + r0_norm), 1e-2 * np.sqrt(2 * cost / max(dof, 1)))

    for _ in range(2000):
        cost = float(rng.choice([0.0, -0.0, 1e-300, np.inf])) if rng.random() < 0.1 else float(rng.lognormal(0, 20))
        dof = int(rng.integers(0, 50))
        scatter = 1e-2 * np.sqrt(2 * cost / max(dof, 1))
        step = float(scatter * rng.choice([0.5, 1.0, 2.0])) if rng.random() < 0.5 else float(rng.lognormal(0, 20))
        r0 = float(rng.lognormal(0, 5))
        assert steps.converged(step, r0, cost, dof) == numpys(step, r0, cost, dof)
        assert steps.converged(step, np.float64(r0), cost, dof) == numpys(step, np.float64(r0), cost, dof)
