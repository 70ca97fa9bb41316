"""Session 14 (init): the start values of a calibration and the calibrated robot with fewer numpy calls.

``fit_transform`` of one set of points takes a path without the batch axes' handling (one sum and one
subtraction of both sets side by side); held here to the batch path (a stack of one) bit for bit, reflected
best fits included."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.experiments._kernel import fit_transform


@pytest.mark.parametrize("K", [1, 2, 3, 4, 7, 50, 300])
def test_one_fit_is_the_batch_fit(K):
    rng = np.random.default_rng(K)
    for trial in range(60):
        a = rng.normal(size=(K, 3)) * rng.uniform(0.01, 3)
        Q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        b = a @ Q.T + rng.normal(size=3) + rng.normal(size=(K, 3)) * rng.uniform(0, 1)
        if trial % 3 == 0:  # a mirror image: the best orthogonal fit is a reflection, made proper
            b[:, 0] *= -1
        one = fit_transform(a, b)
        assert one.shape == (4, 4)
        assert one.tobytes() == fit_transform(a[None], b[None])[0].tobytes()
        if K >= 3:
            assert np.linalg.det(one[:3, :3]) > 0


def test_one_fit_recovers_a_transform():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(20, 3))
    Q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    Q *= np.sign(np.linalg.det(Q))
    T = fit_transform(a, a @ Q.T + [0.1, -0.2, 0.3])
    np.testing.assert_allclose(T[:3, :3], Q, atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], [0.1, -0.2, 0.3], atol=1e-12)
    assert T[3].tolist() == [0.0, 0.0, 0.0, 1.0]
