"""Session 13 (helper b): the end of a calibration with fewer numpy and Python calls, bit for bit.

``ops.displacement`` writes an additive kind's identity derivative onto D's diagonal (no ``np.eye`` per block:
``ParamKind.additive``, ``offset``) and takes ``T @ inverse(T0)`` pose by pose with the nominal poses' inverses
remembered (``se3.remembered``); ``outliers.row_chi2`` scales rows by a constant diagonal whitener as the solve
does; ``values.to_robot`` passes no compliance that is the model's own bit for bit; ``result.estimates_of`` fills
each instance's dict item by item; ``result.new_result`` sets a ``Result``'s fields in its dict at once;
``stats.residual_norms`` takes a residual whose columns are all of one quantity as it is. Each against the path it replaces, on several structures (markers, pose,
clamp, dual arm, elastic, lateral compliance), and through whole calibrations."""

from __future__ import annotations

import dataclasses
import importlib

import numpy as np
import pytest
from test_fixed_overhead_s12_c import _bits, _digest, _with_compliance, cases  # noqa: F401 (structures, digest)

from kincal import robots
from kincal.estimation import Noise, Problem, calibrate
from kincal.estimation.result import Estimate, Result, estimates_of
from kincal.kinematics import Robot
from kincal.lie import se3
from kincal.params import LATERAL, State, build_layout, clear_caches, displacement, retract
from kincal.params import kinds as K
from kincal.params import values as V
from kincal.simulate import generate_markers, perturb_robot
from kincal.simulate.noise import Noise as Simulated

OPS = importlib.import_module("kincal.params.ops")
OUT = importlib.import_module("kincal.estimation.outliers")


def _plain_displacement(state, nominal, layout, only=None, jacobian=True, blocks=None):
    """``ops.displacement`` as it was (up to 7c28e65): each kind's own derivative, the poses' inverses in a batch,
    the blocks holding ``only`` found by ``Layout.holding`` (``blocks`` ignored)."""
    disp = np.zeros(layout.size)
    D = np.zeros((layout.size, layout.size)) if jacobian else None
    blocks = layout.blocks if only is None else layout.holding(only)
    poses = [b for b in blocks if b.kind.pose_of(b.value(state)) is not None]
    for b in blocks:
        if b not in poses:
            d, J = b.kind.displacement(b.value(state), b.value(nominal))
            disp[b.slice] = d
            if jacobian:
                D[b.slice, b.slice] = J
    if not poses:
        return disp, D
    T = np.stack([b.kind.pose_of(b.value(state)) for b in poses])
    D_T = T @ se3.inverse(np.stack([b.kind.pose_of(b.value(nominal)) for b in poses]))
    x, Jinv = se3.log_with_jacobian_inv(D_T) if jacobian else (se3.log(D_T), [None] * len(poses))
    for b, xb, Jb in zip(poses, x, Jinv):
        disp[b.slice] = xb
        if jacobian:
            D[b.slice, b.slice] = Jb
    return disp, D


def _plain_row_chi2(problem, state):
    return [(np.einsum("nij,nj->ni", W, res.r) ** 2).sum(axis=1)
            for W, res in zip(problem.whiteners(state), problem.residuals(state))]


_compliance_fields = V._compliance_fields


def _plain_compliance_fields(a, model=None):
    """``values._compliance_fields`` as it was: the compliance passed whatever it is (no model to compare with)."""
    return _compliance_fields(a)


def _plain_estimates_of(names, units, idx, values, nominals, stds, identifiable):
    return [Estimate(names[i], v, n, s, units[i], o) for i, v, n, s, o in zip(idx, values, nominals, stds, identifiable)]


def _plain_paths(m):
    m.setattr(OPS, "displacement", _plain_displacement)
    for name in ("kincal.estimation.finalize", "kincal.estimation.result", "kincal.estimation.problem"):
        m.setattr(importlib.import_module(name), "displacement", _plain_displacement)
    m.setattr(OUT, "row_chi2", _plain_row_chi2)
    m.setattr(V, "_compliance_fields", _plain_compliance_fields)
    finalize = importlib.import_module("kincal.estimation.finalize")
    m.setattr(finalize, "estimates_of", _plain_estimates_of)
    m.setattr(finalize, "new_result", lambda **values: Result(**values))
    m.setattr(importlib.import_module("kincal.estimation.problem"), "residual_norms", _plain_norms)


