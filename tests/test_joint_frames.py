"""Forward kinematics and the tool Jacobian's prefix projections through the joints' frames
(``se3.joint_frames``: ``exp(xi t) = C Z(t) C^-1``) against the plain products of joint exponentials and the
per-prefix projection, for revolute and prismatic joints, joints at zero in every sample, batch shapes and a
base per sample; and the tool Jacobian of such chains against finite differences."""

import numpy as np
import pytest

from kincal.kinematics import tangent_generators
from kincal.kinematics.elastic import loaded_chain
from kincal.kinematics.fk import _product_prefixes, chain
from kincal.kinematics.jacobians import _project_prefixes, prefix_projections, tool_jacobians
from kincal.lie import se3
from kincal.testing import numerical_jacobian, pose_minus, random_arm, random_pose
from test_kinematics import _moved_fk

ARMS = [(6, ()), (3, (1,)), (7, (0, 4))]


@pytest.mark.parametrize("n,prismatic", ARMS)
def test_joint_frames_give_each_joints_exponential(rng, n, prismatic):
    arm = random_arm(rng, n, prismatic)
    C, Ci, revolute, AdC, AdCi = se3.joint_frames(arm.screws)
    np.testing.assert_array_equal(revolute, [j not in prismatic for j in range(n)])
    np.testing.assert_allclose(C @ Ci, np.broadcast_to(np.eye(4), C.shape), atol=1e-15)
    np.testing.assert_allclose(AdC, se3.adjoint(C), rtol=0, atol=0)
    np.testing.assert_allclose(AdCi, se3.adjoint(Ci), rtol=0, atol=0)
    t = rng.uniform(-2, 2, n)
    Z = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    c, s = np.cos(t), np.sin(t)
    Z[revolute, 0, 0], Z[revolute, 0, 1], Z[revolute, 1, 0], Z[revolute, 1, 1] = (
        c[revolute], -s[revolute], s[revolute], c[revolute])
    Z[~revolute, 2, 3] = t[~revolute]
    np.testing.assert_allclose(C @ Z @ Ci, se3.exp_joint_screws(arm.screws, t), atol=1e-14)


@pytest.mark.parametrize("n,prismatic", ARMS)
def test_the_chain_through_joint_frames_equals_the_product_of_exponentials(rng, n, prismatic):
    arm = random_arm(rng, n, prismatic)
    q = rng.uniform(-3, 3, (4, 5, n))
    q[..., n // 2] = 0.0  # a joint at zero in every sample: its prefix is the last one, exactly
    kin = chain(arm.screws, q, arm.base, arm.home, arm.tool)
    plain = _product_prefixes(arm.screws, q, arm.base)
    assert kin.prefixes.shape == (4, 5, n + 1, 4, 4)
    np.testing.assert_allclose(kin.prefixes, plain, rtol=0, atol=1e-13)
    np.testing.assert_array_equal(kin.prefixes[..., n // 2 + 1, :, :], kin.prefixes[..., n // 2, :, :])
    np.testing.assert_allclose(kin.tool, plain[..., -1, :, :] @ arm.home @ arm.tool, rtol=0, atol=1e-13)
    np.testing.assert_array_equal(kin.exps, se3.exp_joint_screws(arm.screws, q))  # read on demand
    one = chain(arm.screws, q[1, 2], arm.base, arm.home, arm.tool)  # no batch dimension
    assert one.prefixes.shape == (n + 1, 4, 4)
    np.testing.assert_allclose(one.prefixes, plain[1, 2], rtol=0, atol=1e-13)


@pytest.mark.parametrize("n,prismatic", ARMS)
@pytest.mark.parametrize("base_per_sample", [False, True])
def test_prefix_projections_through_joint_frames_equal_the_per_prefix_projection(rng, n, prismatic,
                                                                                 base_per_sample):
    arm = random_arm(rng, n, prismatic)
    N = 7
    q = rng.uniform(-3, 3, (N, n))
    q[:, 0] = 0.0
    base = random_pose(rng, (N,)) if base_per_sample else arm.base
    kin = chain(arm.screws, q, base, arm.home, arm.tool)
    G = rng.normal(size=(N, 4, 6))
    M = prefix_projections(kin, G)
    direct = _project_prefixes(G, kin.prefixes)
    np.testing.assert_allclose(M, direct, rtol=0, atol=1e-13 * np.abs(direct).max())
    np.testing.assert_array_equal(M[1], M[0])  # the joint at zero


def test_raw_twists_take_the_plain_paths(rng):
    arm = random_arm(rng, 6, ())
    screws = arm.screws * 1.01  # not unit: no joint frames
    q = rng.uniform(-3, 3, (5, 6))
    kin = chain(screws, q, arm.base, arm.home, arm.tool)
    np.testing.assert_array_equal(kin.prefixes, _product_prefixes(screws, q, arm.base))
    G = rng.normal(size=(5, 3, 6))
    np.testing.assert_array_equal(prefix_projections(kin, G), _project_prefixes(G, kin.prefixes))


@pytest.mark.parametrize("n,prismatic", ARMS)
def test_tool_jacobians_with_a_joint_at_zero_match_finite_differences(rng, n, prismatic):
    """The joint-frame projections where a joint sits at zero in every sample (skipped), against finite
    differences of the tool pose (``test_kinematics`` checks them at generic angles)."""
    arm = random_arm(rng, n, prismatic)
    N = 4
    q = rng.uniform(-2, 2, (N, n))
    q[:, -1] = -arm.offsets[-1]  # theta = 0 at the last joint in every sample
    gens = [tangent_generators(s, t) for s, t in zip(arm.screws, arm.joint_types)]
    kin = chain(arm.screws, q + arm.offsets, arm.base, arm.home, arm.tool)
    J, jq = tool_jacobians(kin, np.broadcast_to(np.eye(6), (N, 6, 6)), arm.screws, gens)
    sizes = {"offsets": n, "twists": sum(g.shape[1] for g in gens), "home": 6, "tool": 6}
    for part, size in sizes.items():
        num = numerical_jacobian(lambda d: _moved_fk(arm, q, gens, part, d), np.zeros(size), minus=pose_minus)
        np.testing.assert_allclose(J[part], num, atol=1e-6 * max(1.0, np.abs(num).max()), err_msg=part)
    np.testing.assert_allclose(jq, J["offsets"], rtol=0, atol=0)


def test_the_chain_keeps_the_turns_of_its_joints(rng):
    arm = random_arm(rng, 6, (2,))
    q = rng.uniform(-3, 3, (5, 6))
    kin = chain(arm.screws, q, arm.base, arm.home, arm.tool)
    np.testing.assert_array_equal(kin.turns[0], np.cos(q))
    np.testing.assert_array_equal(kin.turns[1], np.sin(q))



def test_a_loaded_chain_keeps_the_products_of_exponentials(rng):
    """A loaded chain (``elastic.loaded_chain``) and its projections keep the plain computations, bit for bit."""
    arm = random_arm(rng, 6, ())
    q = rng.uniform(-2, 2, (5, 6))
    kin = loaded_chain(arm.screws, q, arm.base, arm.home, arm.tool, np.full(6, 1e-3), rng.normal(size=(5, 6)))
    np.testing.assert_array_equal(kin.prefixes, _product_prefixes(arm.screws, kin.theta, arm.base))
    np.testing.assert_array_equal(kin.unloaded.prefixes, _product_prefixes(arm.screws, q, arm.base))
    G = rng.normal(size=(5, 3, 6))
    np.testing.assert_array_equal(prefix_projections(kin, G), _project_prefixes(G, kin.prefixes))
