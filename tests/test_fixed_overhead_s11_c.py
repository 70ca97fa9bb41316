"""Session 11 (helper c): the per-joint paths on Python floats that replace batched numpy calls for an arm's
few joints give the batched paths' numbers bit for bit (signed zeros included), for revolute and prismatic
joints, ties in the helper-axis choice and axis-aligned screws."""

import numpy as np
import pytest

from kincal.kinematics import twists
from kincal.kinematics.twists import conform_twists
from kincal.lie import se3


def _screws(rng, n, types, trial):
    xi = rng.normal(size=(n, 6))
    if trial % 3 == 0:
        xi[:, rng.integers(6)] = 0.0  # axis-aligned: exact zeros in the frames
    if trial % 5 == 0:
        xi = np.round(xi)  # equal magnitudes: the first is the helper axis
    for j, t in enumerate(types):
        part = xi[j, 3:] if t == "revolute" else xi[j, :3]
        if not np.any(part):
            part[0] = 1.0
    return conform_twists(xi, types)


def _bits(a) -> bytes:
    a = np.asarray(a)
    return a.dtype.str.encode() + str(a.shape).encode() + np.ascontiguousarray(a).tobytes()


@pytest.mark.parametrize("prismatic_share", [0.0, 0.4])
def test_joint_frames_per_joint_equal_the_batched_ones(rng, monkeypatch, prismatic_share):
    for trial in range(300):
        n = int(rng.integers(1, 9))
        types = tuple("prismatic" if rng.random() < prismatic_share else "revolute" for _ in range(n))
        xi = _screws(rng, n, types, trial)
        few = se3._compute_frames(xi)
        with monkeypatch.context() as m:
            m.setattr(se3, "_FEW_JOINTS", -1)
            batched = se3._compute_frames(xi)
        assert [_bits(a) for a in few] == [_bits(b) for b in batched]


def test_tangent_frames_per_joint_equal_the_batched_ones(rng):
    for trial in range(300):
        n = int(rng.integers(1, 9))
        xi = _screws(rng, n, ("revolute",) * n, trial)
        B, G = twists.tangent_frames(xi, ("revolute",) * n)
        B2, G2 = twists._revolute_frames(xi[:, :3], xi[:, 3:])
        assert [_bits(b) for b in B] == [_bits(b) for b in B2]
        assert [_bits(g) for g in G] == [_bits(g) for g in G2]


def test_joint_frames_of_many_joints_take_the_batched_path(rng):
    n = se3._FEW_JOINTS + 1
    xi = _screws(rng, n, ("revolute",) * n, 1)
    C, Ci, revolute, AdC, AdCi = se3._compute_frames(xi)
    np.testing.assert_allclose(C @ Ci, np.broadcast_to(np.eye(4), C.shape), atol=1e-15)
    np.testing.assert_array_equal(AdC, se3.adjoint(C))
    np.testing.assert_array_equal(AdCi, se3.adjoint(Ci))


@pytest.mark.parametrize("scale", [1e-9, 1e-3, 0.3, 1.0, 3.0, 10.0])
def test_exp_of_a_few_twists_equals_the_batched_one(rng, monkeypatch, scale):
    for trial in range(200):
        m = int(rng.integers(1, se3._FEW_JOINTS + 1))
        xi = rng.normal(size=(m, 6)) * scale
        if trial % 3 == 0:
            xi[rng.integers(m)] = 0.0  # exp(0) = I
        if trial % 4 == 0:
            xi[:, 3:] = 0.0  # pure translations
        few = se3.exp(xi)
        with monkeypatch.context() as mp:
            mp.setattr(se3, "_FEW_JOINTS", -1)
            batched = se3.exp(xi)
        assert _bits(few) == _bits(batched)


