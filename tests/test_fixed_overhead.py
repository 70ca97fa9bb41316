"""Session 9's cuts of a small calibration's fixed cost (docs/performance.md "Fixed overhead: session 9"): the final
identifiability report named when read (``estimation.result.FinalReport``), experiment digests of the structure key
remembered per experiment, a calibrated ArmModel validating only its changed geometry, the null and range bases
from one SVD, the row reduction on reordered columns, twist coordinates solved joint by joint. Each gives what the
computation it replaces gives (bit for bit, or to round-off where the brief allows it), and a changed input never
reuses a remembered entry."""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np
import pytest

from kincal.analysis import identify, symmetries
from kincal.analysis.identifiability import _null_and_range, _orth, _rref
from kincal.analysis.naming import blocks_of, degenerate
from kincal.errors import ManifoldError, ModelError
from kincal.estimation import Problem, calibrate, steps
from kincal.estimation.gauge import priority
from kincal.estimation.iterate import scale_test_needed
from kincal.estimation.result import FinalReport
from kincal.kinematics.twists import conform_twists
from kincal.params import ArmValues, displacement, recentre, retract
from test_structure_cache import NOISE, ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)


@pytest.mark.parametrize("free", ["kinematic", "offsets"])
def test_final_report_is_named_on_first_read_and_equals_the_eager_one(ur10_sets, free):
    nominal, ds, _ = ur10_sets
    res = calibrate(nominal, [ds], free, noise=NOISE)
    deferred = vars(res)["identifiability"]
    assert isinstance(deferred, FinalReport) and "report" not in vars(deferred)  # nothing asked for the words
    assert vars(res)["messages"] is deferred
    twin = copy.copy(res)  # copies unnamed, names itself on its own
    assert isinstance(vars(twin)["identifiability"], FinalReport)
    problem, lin = res.problem, res.linearization
    want = identify(lin, problem.layout, problem.experiments, rtol=deferred.analysis.rtol,
                    priority=priority(problem, "min-change"))
    got = res.identifiability
    assert res.identifiability is got and vars(res)["identifiability"] is got  # named once, kept
    assert (got.rank, got.names, got.messages, got.weak, got.degenerate) == \
        (want.rank, want.names, want.messages, want.weak, want.degenerate)
    assert [(d.pivot, d.partners, d.words) for d in got.directions] == \
        [(d.pivot, d.partners, d.words) for d in want.directions]
    assert np.array_equal(got.null_space, want.null_space) and np.array_equal(got.range_space, want.range_space)
    assert res.messages == deferred.head + want.messages + deferred.tail
    assert twin.messages == res.messages and twin.identifiability.messages == got.messages
    if free == "kinematic":
        assert got.directions and all(d.words in res.messages for d in got.directions)
    moved = replace(res, status="misfit")  # a replaced Result reads the named report
    assert moved.messages == res.messages and moved.identifiability is got


def test_experiment_digest_is_remembered_and_follows_the_experiment(ur10_sets):
    nominal, ds, _ = ur10_sets
    problem = Problem.build(nominal, [ds], "kinematic", noise=NOISE)
    lin = steps.linearize(problem, problem.start, None, scale_test_needed(problem))
    args = (lin, problem.layout, problem.experiments, 1e-9)
    symmetries._DIGESTS.clear()
    cold = symmetries.structure_key(*args)
    assert problem.experiments[0] in symmetries._DIGESTS
    assert symmetries.structure_key(*args) == cold  # remembered: the same key
    symmetries._DIGESTS.clear()
    assert symmetries.structure_key(*args) == cold
    # another problem with other readings (the same number of rows) or fewer rows: other digests and keys
    moved = replace(ds, q={k: q + 1e-3 for k, q in ds.q.items()})
    for other in (moved, ds.subset(np.arange(10))):
        p2 = Problem.build(nominal, [other], "kinematic", noise=NOISE)
        lin2 = steps.linearize(p2, p2.start, None, scale_test_needed(p2))
        assert symmetries.experiment_digest(p2.experiments[0]) != symmetries.experiment_digest(problem.experiments[0])
        assert symmetries.structure_key(lin2, p2.layout, p2.experiments, 1e-9) != cold


def _calibrated_fields(arm, rng):
    screws = conform_twists(arm.screws + rng.normal(0, 1e-3, arm.screws.shape), arm.joint_types)
    tilt = np.eye(4)
    tilt[:3, 3] = rng.normal(0, 1e-3, 3)
    return dict(screws=screws, offsets=arm.offsets + 1e-3, base=arm.base @ tilt, home=arm.home @ tilt,
                tool=arm.tool @ tilt, compliance=np.full(arm.dof, 1e-5))


