"""The std of a reported twist (issue #14): the value is the displacement from nominal, so its std is the
covariance (tangent coordinates at the estimate) propagated through the displacement's Jacobian; for an axis
moved far from nominal the two coordinate systems differ (tilt_1 and tilt_2 look swapped)."""

from __future__ import annotations

import numpy as np

from kincal import robots
from kincal.estimation import Noise, calibrate
from kincal.kinematics import Robot
from kincal.lie import se3, so3
from kincal.params import displacement, retract
from kincal.simulate import generate_pose

NOISE = Noise(position=2e-5, orientation=2e-5)


def test_the_std_of_a_far_moved_twist_is_the_std_of_its_reported_displacement():
    nominal = robots.load("ur10")
    arm = nominal["arm"]
    screws = arm.screws.copy()  # the elbow axis tilted by 0.58 rad and shifted by 5 cm
    screws[2] = se3.adjoint(se3.make(so3.exp(np.array([0.0, 0.5, 0.3])), [0.05, 0.02, 0.0])) @ screws[2]
    ds, _, _ = generate_pose(Robot("ur10", {"arm": arm.replace(screws=screws)}), "arm", n=30, rng=1, noise=NOISE,
                             known_tracker=True)
    res = calibrate(nominal, [ds], ["arm.elbow.xi.*"], noise=NOISE)
    assert res.status == "converged"
    problem, layout, free = res.problem, res.problem.layout, res.problem.free_idx

    def reported(d):  # the reported values at local coordinates d around the estimate
        full = np.zeros(layout.size)
        full[free] = d
        return displacement(retract(res.state, layout, full), problem.nominal, layout, free, jacobian=False)[0][free]

    values = np.array([e.value for e in res.estimates])
    std = np.array([e.std for e in res.estimates])
    np.testing.assert_allclose(reported(np.zeros(len(free))), values, atol=1e-15)
    assert abs(values[3]) > 0.25  # a large move
    h = 1e-6
    J = np.column_stack([(reported(h * e) - reported(-h * e)) / (2 * h) for e in np.eye(len(free))])
    np.testing.assert_allclose(std, np.sqrt(np.diag(J @ res.covariance @ J.T)), rtol=1e-6)
    samples = np.random.default_rng(0).multivariate_normal(np.zeros(len(free)), res.covariance, 2000)
    np.testing.assert_allclose(np.array([reported(s) for s in samples]).std(axis=0), std, rtol=0.06)
    tangent = np.sqrt(np.diag(res.covariance))
    assert np.max(np.abs(tangent / std - 1)) > 0.15  # what was reported before: the tangent coordinates' std