def test_moved_blocks_are_those_with_a_nonzero_coordinate(rng):
    from kincal.params import ops
    from kincal.params.layout import Block
    from kincal.params.kinds import OFFSETS

    sizes = [3, 0, 6, 1, 0, 4]
    starts = np.cumsum([0] + sizes)
    layout = type("L", (), {"blocks": tuple(Block(f"b{i}", OFFSETS, int(a), int(a + s))
                                            for i, (a, s) in enumerate(zip(starts, sizes)))})()
    for _ in range(200):
        delta = rng.normal(size=starts[-1]) * (rng.random(starts[-1]) < 0.2)
        delta[rng.integers(starts[-1])] = -0.0 if rng.random() < 0.5 else np.nan
        want = [b for b in layout.blocks if delta[b.slice].any()]
        assert ops._moved_blocks(layout, delta) == want
    assert ops._moved_blocks(layout, np.zeros(starts[-1])) == []


def test_constant_diagonal_is_the_whiteners_diagonal_exactly_when_nothing_else_is_nonzero():
    from kincal.estimation.problem import _constant_diagonal

    def before(W):  # the test it replaced
        d = np.diagonal(W[0])
        with np.errstate(invalid="ignore"):  # inf - inf
            return d.copy() if not np.any(W[0] - np.diag(d)) else None

    cases = [np.diag([1.0, 2.0, 3.0]), np.diag([1.0, 0.0, 3.0]), np.diag([1.0, np.inf, 3.0]),
             np.diag([1.0, np.nan, 3.0]), np.array([[1.0, 0.0], [1e-300, 2.0]]), np.array([[1.0, np.nan], [0.0, 2.0]]),
             np.array([[1.0, -0.0], [0.0, 2.0]]), np.zeros((2, 2))]
    for D in cases:
        W = np.broadcast_to(D, (4,) + D.shape)
        got, want = _constant_diagonal(W), before(W)
        assert (got is None) == (want is None)
        if want is not None:
            assert _bits(got) == _bits(want)
    assert _constant_diagonal(np.stack([np.eye(2), np.eye(2)])) is None  # one per sample: the product


def test_pose_gap_without_b_gives_the_same_gap_and_a_derivative(rng):
    from kincal.experiments._kernel import pose_gap
    from kincal.testing import random_pose

    TA = np.stack([random_pose(rng) for _ in range(5)])
    TB = np.stack([random_pose(rng) for _ in range(5)])
    r, GA, GB = pose_gap(TA, TB)
    r1, GA1, GB1 = pose_gap(TA, TB, of_b=False)
    assert GB1 is None and GB is not None
    assert _bits(r1) == _bits(r) and _bits(GA1) == _bits(GA)


def test_ad_is_the_two_hats(rng):
    from kincal.lie import so3

    for shape in [(6,), (1, 6), (5, 6), (3, 4, 6), (0, 6)]:
        xi = rng.normal(size=shape)
        xi[..., 1], xi[..., 4] = 0.0, -0.0  # signed zeros stay where they were
        want = np.zeros(shape[:-1] + (6, 6))
        want[..., :3, :3] = want[..., 3:, 3:] = so3.hat(xi[..., 3:])
        want[..., :3, 3:] = so3.hat(xi[..., :3])
        assert _bits(se3.ad(xi)) == _bits(want)


def test_left_jacobian_coefficients_of_a_few_small_angles_are_the_series(rng):
    from kincal.lie import _coeffs

    series = (_coeffs._A1, _coeffs._A2, _coeffs._A3, _coeffs._A4)
    for shape in [(), (1,), (3,), (2, 3), (0,)]:
        theta = np.abs(rng.normal(size=shape)) * 0.3
        got = _coeffs.se3_jl_coeffs(theta)
        for g, c in zip(got, series):
            want = np.vectorize(lambda t: _coeffs._horner_float(c.rest, c.top, t * t), otypes=[float])(theta)
            assert _bits(g) == _bits(np.asarray(want, float))
    theta = np.array([0.2, 1.5])  # one above the branch point: the closed form there, as before
    a1 = _coeffs.se3_jl_coeffs(theta)[0]
    t = 1.5
    assert a1[1] == (4 - t * np.sin(t) - 4 * np.cos(t)) / (2 * t**2)


