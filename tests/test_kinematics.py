"""Forward kinematics, geometric Jacobians and the identification Jacobian against finite differences."""

import numpy as np
import pytest
from scipy.linalg import expm

from kincal.baselines.identification import identification_jacobian
from kincal.errors import ModelError, ShapeError
from kincal.kinematics import (
    ArmModel,
    body_jacobian,
    chain,
    conform_twists,
    forward_kinematics,
    kinematics,
    space_jacobian,
    tangent_basis,
    tangent_generators,
    tool_jacobians,
)
from kincal.lie import se3
from kincal.testing import numerical_jacobian, pose_minus, random_arm

ARMS = [(6, ()), (7, ()), (3, (1,)), (7, (0, 4))]


def _configs(rng, n, count=5):
    """q = 0, ordinary and large angles (beyond pi)."""
    return np.concatenate([np.zeros((1, n)), rng.uniform(-np.pi, np.pi, (count - 2, n)), rng.uniform(-6, 6, (1, n))])


@pytest.mark.parametrize("n,prismatic", ARMS)
def test_fk_matches_product_of_matrix_exponentials(rng, n, prismatic):
    arm = random_arm(rng, n, prismatic)
    q = _configs(rng, n)
    T = forward_kinematics(arm, q)
    for qi, Ti in zip(q, T):
        ref = arm.base.copy()
        for xi, th in zip(arm.screws, qi + arm.offsets):
            ref = ref @ expm(se3.hat(xi) * th)
        np.testing.assert_allclose(Ti, ref @ arm.home @ arm.tool, atol=1e-13)


@pytest.mark.parametrize("n,prismatic", ARMS)
def test_geometric_jacobians_match_finite_differences(rng, n, prismatic):
    arm = random_arm(rng, n, prismatic)
    for q in _configs(rng, n):
        num_s = numerical_jacobian(lambda x: forward_kinematics(arm, x), q, minus=pose_minus)
        np.testing.assert_allclose(space_jacobian(arm, q), num_s, atol=1e-8)
        num_b = numerical_jacobian(
            lambda x: forward_kinematics(arm, x), q, minus=lambda a, b: se3.log(se3.inverse(b) @ a)
        )
        np.testing.assert_allclose(body_jacobian(arm, q), num_b, atol=1e-8)


def _raw_fk(arm, q, block, delta):
    """Tool pose with ``delta`` added to one parameter block, raw (unconformed) twists allowed."""
    screws, offsets = arm.screws.copy(), arm.offsets.copy()
    poses = {b: getattr(arm, b) for b in ("base", "home", "tool")}
    if block == "twists":
        screws = screws + delta.reshape(-1, 6)
    elif block == "offsets":
        offsets = offsets + delta
    else:
        poses[block] = se3.exp(se3.log(poses[block]) + delta)
    return chain(screws, q + offsets, poses["base"], poses["home"], poses["tool"]).tool


def _moved_fk(arm, q, gens, part, d):
    """Tool pose after the increment d of one part as ``tool_jacobians`` parametrizes it: offsets additive,
    joint screws moved rigidly by ``exp(G_j d_j)``, poses by left increments."""
    screws, offsets = arm.screws.copy(), arm.offsets.copy()
    poses = {b: getattr(arm, b) for b in ("base", "home", "tool")}
    if part == "offsets":
        offsets = offsets + d
    elif part == "twists":
        c = 0
        for j, G in enumerate(gens):
            screws[j] = se3.adjoint(se3.exp(G @ d[c: c + G.shape[1]])) @ screws[j]
            c += G.shape[1]
    else:
        poses[part] = se3.exp(d) @ poses[part]
    return chain(screws, q + offsets, poses["base"], poses["home"], poses["tool"]).tool


