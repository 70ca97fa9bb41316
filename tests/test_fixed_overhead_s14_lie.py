"""Session 14 (helper lie): the logarithm of a few poses and its inverse left Jacobian on Python floats, bit for bit.

``se3._few_logs`` is ``_log`` of up to ``_FEW_POSES`` poses whose angles are below the series' branch point, its
elementwise steps on Python floats (the arctangent, ``einsum``'s dot products and the matrix products still
numpy's); ``se3._few_jacobians_inv`` the top right block of ``left_jacobian`` and ``_inverse_blocks`` from it;
``_coeffs.series_at`` and ``_coeffs.jl_coeffs_at`` the series on floats. Each against the batched path it replaces,
on poses at and near the identity, below, at and above the branch point and near pi, and through whole
calibrations (markers, pose, clamp, dual arm, elastic)."""

from __future__ import annotations

import numpy as np
import pytest
from test_fixed_overhead_s12_c import _digest, cases  # noqa: F401 (the structures, the result digest)

from kincal.estimation import Problem, calibrate
from kincal.lie import _coeffs, se3, so3
from kincal.params import clear_caches, displacement, retract


def _same(a, b) -> bool:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def _batched(T):
    """``log_with_jacobian_inv``'s batched path (what it computed before the few-pose one)."""
    x, Ji = se3._log(T)
    return x, se3._inverse_blocks(Ji, se3.left_jacobian(x)[..., :3, 3:])


ANGLES = [0.0, 1e-12, 1e-7, 1e-3, 0.1, 0.7, 0.999, 0.99999999, 1.0, 1.2, 2.5, np.pi - 1e-6, np.pi]


def _poses(rng, angles, shift=1.0):
    w = rng.normal(size=(len(angles), 3))
    w *= np.asarray(angles)[:, None] / np.linalg.norm(w, axis=1, keepdims=True)
    return se3.make(so3.exp(w), rng.normal(size=(len(angles), 3)) * shift)


@pytest.mark.parametrize("angle", ANGLES)
@pytest.mark.parametrize("m", [1, 2, 3, 4, 5, 9, 17])
def test_few_logs_are_the_batched_ones(rng, angle, m):
    for shift in (0.0, 1e-6, 0.05, 3.0):
        angles = rng.uniform(0.5, 1.0, m) * angle
        T = _poses(rng, angles, shift)
        x, J = se3.log_with_jacobian_inv(T)
        x0, J0 = _batched(T)
        assert _same(x, x0) and _same(J, J0), (angle, m, shift)
        assert _same(se3.log(T), x0)
        fast = se3._few_logs(T) is not None
        if fast:  # and ``left_jacobian_inv``'s own (which above the branch point may differ by round-off)
            assert _same(se3.left_jacobian_inv(x), J0)
        # taken where it applies: a few poses, every angle below the branch point
        if m > se3._FEW_POSES or angles.max() > 1.0 + 1e-9:
            assert not fast, (angle, m)
        elif angles.max() < 1.0 - 1e-9:
            assert fast, (angle, m)


def test_many_random_few_pose_batches(rng):
    """``einsum``'s sums depend on the arrays' layout and a one-ulp change of an angle seldom moves a series' value:
    thousands of batches, results and their layouts against the batched path's."""
    for k in range(2000):
        m = int(rng.integers(1, se3._FEW_POSES + 1))
        T = _poses(rng, rng.uniform(0.2, 1.0, m) * [1e-9, 1e-3, 0.1, 0.5, 0.9, 0.999][k % 6], [1e-6, 0.01, 1.0][k % 3])
        x, J = se3.log_with_jacobian_inv(T)
        x0, J0 = _batched(T)
        assert _same(x, x0) and _same(J, J0) and x.strides == x0.strides and J.strides == J0.strides, k
        assert se3._few_logs(T) is not None


def test_identity_and_mixed_batches(rng):
    cases = [np.eye(4)[None], np.stack([np.eye(4)] * 3), _poses(rng, [0.0, 0.3, 0.0]),
             _poses(rng, [0.2, 3.0, 1e-9]),  # one near pi: the batched path for all
             _poses(rng, rng.uniform(0, 0.9, 16), 1e-3)]
    for T in cases:
        x, J = se3.log_with_jacobian_inv(T)
        x0, J0 = _batched(T)
        assert _same(x, x0) and _same(J, J0)
    x, J = se3.log_with_jacobian_inv(np.eye(4)[None])
    assert _same(x, np.zeros((1, 6))) and _same(J, np.eye(6)[None])