def _robot_bits(robot) -> bytes:
    """Every field of every arm of a calibrated robot, bit for bit."""
    return b"".join(name.encode() + _bits({k: v for k, v in vars(m).items() if k != "meta"})
                    for name, m in robot.arms.items())


def _lateral_robot():
    ur10 = robots.load("ur10")
    a = ur10.arms["arm"]
    rng = np.random.default_rng(8)
    arm = a.replace(lateral=rng.uniform(0, 2e-3, (a.dof, 2)), compliance=rng.uniform(1e-6, 1e-5, a.dof))
    return Robot(ur10.name, {"arm": arm}, dict(ur10.meta), dict(ur10.mounts))


def _states(cases, rng):
    """(name, layout, nominal, a state moved from it in every coordinate) per structure, lateral compliance too."""
    out = []
    for name, robot, sets, free, noise in cases:
        p = Problem.build(robot, sets, free, noise=noise)
        out.append((name, p.layout, p.nominal, p.free_idx))
    lateral = State.from_robot(_lateral_robot())
    out.append(("lateral", build_layout(lateral, ["kinematic", "elastic", "lateral"]), lateral, None))
    return [(name, layout, nominal, free, retract(nominal, layout, rng.normal(size=layout.size) * 1e-2))
            for name, layout, nominal, free in out]


def test_displacement_is_the_kinds_own(cases, rng):
    for name, layout, nominal, free, state in _states(cases, rng):
        assert any(b.kind.additive for b in layout.blocks), name
        for only in (None, free if free is not None else np.arange(layout.size)[::3]):
            for jac in (True, False):
                got, plain = displacement(state, nominal, layout, only, jac), _plain_displacement(
                    state, nominal, layout, only, jac)
                assert _bits(got) == _bits(plain), (name, jac)


def test_additive_kinds_derivative_is_the_identity(cases, rng):
    kinds = set()
    for name, layout, nominal, _, state in _states(cases, rng):
        for b in layout.blocks:
            if b.kind.additive:
                d, D = b.kind.displacement(b.value(state), b.value(nominal))
                assert _bits(D) == _bits(np.eye(b.stop - b.start)), (name, b.name)
                assert _bits(b.kind.offset(b.value(state), b.value(nominal))) == _bits(d), (name, b.name)
                kinds.add(b.kind)
    assert {K.OFFSETS, K.COMPLIANCE, LATERAL, K.POINTS} <= kinds
    assert not any(k.additive for k in (K.TWISTS, K.HOME, K.BASE, K.TOOL, K.POSE, K.PLANE))


def test_the_displacement_comparison_can_fail(monkeypatch, cases, rng):
    """A nominal pose's remembered inverse off by round-off, or the twists taken for additive: the bits differ."""
    name, layout, nominal, free, state = _states(cases[:1], rng)[0]
    plain = _bits(displacement(state, nominal, layout, free))
    b = next(b for b in layout.blocks if b.kind.pose_of(b.value(nominal)) is not None)
    se3.clear_caches()
    inverse = se3.remembered(se3.inverse, b.kind.pose_of(b.value(nominal)))
    key = next(k for k, v in se3._ONE_POSE.items() if v is inverse)
    se3._ONE_POSE[key] = inverse * (1 + 1e-15)
    try:
        assert _bits(displacement(state, nominal, layout, free)) != plain
    finally:
        se3.clear_caches()
    assert _bits(displacement(state, nominal, layout, free)) == plain
    monkeypatch.setattr(K._Twists, "additive", True)
    assert _bits(displacement(state, nominal, layout, free)) != plain


def test_row_chi2_is_the_whitened_product(cases):
    met = set()
    for name, robot, sets, free, noise in cases:
        p = Problem.build(robot, sets, free, noise=noise)
        got, plain = OUT.row_chi2(p, p.nominal), _plain_row_chi2(p, p.nominal)
        assert _bits(got) == _bits(plain), name
        met |= {p.cache.diagonal(W) is not None for W in p.whiteners(p.nominal)}
    assert met == {True, False}  # rows scaled by a diagonal, and whitened by the product


