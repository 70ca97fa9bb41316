"""Batch adaptive-DLS inverse kinematics: single arm, closed chain, socket; Jacobians vs differences."""

import numpy as np
import pytest

from kincal.kinematics import forward_kinematics
from kincal.robots import load
from kincal.simulate.generators import BRACKET_90
from kincal.simulate.ik import (
    ClosedChainConstraint,
    PoseConstraint,
    PositionConstraint,
    closure_error,
    solve,
    solve_closed_chain,
    solve_ik,
)
from kincal.testing import numerical_jacobian, random_arm, random_pose


def limited_arm(rng, n, name="arm", limit=2.5):
    return random_arm(rng, n, name=name).replace(lower=np.full(n, -limit), upper=np.full(n, limit))


@pytest.mark.parametrize("n", [6, 7])
def test_single_arm_reaches_targets_within_limits(rng, n):
    arm = limited_arm(rng, n)
    q_true = rng.uniform(-2.0, 2.0, (200, n))
    T = forward_kinematics(arm, q_true)
    res = solve_ik(arm, T, q_true + rng.normal(0, 0.3, q_true.shape))
    assert res.n_converged + res.n_failed == 200
    assert res.n_converged >= 180
    assert np.all(arm.within_limits(res.q))
    T_sol = forward_kinematics(arm, res.q)
    assert np.abs(T_sol[:, :3, 3] - T[res.index, :3, 3]).max() < 1e-10
    assert np.abs(T_sol[:, :3, :3] - T[res.index, :3, :3]).max() < 1e-10
    assert np.all(res.pos_err < 1e-10) and np.all(res.rot_err < 1e-10)


def test_unreachable_targets_are_counted_not_returned(rng):
    arm = limited_arm(rng, 6)
    T = forward_kinematics(arm, rng.uniform(-2, 2, (10, 6)))
    T[:5, :3, 3] += 100.0  # far outside the workspace
    res = solve_ik(arm, T, np.zeros((10, 6)), max_iter=50)
    assert res.n_failed >= 5
    assert not np.any(res.index < 5)
    assert len(res.q) == len(res.index) == res.n_converged


def test_limits_are_respected_when_the_start_is_outside(rng):
    arm = limited_arm(rng, 7, limit=1.0)
    q_true = rng.uniform(-0.9, 0.9, (50, 7))
    res = solve_ik(arm, forward_kinematics(arm, q_true), np.full((50, 7), 3.0))
    assert np.all(arm.within_limits(res.q))


def test_closed_chain_closure_and_limits(rng):
    a, b = limited_arm(rng, 7, "a", 2.8), limited_arm(rng, 7, "b", 2.8)
    C = random_pose(rng, scale=0.1)
    res = solve_closed_chain(a, b, C, rng.uniform(-2.8, 2.8, (300, 7)), rng.uniform(-2.8, 2.8, (300, 7)))
    assert res.n_converged > 150
    qa, qb = res.arms()
    pos, rot = closure_error(a, b, C, qa, qb)
    assert pos.max() < 1e-10 and rot.max() < 1e-10
    assert np.all(a.within_limits(qa)) and np.all(b.within_limits(qb))
    assert np.abs(forward_kinematics(a, qa) @ C - forward_kinematics(b, qb)).max() < 1e-10
    # solved jointly: both arms moved away from their starts
    starts = np.clip(np.concatenate([rng.uniform(-2.8, 2.8, (1, 7))] * 2, axis=1), -2.8, 2.8)
    one = solve_closed_chain(a, b, C, starts[:, :7], starts[:, 7:])
    if one.n_converged:
        moved = np.abs(one.q - starts[one.index]).max(axis=0)
        assert moved[:7].max() > 1e-3 and moved[7:].max() > 1e-3


def test_frida_dual_arm_closed_chain_with_the_bracket(rng):
    frida = load("frida")
    left, right = frida["left"], frida["right"]
    lo, hi = left.lower, left.upper
    res = solve_closed_chain(left, right, BRACKET_90, rng.uniform(lo, hi, (100, 7)), rng.uniform(lo, hi, (100, 7)))
    assert res.n_converged > 50
    pos, rot = closure_error(left, right, BRACKET_90, *res.arms())
    assert pos.max() < 1e-10 and rot.max() < 1e-10


def _check_constraint_jacobian(con, q, minus=None):
    e, J, _, _ = con.residual(q[None], np.arange(1))
    num = numerical_jacobian(lambda x: con.residual(x[None], np.arange(1))[0][0], q, minus=minus)
    np.testing.assert_allclose(J[0], num, atol=1e-6)
    return e


def test_constraint_jacobians_match_finite_differences(rng):
    a, b = random_arm(rng, 7, name="a"), random_arm(rng, 6, name="b")
    q = rng.uniform(-1, 1, 7)
    _check_constraint_jacobian(PoseConstraint(a, random_pose(rng)), q)
    _check_constraint_jacobian(PositionConstraint(a, rng.normal(size=3)), q)
    _check_constraint_jacobian(ClosedChainConstraint(a, b, random_pose(rng)), rng.uniform(-1, 1, 13))


def test_socket_constraint_fixes_position_only(rng):
    arm = limited_arm(rng, 7, limit=2.8)
    p = forward_kinematics(arm, rng.uniform(-1, 1, 7))[:3, 3]
    res = solve(PositionConstraint(arm, p), rng.uniform(-2.8, 2.8, (100, 7)))
    assert res.n_converged > 30
    T = forward_kinematics(arm, res.q)
    assert np.abs(T[:, :3, 3] - p).max() < 1e-10
    assert np.ptp(T[:, 0, 0]) > 0.1  # orientation is free


def test_identical_inputs_identical_output(rng):
    arm = limited_arm(rng, 7)
    T = forward_kinematics(arm, rng.uniform(-2, 2, (20, 7)))
    q0 = rng.uniform(-2.5, 2.5, (20, 7))
    r1, r2 = solve_ik(arm, T, q0), solve_ik(arm, T, q0.copy())
    assert np.array_equal(r1.q, r2.q) and np.array_equal(r1.index, r2.index)


