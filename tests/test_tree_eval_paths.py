"""The fast paths of a loaded chain's evaluation (bench/bench_tree_eval.py) give what the plain ones give: the
expanded chain at its unloaded values, the world axes, a joint's twist columns over its three screws (lateral
compliance) and the weights' torque derivatives projected through C. (Each Jacobian is also checked against
finite differences in test_gravity, test_lateral, test_tree and test_tree_gravity.)"""

import numpy as np
import pytest

from kincal.kinematics.elastic import loaded_chain
from kincal.kinematics.fk import chain, expanded_chain, space_axes
from kincal.kinematics.gravity import gravity_load
from kincal.kinematics.jacobians import TOOL_PARTS, tool_jacobians, torque_derivatives
from kincal.kinematics.lateral import expand_screws, expand_values
from kincal.lie import se3
from kincal.params import ArmValues
from test_gravity import _heavy
from test_residuals import _robot


def _arm(rng):
    model = _heavy(_robot(rng, compliance=0.002), rng)["a"]
    return model.replace(lateral=rng.uniform(0, 0.002, (model.dof, 2)))


def test_the_expanded_chain_and_the_world_axes_equal_the_plain_computation(rng):
    a = _arm(rng)
    q = rng.uniform(-2, 2, (5, a.dof))
    screws = expand_screws(a.screws, a.lateral_axes)
    plain = chain(screws, expand_values(q, 0.0), a.base, a.home, a.tool)
    fast = expanded_chain(a.screws, q, a.base, a.home, a.tool)
    for field in ("theta", "exps", "prefixes", "flange", "tool"):
        np.testing.assert_array_equal(getattr(fast, field), getattr(plain, field), err_msg=field)
    axes = np.einsum("...kij,kj->...ki", se3.adjoint(plain.prefixes[:, :-1]), screws)
    np.testing.assert_allclose(space_axes(plain.prefixes, screws), axes, rtol=0, atol=1e-14)


@pytest.mark.parametrize("wrench", [False, True])
def test_a_joints_twist_columns_over_its_three_screws_sum_the_screws_own(rng, wrench):
    """``tool_jacobians(step=3)`` (a joint's generator moves its three screws) against the expanded chain's
    per-screw columns with each generator repeated, summed per joint (offsets and readings: the first screw)."""
    a = _arm(rng)
    N = 6
    q = rng.uniform(-2, 2, (N, a.dof))
    w = rng.normal(size=(N, 6)) if wrench else None
    kin = loaded_chain(a.screws, q + a.offsets, a.base, a.home, a.tool, a.compliance, w, gravity_load(a),
                       lateral=(a.lateral_axes, a.lateral))
    vals = ArmValues.from_model(a)
    screws = expand_screws(vals.screws, vals.lateral_axes)
    coeffs = expand_values(vals.joint_compliance, vals.lateral)
    G = rng.normal(size=(N, 3, 6))
    fast, jq = tool_jacobians(kin, G, screws, vals.generators, coeffs, TOOL_PARTS, True, None, 3)
    slow, jq3 = tool_jacobians(kin, G, screws, tuple(g for g in vals.generators for _ in range(3)), coeffs,
                               TOOL_PARTS, True, None, 1)
    widths = [g.shape[1] for g in vals.generators]
    cut = np.cumsum([3 * w for w in widths])[:-1]
    summed = np.concatenate([sum(np.split(J, 3, axis=-1)) for J in np.split(slow["twists"], cut, axis=-1)], axis=-1)
    scale = np.abs(summed).max()
    np.testing.assert_allclose(fast["twists"], summed, rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(fast["offsets"], slow["offsets"][..., 0::3], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(jq, jq3[..., 0::3], rtol=1e-12, atol=1e-15)
    for p in ("home", "base", "tool", "compliance"):
        np.testing.assert_allclose(fast[p], slow[p], rtol=1e-12, atol=1e-15, err_msg=p)


def test_projected_torque_derivatives_are_the_projection_of_the_derivatives(rng):
    a = _heavy(_robot(rng, compliance=0.002), rng)["a"]
    vals = ArmValues.from_model(a)
    q = rng.uniform(-2, 2, (4, a.dof))
    kin = loaded_chain(a.screws, q + a.offsets, a.base, a.home, a.tool, a.compliance, rng.normal(size=(4, 6)),
                       gravity_load(a))
    parts = ("offsets", "twists", "home", "tool", "base")
    C = rng.normal(size=(4, 3, a.dof))
    D, CD = torque_derivatives(kin, vals.generators, parts), torque_derivatives(kin, vals.generators, parts, 1, C)
    for p in parts:
        np.testing.assert_allclose(CD[p], C @ D[p], rtol=1e-12, atol=1e-12 * np.abs(CD[p]).max(), err_msg=p)