@pytest.mark.parametrize("n,prismatic", ARMS)
def test_tool_jacobians_match_finite_differences(rng, n, prismatic):
    arm = random_arm(rng, n, prismatic)
    q = _configs(rng, n, count=5)
    gens = [tangent_generators(s, t) for s, t in zip(arm.screws, arm.joint_types)]
    kin = chain(arm.screws, q + arm.offsets, arm.base, arm.home, arm.tool)
    J, jq = tool_jacobians(kin, np.broadcast_to(np.eye(6), (len(q), 6, 6)), arm.screws, gens)
    np.testing.assert_allclose(jq, space_jacobian(arm, q), atol=1e-12)
    sizes = {"offsets": n, "twists": sum(G.shape[1] for G in gens), "home": 6, "base": 6, "tool": 6}
    for part, size in sizes.items():
        num = numerical_jacobian(lambda d: _moved_fk(arm, q, gens, part, d), np.zeros(size), minus=pose_minus)
        assert J[part].shape == (len(q), 6, size)
        np.testing.assert_allclose(J[part], num, atol=1e-6 * max(1.0, np.abs(num).max()), err_msg=part)
    np.testing.assert_array_equal(J["compliance"], 0.0)  # no load: compliance has no effect


@pytest.mark.parametrize("frame", ["space", "body"])
@pytest.mark.parametrize("n,prismatic", ARMS)
def test_identification_jacobian_matches_finite_differences(rng, n, prismatic, frame):
    arm = random_arm(rng, n, prismatic)
    q = _configs(rng, n, count=6)
    J = identification_jacobian(arm, q, frame=frame)
    if frame == "space":
        minus = pose_minus
    else:
        minus = lambda a, b: se3.log(se3.inverse(b) @ a)  # noqa: E731
    sizes = {"base": 6, "twists": 6 * n, "offsets": n, "home": 6, "tool": 6}
    for block, size in sizes.items():
        num = numerical_jacobian(lambda d: _raw_fk(arm, q, block, d), np.zeros(size), minus=minus)
        ana = getattr(J, block)
        assert ana.shape == (len(q), 6, size)
        rel = np.abs(ana - num).max() / max(1.0, np.abs(num).max())
        assert rel < 1e-6, (block, rel)


def test_identification_jacobian_thesis_layout(rng):
    arm = random_arm(rng, 7)
    q = rng.uniform(-2, 2, (4, 7))
    J = identification_jacobian(arm, q)
    thesis = J.thesis()
    assert thesis.shape == (4, 6, 7 * 7 + 6)
    for i in range(7):
        np.testing.assert_array_equal(thesis[..., 7 * i:7 * i + 6], J.twists[..., 6 * i:6 * i + 6])
        np.testing.assert_array_equal(thesis[..., 7 * i + 6], J.offsets[..., i])
    np.testing.assert_array_equal(thesis[..., -6:], J.home)
    full, names = J.stacked(prefix="right")
    assert full.shape == (4, 6, 6 + 42 + 7 + 6 + 6) and len(names) == full.shape[-1]
    assert names[6] == "right.j1.xi.v_x" and "right.j3.offset" in names and names[-1] == "right.tool.w_z"
    # Offset columns are the space Jacobian.
    np.testing.assert_allclose(J.offsets, space_jacobian(arm, q), atol=1e-15)


def test_thesis_closed_form_A_matches(rng):
    """The thesis' A_i (eq. 2.44) with |w| != 1 equals q J_l(q xi)."""
    xi = se3.join(rng.normal(size=3), 1.3 * rng.normal(size=3))
    q = 0.8
    Om = se3.ad(xi)
    nw = np.linalg.norm(xi[3:])
    t = nw * q
    A = (
        q * np.eye(6)
        + (4 - t * np.sin(t) - 4 * np.cos(t)) / (2 * nw**2) * Om
        + (4 * t - 5 * np.sin(t) + t * np.cos(t)) / (2 * nw**3) * Om @ Om
        + (2 - t * np.sin(t) - 2 * np.cos(t)) / (2 * nw**4) * Om @ Om @ Om
        + (2 * t - 3 * np.sin(t) + t * np.cos(t)) / (2 * nw**5) * Om @ Om @ Om @ Om
    )
    np.testing.assert_allclose(A, q * se3.left_jacobian(q * xi), atol=1e-13)


def test_kinematics_prefixes_and_batch_shapes(rng):
    arm = random_arm(rng, 5)
    q = rng.uniform(-1, 1, (2, 3, 5))
    kin = kinematics(arm, q)
    assert kin.prefixes.shape == (2, 3, 6, 4, 4) and kin.tool.shape == (2, 3, 4, 4)
    np.testing.assert_allclose(kin.tool[1, 2], forward_kinematics(arm, q[1, 2]), atol=1e-15)
    assert forward_kinematics(arm, np.zeros(5)).shape == (4, 4)


