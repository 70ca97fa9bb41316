"""Property tests of the SO(3)/SE(3) layer over batch shapes, near 0 and near pi."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from kincal.lie import se3, so3
from kincal.testing import numerical_jacobian

BATCHES = [(), (1,), (3, 1, 2)]
PINNED_ANGLES = [0.0, 1e-12, 1e-7, 1e-3, 0.5, 1.0 - 1e-9, 1.0 + 1e-9, 2.0, np.pi - 1e-7, np.pi - 1e-12]


@st.composite
def rotation_vectors(draw, batch):
    """Rotation vectors with angle in [0, pi), biased towards 0 and pi on purpose."""
    size = int(np.prod(batch)) if batch else 1
    seed = draw(st.integers(0, 2**32 - 1))
    mode = draw(st.sampled_from(["uniform", "tiny", "near_pi", "pinned"]))
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=(size, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    if mode == "uniform":
        t = rng.uniform(0, np.pi - 1e-6, size)
    elif mode == "tiny":
        t = 10.0 ** rng.uniform(-12, -2, size)
    elif mode == "near_pi":
        t = np.pi - 10.0 ** rng.uniform(-10, -2, size)
    else:
        t = rng.choice(PINNED_ANGLES, size)
    return (axis * t[:, None]).reshape(batch + (3,))


@st.composite
def twists(draw, batch):
    w = draw(rotation_vectors(batch))
    seed = draw(st.integers(0, 2**32 - 1))
    v = np.random.default_rng(seed).uniform(-2, 2, size=w.shape)
    return se3.join(v, w)


@pytest.mark.parametrize("batch", BATCHES)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_so3_exp_log_roundtrip(batch, data):
    w = data.draw(rotation_vectors(batch))
    R = so3.exp(w)
    assert R.shape == batch + (3, 3)
    # R^T R itself is computed with ~3 ulp of round-off per entry: 1e-15 was below what the check can resolve
    np.testing.assert_allclose(np.swapaxes(R, -1, -2) @ R, np.broadcast_to(np.eye(3), R.shape), atol=2e-15)
    np.testing.assert_allclose(so3.log(R), w, atol=2e-15, rtol=0)


@pytest.mark.parametrize("batch", BATCHES)
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_so3_matches_scipy(batch, data):
    w = data.draw(rotation_vectors(batch))
    ref = Rotation.from_rotvec(w.reshape(-1, 3)).as_matrix().reshape(batch + (3, 3))
    np.testing.assert_allclose(so3.exp(w), ref, atol=1e-15)


@pytest.mark.parametrize("batch", BATCHES)
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_se3_exp_matches_expm_and_log_roundtrip(batch, data):
    xi = data.draw(twists(batch))
    T = se3.exp(xi)
    ref = np.stack([expm(se3.hat(x)) for x in xi.reshape(-1, 6)]).reshape(batch + (4, 4))
    np.testing.assert_allclose(T, ref, atol=2e-14)
    np.testing.assert_allclose(se3.log(T), xi, atol=5e-14, rtol=0)


@pytest.mark.parametrize("batch", BATCHES)
@settings(max_examples=30, deadline=None)
@given(data=st.data())
def test_se3_left_jacobian_and_inverse(batch, data):
    xi = data.draw(twists(batch))
    J = se3.left_jacobian(xi)
    # Series definition sum ad^k/(k+1)!, summed far enough to converge for |w| < pi, |v| < 3.5.
    X = se3.ad(xi)
    ref = np.broadcast_to(np.eye(6), J.shape).copy()
    term = np.broadcast_to(np.eye(6), J.shape).copy()
    for k in range(1, 60):
        term = term @ X / (k + 1)
        ref = ref + term
    np.testing.assert_allclose(J, ref, atol=1e-12)
    np.testing.assert_allclose(se3.left_jacobian_inv(xi) @ J, np.broadcast_to(np.eye(6), J.shape), atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 0.7, 2.5, np.pi - 1e-6])
def test_se3_left_jacobian_finite_differences(angle, rng):
    axis = rng.normal(size=3)
    xi = se3.join(rng.uniform(-1, 1, 3), angle * axis / np.linalg.norm(axis))
    num = numerical_jacobian(se3.exp, xi, minus=lambda a, b: se3.log(a @ se3.inverse(b)))
    np.testing.assert_allclose(se3.left_jacobian(xi), num, atol=1e-8)
    num_so3 = numerical_jacobian(so3.exp, xi[3:], minus=lambda a, b: so3.log(a @ np.swapaxes(b, -1, -2)))
    np.testing.assert_allclose(so3.left_jacobian(xi[3:]), num_so3, atol=1e-8)
    np.testing.assert_allclose(so3.left_jacobian_inv(xi[3:]) @ so3.left_jacobian(xi[3:]), np.eye(3), atol=1e-13)


def test_so3_log_exactly_pi_is_a_valid_rotation_vector():
    for axis in np.eye(3):
        R = so3.exp(np.pi * axis)
        w = so3.log(R)
        assert abs(np.linalg.norm(w) - np.pi) < 1e-15
        np.testing.assert_allclose(so3.exp(w), R, atol=1e-15)


@pytest.mark.parametrize("batch", BATCHES)
@settings(max_examples=30, deadline=None)
@given(data=st.data())
def test_adjoint_identities(batch, data):
    xi = data.draw(twists(batch))
    eta = data.draw(twists(batch))
    T = se3.exp(xi)
    # T hat(eta) T^-1 == hat(Ad_T eta)
    lhs = T @ se3.hat(eta) @ se3.inverse(T)
    rhs = se3.hat(np.einsum("...ij,...j->...i", se3.adjoint(T), eta))
    np.testing.assert_allclose(lhs, rhs, atol=1e-12)
    np.testing.assert_allclose(se3.adjoint(se3.inverse(T)), se3.adjoint_inv(T), atol=1e-14)
    np.testing.assert_allclose(se3.inverse(T) @ T, np.broadcast_to(np.eye(4), T.shape), atol=1e-14)
    # ad is the derivative of Ad: Ad(exp(t xi)) = expm(t ad(xi))
    ref = np.stack([expm(a) for a in se3.ad(xi).reshape(-1, 6, 6)]).reshape(batch + (6, 6))
    np.testing.assert_allclose(se3.adjoint(T), ref, atol=1e-12)


def test_hat_vee_roundtrip(rng):
    xi = rng.normal(size=(4, 5, 6))
    np.testing.assert_array_equal(se3.vee(se3.hat(xi)), xi)
    w, b = rng.normal(size=(7, 3)), rng.normal(size=(7, 3))
    np.testing.assert_allclose(np.einsum("...ij,...j->...i", so3.hat(w), b), np.cross(w, b), atol=1e-15)
    np.testing.assert_array_equal(so3.vee(so3.hat(w)), w)



def test_exp_joint_screws_matches_general_exp(rng):
    from kincal.testing import random_arm

    arm = random_arm(rng, 6, prismatic=(2,))
    theta = np.concatenate([np.zeros((1, 6)), rng.uniform(-7, 7, (5, 6)), np.full((1, 6), 1e-9)])
    assert se3.exact_joint_screws(arm.screws)
    np.testing.assert_allclose(se3.exp_joint_screws(arm.screws, theta), se3.exp(arm.screws * theta[..., None]),
                               atol=1e-14)
    bent = arm.screws.copy()
    bent[0, 3:] *= 1.01
    assert not se3.exact_joint_screws(bent)