def test_vee_reads_the_skew_part_entry_by_entry(rng):
    from kincal.lie import so3

    for shape in [(3, 3), (4, 3, 3), (2, 5, 3, 3)]:
        W = rng.normal(size=shape)
        for X in (W, np.swapaxes(W, -1, -2)):  # contiguous or not
            want = 0.5 * np.stack([X[..., 2, 1] - X[..., 1, 2], X[..., 0, 2] - X[..., 2, 0],
                                   X[..., 1, 0] - X[..., 0, 1]], axis=-1)
            assert _bits(so3.vee(X)) == _bits(want)


@pytest.mark.parametrize("step,widths", [(1, (4, 4, 4)), (3, (4, 4)), (1, (4, 2, 4))])
def test_twist_columns_in_one_product_equal_the_joint_by_joint_ones(rng, step, widths):
    from kincal.kinematics.jacobians import _twist_columns

    N, k = 7, 3
    gens = tuple(rng.normal(size=(6, t)) for t in widths)
    M = rng.normal(size=(step * len(gens) + 1, N * k, 6))
    want = np.concatenate([((M[step * j] - M[step * (j + 1)]) @ G).reshape(N, k, -1) for j, G in enumerate(gens)],
                          axis=-1)
    assert _bits(_twist_columns(M, gens, step, N, k)) == _bits(want)


def test_exactness_verdict_per_joint_equals_the_batched_one(rng, monkeypatch):
    for trial in range(2000):
        n = int(rng.integers(1, 9))
        types = tuple("revolute" if rng.random() < 0.7 else "prismatic" for _ in range(n))
        xi = conform_twists(rng.normal(size=(n, 6)), types)
        if trial % 2:
            xi = xi + rng.normal(size=xi.shape) * 10.0 ** rng.uniform(-16, -10)  # near the tolerance
        if trial % 7 == 0:
            xi[rng.integers(n), rng.integers(6)] = np.nan
        tol = (1e-12, 1e-9, 0.0)[trial % 3]
        few = se3._exact(xi, tol)
        with monkeypatch.context() as m:
            m.setattr(se3, "_FEW_JOINTS", -1)
            assert se3._exact(xi, tol) is few


@pytest.mark.parametrize("prismatic", [(), (1,)])
def test_scale_directions_of_arms_with_and_without_prismatic_joints(rng, prismatic):
    from kincal.params import ArmValues
    from kincal.params.kinds import COMPLIANCE, OFFSETS, TWISTS
    from kincal.testing import random_arm
    from dataclasses import replace

    a = ArmValues.from_model(random_arm(rng, 4, prismatic))
    a = replace(a, offsets=rng.normal(size=4), compliance=rng.uniform(1e-6, 1e-5, 4))
    rev = np.array(a.joint_types) == "revolute"
    assert _bits(OFFSETS.scale(a)) == _bits(np.where(~rev, a.offsets, 0.0))
    assert _bits(COMPLIANCE.scale(a)) == _bits(np.where(~rev, a.joint_compliance, -a.joint_compliance))
    v = np.zeros_like(a.screws)
    v[rev, :3] = a.screws[rev, :3]
    assert _bits(TWISTS.scale(a)) == _bits(a.tangent_coordinates(v))


def test_twists_recentre_in_one_replace_is_conform_then_tangents(rng):
    from dataclasses import fields, replace
    from kincal.params import ArmValues
    from kincal.params.kinds import TWISTS, with_arm_poses, HOME
    from kincal.testing import random_arm

    a = ArmValues.from_model(random_arm(rng, 5, (2,)))
    a = replace(a, screws=a.screws + rng.normal(size=a.screws.shape) * 1e-9)  # off the exact screws
    one, two = TWISTS.recentre(a), TWISTS.with_tangents(TWISTS.conform(a))
    assert _bits(one.screws) == _bits(two.screws)
    for name in ("bases", "generators"):
        assert [_bits(u) for u in getattr(one, name)] == [_bits(v) for v in getattr(two, name)]
    for f in fields(a):
        if f.name not in ("screws", "bases", "generators"):
            assert getattr(one, f.name) is getattr(a, f.name)
    T = se3.exp(rng.normal(size=6))
    moved = with_arm_poses(a, [(HOME, T)])
    assert moved.home is T and moved.tool is a.tool and moved.screws is a.screws