def test_arm_model_geometry_replace_equals_the_validated_replace():
    from kincal.robots import load

    arm = load("ur10")["arm"]
    changes = _calibrated_fields(arm, np.random.default_rng(4))
    fast, full = arm.replace(**changes), replace(arm, **changes)
    assert fast == full and type(fast) is type(full)
    for name in ("screws", "offsets", "base", "home", "tool", "compliance", "lower", "upper", "link_coms"):
        a, b = getattr(fast, name), getattr(full, name)
        assert np.array_equal(a, b) and not a.flags.writeable
    assert (fast.joint_names, fast.joint_types, fast.controller_order, dict(fast.meta)) == \
        (full.joint_names, full.joint_types, full.controller_order, dict(full.meta))
    assert fast.screws is not changes["screws"]  # its own read-only copy
    assert not np.array_equal(arm.screws, fast.screws)  # the model itself is unchanged


@pytest.mark.parametrize("bad", ["pitch", "offsets", "tool", "compliance", "joints"])
def test_arm_model_geometry_replace_refuses_what_the_validated_replace_refuses(bad):
    from kincal.robots import load

    arm = load("ur10")["arm"]
    changes = _calibrated_fields(arm, np.random.default_rng(5))
    if bad == "pitch":
        changes["screws"] = changes["screws"].copy()
        changes["screws"][2, :3] += 1e-3 * changes["screws"][2, 3:]
    elif bad == "offsets":
        changes["offsets"] = np.full(arm.dof, np.nan)
    elif bad == "tool":
        changes["tool"] = changes["tool"] * 1.01
    elif bad == "compliance":
        changes["compliance"] = -changes["compliance"]
    else:
        changes["screws"] = changes["screws"][:5]
    with pytest.raises(Exception) as fast:
        arm.replace(**changes)
    with pytest.raises(Exception) as full:
        replace(arm, **changes)
    assert type(fast.value) is type(full.value) and str(fast.value) == str(full.value)
    assert isinstance(fast.value, (ModelError, ManifoldError))


def _rref_reference(M, order):
    """The row reduction as it was before session 9 (columns indexed through ``order`` at every step)."""
    M = np.array(M, dtype=float)
    k, order = M.shape[0], np.asarray(order, dtype=int)
    rows_done, pos = 0, 0
    while rows_done < k and pos < len(order):
        usable = np.flatnonzero(np.abs(M[rows_done:][:, order[pos:]]).max(axis=0) >= 1e-8)
        if not len(usable):
            break
        j = int(order[pos + usable[0]])
        pos += int(usable[0]) + 1
        i = rows_done + int(np.argmax(np.abs(M[rows_done:, j])))
        if i != rows_done:
            M[[rows_done, i]] = M[[i, rows_done]]
        M[rows_done] /= M[rows_done, j]
        pivot = M[rows_done].copy()
        M -= np.outer(M[:, j], pivot)
        M[rows_done] = pivot
        rows_done += 1
    M[np.abs(M) < 1e-12] = 0.0
    return [M[i] for i in range(rows_done)]


def test_row_reduction_equals_the_reference_bit_for_bit():
    rng = np.random.default_rng(6)
    for t in range(200):
        p = int(rng.integers(3, 40))
        k = int(rng.integers(1, p))
        M = rng.normal(size=(k, p))
        M[:, rng.random(p) < 0.3] = 0.0  # columns that never pivot
        if t % 3 == 0:
            M[1 % k] = M[0]  # a dependent row
        order = rng.permutation(p)
        if t % 5 == 0:
            order = order[: max(1, p - 3)]  # columns outside the order are reduced, never pivots
        want, got = _rref_reference(M, order), _rref(M, order)
        assert len(got) == len(want) and all(np.array_equal(a, b) for a, b in zip(got, want))


def test_null_and_range_bases_from_one_svd():
    rng = np.random.default_rng(7)
    for p, k in ((45, 18), (7, 1), (5, 0), (6, 6)):
        A = rng.normal(size=(p, k)) * rng.uniform(0.1, 10, p)[:, None]
        N, R = _null_and_range(A)
        assert N.shape == (p, k) and R.shape == (p, p - k)
        Q = np.column_stack([N, R])
        assert np.allclose(Q.T @ Q, np.eye(p), atol=1e-12)
        if k:  # N spans A's columns, as the separate orthonormalization did
            assert np.allclose(N @ N.T, _orth(A) @ _orth(A).T, atol=1e-12)
            assert np.allclose(R.T @ A, 0, atol=1e-12)
        else:
            assert np.array_equal(R, np.eye(p))