def test_to_robot_is_the_model_with_every_estimate(cases):
    soft = _with_compliance(robots.load("ur10"), np.random.default_rng(3))
    _, _, sets, _, noise = cases[0]
    extra = [("compliance held", soft, sets, "kinematic", noise)]
    for name, robot, sets, free, noise in list(cases) + extra:
        res = calibrate(robot, sets, free, noise=noise)
        with pytest.MonkeyPatch.context() as m:
            m.setattr(V, "_compliance_fields", _plain_compliance_fields)
            plain = res.state.to_robot(res.nominal_robot)
        assert _robot_bits(res.robot) == _robot_bits(plain), name
        for arm, model in res.robot.arms.items():
            assert not model.compliance.flags.writeable, (name, arm)


def test_a_negative_or_estimated_compliance_is_passed(rng):
    soft = _with_compliance(robots.load("ur10"), rng)
    a = V.ArmValues.from_model(soft.arms["arm"])
    assert V._compliance_fields(a, soft.arms["arm"]) == {}
    moved = V.arm_replace(a, compliance=a.compliance + 1e-7)
    assert set(V._compliance_fields(moved, soft.arms["arm"])) == {"compliance"}
    below = V.arm_replace(a, compliance=-a.compliance)
    fields = V._compliance_fields(below, soft.arms["arm"])
    assert fields["allow_negative_compliance"] and _bits(fields["compliance"]) == _bits(-a.compliance)
    zero = soft.arms["arm"].replace(compliance=np.zeros(6))
    signed = V.arm_replace(V.ArmValues.from_model(zero), compliance=-np.zeros(6))  # -0.0 is not 0.0 bit for bit
    assert set(V._compliance_fields(signed, zero)) == {"compliance"}


def test_estimates_are_the_dataclass_instances(rng):
    names, units = [f"p{i}" for i in range(9)], ["m", "rad", "m/N"] * 3
    idx, n = [0, 2, 3, 7, 8], 5
    args = (names, units, idx, rng.normal(size=n).tolist(), rng.normal(size=n).tolist(),
            [0.1, float("nan"), 0.0, 2.0, 1e-9], [True, False, True, True, True])
    got, plain = estimates_of(*args), _plain_estimates_of(*args)
    assert got == plain and all(type(e) is Estimate and list(vars(e)) == list(vars(q)) for e, q in zip(got, plain))
    with pytest.raises(AttributeError):
        got[0].std = 1.0


def test_calibrations_give_what_the_replaced_paths_give(monkeypatch, cases):
    for name, robot, sets, free, noise in cases:
        clear_caches()
        res = calibrate(robot, sets, free, noise=noise)
        shipped = (_digest(res), _robot_bits(res.robot))
        with monkeypatch.context() as m:
            _plain_paths(m)
            clear_caches()
            res = calibrate(robot, sets, free, noise=noise)
            plain = (_digest(res), _robot_bits(res.robot))
        assert shipped == plain, name


def test_outlier_screen_and_rejection_are_unchanged(monkeypatch):
    """A corrupted row: the screen sends it to the robust pass and the same row is left out by either path."""
    nominal = robots.load("ur10")
    ds = generate_markers(perturb_robot(nominal, "fine", 3), "arm", n=40, rng=4, markers=1,
                          noise=Simulated(position=5e-5))[0]
    measured = {k: v.copy() for k, v in ds.measured.items()}
    measured["p_tracker_marker"][7, 0, 1] += 0.01
    bad = dataclasses.replace(ds, measured=measured)
    stated = Noise(position=5e-5, joint=0.0)
    res = calibrate(nominal, [bad], "kinematic", noise=stated)
    with monkeypatch.context() as m:
        _plain_paths(m)
        plain = calibrate(nominal, [bad], "kinematic", noise=stated)
    assert [o.sample for o in res.outliers] == [o.sample for o in plain.outliers] == [7]
    assert _digest(res) == _digest(plain)
    assert OUT.any_beyond(res.problem, res.state, 1e-6) is False