def test_other_shapes_take_the_batched_path(rng):
    T = _poses(rng, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    for X in (T[0], T.reshape(2, 3, 4, 4), T[:0]):
        assert se3._few_logs(X) is None
        x, J = se3.log_with_jacobian_inv(X)
        x0, J0 = _batched(X)
        assert _same(x, x0) and _same(J, J0)


def test_few_logs_invert_exp_and_the_jacobian(rng):
    xi = rng.normal(size=(5, 6)) * 0.2
    x, J = se3.log_with_jacobian_inv(se3.exp(xi))
    assert np.allclose(x, xi, atol=1e-12)
    assert np.allclose(J @ se3.left_jacobian(xi), np.eye(6), atol=1e-12)


def test_series_on_floats_are_the_batched_ones(rng):
    ts = [0.0, 1e-9, 1e-4, 0.3, 0.999999, *rng.uniform(0.0, 1.0, 20).tolist()]
    for s, f in ((_coeffs._SIN_OVER_T, _coeffs.sin_over_t), (_coeffs._LOG_D, _coeffs.log_coeff)):
        assert _same(_coeffs.series_at(s, ts), _coeffs._horner(s.values, np.array(ts) ** 2))
        assert _same(_coeffs.series_at(s, ts[:3]), f(np.array(ts[:3])))
    plain = [_coeffs._horner(c.values, np.array(ts) ** 2) for c in (_coeffs._A1, _coeffs._A2, _coeffs._A3, _coeffs._A4)]
    assert _same(np.array(_coeffs.jl_coeffs_at(ts)).T, np.array(plain))
    assert _same(np.array(_coeffs.jl_coeffs_at(ts[:4])).T, np.array(_coeffs.se3_jl_coeffs(np.array(ts[:4]))))


def test_displacement_with_and_without_the_few_pose_path(monkeypatch, cases, rng):
    for name, robot, sets, free, noise in cases:
        p = Problem.build(robot, sets, free, noise=noise)
        state = retract(p.nominal, p.layout, rng.normal(size=p.layout.size) * 1e-2)
        fast = [displacement(state, p.nominal, p.layout, jacobian=j) for j in (True, False)]
        with monkeypatch.context() as m:
            m.setattr(se3, "_few_logs", lambda T: None)
            plain = [displacement(state, p.nominal, p.layout, jacobian=j) for j in (True, False)]
        assert _same(fast[0][0], plain[0][0]) and _same(fast[0][1], plain[0][1]), name
        assert _same(fast[1][0], plain[1][0]) and fast[1][1] is None, name


def test_calibrations_with_and_without_the_few_pose_path(monkeypatch, cases):
    for name, robot, sets, free, noise in cases:
        clear_caches()
        shipped = _digest(calibrate(robot, sets, free, noise=noise))
        with monkeypatch.context() as m:
            m.setattr(se3, "_few_logs", lambda T: None)
            clear_caches()
            plain = _digest(calibrate(robot, sets, free, noise=noise))
        assert shipped == plain, name


def test_the_comparison_can_fail(monkeypatch, cases, rng):
    """The pose blocks' estimates come from the few-pose logarithm: off by round-off, the digest differs. (Their
    std, from its Jacobian, are nan in these gauge-free models: the Jacobian is held by ``displacement``'s D.)"""
    _, robot, sets, free, noise = cases[0]
    shipped = _digest(calibrate(robot, sets, free, noise=noise))
    few, inv = se3._few_logs, se3._few_jacobians_inv
    with monkeypatch.context() as m:
        m.setattr(se3, "_few_logs", lambda T: None if (r := few(T)) is None else (r[0] * (1 + 1e-15), *r[1:]))
        assert _digest(calibrate(robot, sets, free, noise=noise)) != shipped
    p = Problem.build(robot, sets, free, noise=noise)
    state = retract(p.nominal, p.layout, rng.normal(size=p.layout.size) * 1e-2)
    D = displacement(state, p.nominal, p.layout)[1]
    with monkeypatch.context() as m:
        m.setattr(se3, "_few_jacobians_inv", lambda *a: inv(*a) * (1 + 1e-15))
        assert not _same(displacement(state, p.nominal, p.layout)[1], D)


def _with_priors(case):
    """(robot, data, free) and the keywords of a calibration with priors on its poses."""
    from kincal.params import Prior

    _, robot, sets, free, noise = case
    return (robot, sets, free), dict(noise=noise, priors={"tracker": Prior(1e-3), "arm.home": Prior(1e-3)})


def test_calibration_with_pose_priors(monkeypatch, cases):
    """Priors on poses: the displacement and its Jacobian at every evaluation, the std of the pose blocks finite
    (so the reported std hold the few-pose Jacobian): the same digest with and without the few-pose path, and a
    Jacobian off by round-off shows."""
    args, kw = _with_priors(cases[0])
    res = calibrate(*args, **kw)
    assert any(np.isfinite(e.std) for e in res.estimates if e.name.startswith("tracker."))
    shipped = _digest(res)
    with monkeypatch.context() as m:
        m.setattr(se3, "_few_logs", lambda T: None)
        assert _digest(calibrate(*args, **kw)) == shipped
    inv = se3._few_jacobians_inv
    with monkeypatch.context() as m:
        m.setattr(se3, "_few_jacobians_inv", lambda *a: inv(*a) * (1 + 1e-15))
        assert _digest(calibrate(*args, **kw)) != shipped