def test_twist_coordinates_joint_by_joint_equal_the_pseudo_inverse(ur10_sets):
    nominal, _, _ = ur10_sets
    a = ArmValues.from_model(nominal["arm"])
    v = np.random.default_rng(8).normal(size=a.screws.shape)
    assert np.allclose(a.tangent_coordinates(v), a.basis_pinv @ v.ravel(), rtol=1e-12, atol=1e-14)


def test_degenerate_needs_no_svd_when_the_frames_cannot_reach_the_rank(ur10_sets):
    """The frames' columns alone have at most their number of singular values above the tolerance: fewer than
    the rank, they never reach it (the answer the singular values give, without them)."""
    nominal, ds, _ = ur10_sets
    problem = Problem.build(nominal, [ds], "kinematic", noise=NOISE)
    lin = steps.linearize(problem, problem.start, None, scale_test_needed(problem))
    ana = identify(lin, problem.layout, problem.experiments, report=False)
    arm = np.array([b.arm is not None for b in blocks_of(problem.layout, lin.free)])
    assert 0 < np.count_nonzero(~arm) < ana.rank  # the shortcut applies
    Js = lin.Rf / np.linalg.norm(lin.Rf, axis=0)
    s_all, s_frames = (np.linalg.svd(x, compute_uv=False) for x in (Js, Js[:, ~arm]))
    tol = 1e-9 * s_all[0]
    want = int(np.sum(s_frames > tol)) >= int(np.sum(s_all > tol))
    assert degenerate(lin.Rf, ana.rank, 1e-9, problem.layout, lin.free) is want is False


def test_pose_blocks_batched_equal_their_kinds_block_by_block(ur10_sets):
    """``retract`` and ``displacement`` take the pose blocks' exponentials and logarithms in one batch: what each
    block's kind gives on its own, to round-off."""
    nominal, ds, _ = ur10_sets
    problem = Problem.build(nominal, [ds], "kinematic", noise=NOISE)
    layout, start = problem.layout, problem.start
    delta = problem.full_delta(np.random.default_rng(9).normal(0, 1e-2, len(problem.free_idx)))
    moved = retract(start, layout, delta)
    poses = [b for b in layout.blocks if b.kind.pose_of(b.value(start)) is not None and delta[b.slice].any()]
    assert len(poses) >= 2  # the arm's home and the tracker at least
    for b in poses:
        want = b.kind.pose_of(b.kind.retract(b.value(start), delta[b.slice]))
        assert np.allclose(b.kind.pose_of(b.value(moved)), want, rtol=1e-13, atol=1e-15)
    disp, D = displacement(moved, start, layout)
    for b in layout.blocks:
        x, Db = b.kind.displacement(b.value(moved), b.value(start))
        assert np.allclose(disp[b.slice], x, rtol=1e-10, atol=1e-15)
        assert np.allclose(D[b.slice, b.slice], Db, rtol=1e-10, atol=1e-15)
    assert np.array_equal(displacement(moved, start, layout, jacobian=False)[0], disp)


def test_a_trial_point_retracts_its_screws_only(ur10_sets):
    """``retract(..., tangents=False)`` (a Gauss-Newton trial, a Levenberg-Marquardt residual): the same values,
    bit for bit, without the tangent bases, which ``recentre`` gives back as from the full retraction."""
    nominal, ds, _ = ur10_sets
    problem = Problem.build(nominal, [ds], "kinematic", noise=NOISE)
    delta = problem.full_delta(np.random.default_rng(10).normal(0, 1e-2, len(problem.free_idx)))
    full = retract(problem.start, problem.layout, delta)
    trial = retract(problem.start, problem.layout, delta, tangents=False)
    a, b = full.arms["arm"], trial.arms["arm"]
    assert b.bases is None and b.generators is None  # read by nothing but a Jacobian: would fail loudly
    for name in ("screws", "offsets", "base", "home", "tool"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    ra, rb = recentre(full).arms["arm"], recentre(trial).arms["arm"]
    assert all(np.array_equal(x, y) for x, y in zip(ra.bases + ra.generators, rb.bases + rb.generators))
    W = problem.whiteners(problem.start)
    z = delta[problem.free_idx]
    assert np.array_equal(problem.evaluate(problem.start, z, W, jac=False)[0], problem.evaluate(problem.start, z, W)[0])