def _plain_norms(r, components):
    """``stats.residual_norms`` as it was: each quantity's columns taken by a boolean mask, all of them too."""
    from kincal.analysis.linalg import norms
    from kincal.noise import ORIENTATION, PIXEL, POSITION
    out = {}
    for key, q in (("position", POSITION), ("orientation", ORIENTATION), ("pixel", PIXEL)):
        mask = np.array([c == q for c in components], bool)
        if not mask.any():
            out[f"{key}_rms"] = out[f"{key}_max"] = None
            continue
        cols = r[:, mask]
        three = key == "position" and mask.sum() % 3 == 0 and mask.sum() > 1
        e = norms(cols.reshape(len(r), -1, 3), -1).ravel() if three else (
            norms(cols, -1) if key != "position" else np.abs(cols).ravel())
        out[f"{key}_rms"], out[f"{key}_max"] = float(np.sqrt(np.mean(e ** 2))), float(e.max())
    return out


def test_residual_norms_are_the_masked_ones(rng):
    from kincal.estimation.stats import residual_norms
    from kincal.noise import ORIENTATION, PIXEL, POSITION
    for comps in ((POSITION,) * 3, (POSITION,) * 6, (POSITION,) * 3 + (ORIENTATION,) * 3, (POSITION,),
                  (ORIENTATION,) * 3 + (POSITION,) * 2, (PIXEL,) * 2, (POSITION, PIXEL, POSITION, POSITION)):
        for r in (rng.normal(size=(17, len(comps))), np.asfortranarray(rng.normal(size=(9, len(comps)))),
                  rng.normal(size=(12, 2 * len(comps)))[:, ::2]):
            got = residual_norms(r, comps)
            plain = _plain_norms(r, comps)
            assert {k: _bits(v) for k, v in got.items()} == {k: _bits(v) for k, v in plain.items()}, comps


def test_new_result_is_the_dataclass(cases):
    from dataclasses import fields

    from kincal.estimation.result import new_result
    name, robot, sets, free, noise = cases[0]
    res = calibrate(robot, sets, free, noise=noise)
    every = {f.name: res.__dict__[f.name] for f in fields(Result)}
    required = {f.name: every[f.name] for f in fields(Result) if f.name in (
        "robot", "nominal_robot", "state", "layout", "estimates", "covariance", "correlated", "identifiability",
        "start_identifiability", "before", "after", "sigma2", "status", "iterations", "evaluations", "messages")}
    for values in (every, required, {**required, "weights": np.ones(3), "stages": ("s",)}):
        got, plain = new_result(**values), Result(**values)
        assert type(got) is Result and list(vars(got)) == list(vars(plain))
        assert all(vars(got)[k] is vars(plain)[k] or vars(got)[k] == vars(plain)[k] for k in vars(plain))
    assert new_result(**required).extras == {} and new_result(**required).extras is not new_result(**required).extras
    for wrong in ({k: v for k, v in required.items() if k != "status"}, {**required, "colour": 1}):
        with pytest.raises(TypeError):
            new_result(**wrong)
    with pytest.raises(AttributeError):
        new_result(**required).status = "x"


def test_linear_loss_weights_and_slopes_are_ones(rng):
    finalize = importlib.import_module("kincal.estimation.finalize")
    for r in (rng.normal(size=40), np.zeros(0), rng.normal(size=(3, 4))):
        w, s = finalize.robust_weights(r, "linear", 0.5)
        assert _bits(w) == _bits(np.ones_like(r)) == _bits(s)
    assert finalize.covariance_scale(float("nan"), 3, 5) != finalize.covariance_scale(float("nan"), 3, 5)  # nan kept
    assert finalize.covariance_scale(0.5, 3, 5) == 1.0 and finalize.covariance_scale(0.5, 30, 5) == 0.5


def test_the_estimates_blocks_are_those_holding_a_free_coordinate(cases, rng):
    """``_estimates`` takes the problem's wanted blocks for ``Layout.holding(free)``: the same blocks, in order, and
    the same displacement; other blocks given, other numbers."""
    for name, robot, sets, free, noise in cases:
        p = Problem.build(robot, sets, free, noise=noise)
        wanted = [b for b in p.layout.blocks if b.name in p.want]
        assert wanted == p.layout.holding(p.free_idx), name
        state = retract(p.nominal, p.layout, rng.normal(size=p.layout.size) * 1e-2)
        given = displacement(state, p.nominal, p.layout, p.free_idx, blocks=wanted)
        assert _bits(given) == _bits(displacement(state, p.nominal, p.layout, p.free_idx)), name
        assert _bits(displacement(state, p.nominal, p.layout, p.free_idx, blocks=wanted[1:])) != _bits(given), name