def test_conform_twists_unit_axis_zero_pitch(rng):
    w = rng.normal(size=3) * 1.1
    v = rng.normal(size=3)
    c = conform_twists(np.concatenate([v, w])[None], ["revolute"])[0]
    assert abs(np.linalg.norm(c[3:]) - 1) < 1e-15 and abs(c[3:] @ c[:3]) < 1e-15
    # "line" keeps the axis line: the nearest point to the origin is unchanged.
    p_before = np.cross(w, v - (w @ v) / (w @ w) * w) / (w @ w)
    np.testing.assert_allclose(np.cross(c[3:], c[:3]), p_before, atol=1e-15)
    t = conform_twists(np.concatenate([v, w])[None], ["revolute"], mode="thesis")[0]
    np.testing.assert_allclose(t[:3], v - (w @ v) / (w @ w) * w, atol=1e-15)
    p = conform_twists(np.array([[0.0, 0, 2, 0, 0, 0]]), ["prismatic"])[0]
    np.testing.assert_array_equal(p, [0, 0, 1, 0, 0, 0])


def test_tangent_basis_keeps_screws_valid(rng):
    arm = random_arm(rng, 4, prismatic=(2,))
    for xi, kind in zip(arm.screws, arm.joint_types):
        B = tangent_basis(xi, kind)
        assert np.linalg.matrix_rank(B) == B.shape[1]
        for col in B.T:
            moved = xi + 1e-6 * col
            drift = np.abs(conform_twists(moved[None], [kind])[0] - moved).max()
            assert drift < 1e-11  # second order only


def test_bad_inputs_have_clear_errors(rng):
    arm = random_arm(rng, 6)
    with pytest.raises(ShapeError, match=r"expected shape \(\.\.\., 6\), got \(4, 7\)"):
        forward_kinematics(arm, np.zeros((4, 7)))
    q = np.zeros((3, 6))
    q[1, 2] = np.nan
    with pytest.raises(ShapeError, match=r"finite.*index \(1, 2\)"):
        forward_kinematics(arm, q)
    bad = arm.screws.copy()
    bad[1, 3:] *= 1.01
    with pytest.raises(ModelError, match="j2 is revolute and needs a unit axis"):
        arm.replace(screws=bad)
    home = arm.home.copy()
    home[0, 0] += 1e-3
    with pytest.raises(Exception, match="not orthonormal"):
        arm.replace(home=home)
    with pytest.raises(ModelError, match="controller_order"):
        arm.replace(controller_order=(0, 1, 2, 3, 4, 4))
    with pytest.raises(ModelError, match="lower < upper"):
        arm.replace(lower=np.ones(6), upper=np.zeros(6))


def test_model_is_immutable(rng):
    arm = random_arm(rng, 3)
    with pytest.raises(ValueError):
        arm.screws[0, 0] = 1.0
    with pytest.raises(Exception):
        arm.name = "x"
    assert arm == arm.replace() and arm != arm.replace(offsets=np.ones(3))


def test_arm_model_from_plain_lists():
    arm = ArmModel("planar", [[0, 0, 0, 0, 0, 1], [0, -1, 0, 0, 0, 1]], np.eye(4))
    assert arm.dof == 2 and arm.joint_names == ("j1", "j2") and arm.joint_types == ("revolute", "revolute")


def test_tangent_generators_retract_exactly(rng):
    from kincal.kinematics import tangent_generators

    arm = random_arm(rng, 4, prismatic=(1,))
    for xi, kind in zip(arm.screws, arm.joint_types):
        G = tangent_generators(xi, kind)
        np.testing.assert_allclose(-se3.ad(xi) @ G, tangent_basis(xi, kind), atol=1e-15)
        moved = se3.adjoint(se3.exp(G @ rng.normal(scale=0.5, size=G.shape[1]))) @ xi
        np.testing.assert_allclose(conform_twists(moved[None], [kind])[0], moved, atol=1e-14)
