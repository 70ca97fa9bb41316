"""Compliance of coupled joints (``kinematics.elastic.deflection``): a coupled joint has no drive of its own, so
the drives of the joints it follows hold its torque too (virtual work), their deflections move it through the
coupling, and its own compliance is the mechanism's. Agile Justin's torso: t4 = -t2 - t3 (passive)."""

import numpy as np

from kincal.kinematics.couplings import coupling_map
from kincal.kinematics.elastic import compliance_columns, deflection, deflection_map
from kincal.kinematics.lateral import expand_coupling

NAMES = ("t1", "t2", "t3", "t4")
A = coupling_map({"t4": {"t2": -1.0, "t3": -1.0}}, NAMES)[0]


def test_the_drives_hold_the_coupled_joints_torque_and_move_it(rng):
    c, tau = rng.uniform(1e-4, 1e-3, 4), rng.normal(scale=50.0, size=(5, 4))
    d = deflection(c, tau, A)
    drive2, drive3 = c[1] * (tau[:, 1] - tau[:, 3]), c[2] * (tau[:, 2] - tau[:, 3])
    np.testing.assert_allclose(d[:, 0], c[0] * tau[:, 0], rtol=1e-14)
    np.testing.assert_allclose(d[:, 1], drive2, rtol=1e-14)
    np.testing.assert_allclose(d[:, 2], drive3, rtol=1e-14)
    np.testing.assert_allclose(d[:, 3], -drive2 - drive3 + c[3] * tau[:, 3], rtol=1e-12)
    # a rigid mechanism (c_4 = 0) keeps the coupling: the deflections obey t4 = -t2 - t3 themselves
    d0 = deflection(np.r_[c[:3], 0.0], tau, A)
    np.testing.assert_allclose(d0[:, 3], -d0[:, 1] - d0[:, 2], rtol=1e-12)
    np.testing.assert_allclose(deflection(c, tau, None), c * tau)  # no coupling: each joint its own torque


def test_the_compliance_map_is_symmetric_and_its_derivatives_are_exact(rng):
    """Deflection = M tau with M symmetric positive semi-definite (a complementary energy 1/2 tau^T M tau);
    ``deflection_map`` and ``compliance_columns`` are its derivatives in tau and in c, per sample."""
    c = rng.uniform(1e-4, 1e-3, 4)
    M = deflection(c, np.eye(4), A)
    np.testing.assert_allclose(M, M.T, atol=1e-18)
    assert np.linalg.eigvalsh(M).min() > -1e-18
    jq, tau = rng.normal(size=(3, 2, 4)), rng.normal(size=(3, 4))
    np.testing.assert_allclose(deflection_map(jq, c, A), jq @ M, rtol=1e-12)
    h = 1e-7
    num = np.stack([(deflection(c + h * e, tau, A) - deflection(c - h * e, tau, A)) / (2 * h) for e in np.eye(4)], -1)
    np.testing.assert_allclose(compliance_columns(jq, tau, A), jq @ num, rtol=1e-8, atol=1e-12)


def test_lateral_joints_are_never_coupled():
    X = expand_coupling(A)
    assert X.shape == (12, 12)
    np.testing.assert_array_equal(X[0::3, 0::3], A)
    lateral = np.r_[1:12:3, 2:12:3]
    np.testing.assert_array_equal(X[np.ix_(lateral, lateral)], np.eye(8))
    assert expand_coupling(None) is None
