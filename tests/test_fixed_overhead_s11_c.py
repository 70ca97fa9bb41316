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
