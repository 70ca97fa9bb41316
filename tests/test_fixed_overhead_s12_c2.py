"""Session 12, round 2 (helper c2): the Lie kernel with fewer numpy and Python calls, bit for bit.

``_coeffs.exp_coeffs`` evaluates the three series of a few exponentials in one loop (``se3._few_exps``);
``_coeffs._few_small`` lets ``_branch`` and ``se3_jl_coeffs`` check and square a few angles on Python floats;
``se3.log_with_jacobian_inv`` is ``log`` and ``left_jacobian_inv`` with the rotation's inverse Jacobian computed
once (``ops.displacement``, the pose kinds' ``displacement``); ``problem.triangular_factor`` reads the triangle's
mask from a constant table. Each against the calls it replaces, on angles below,
at and above the series' branch point and near pi, and through whole calibrations (markers, pose, clamp, dual arm,
elastic)."""

from __future__ import annotations

import numpy as np
import pytest
from test_fixed_overhead_s12_c import _digest, cases  # noqa: F401 (the structures, the result digest)

from kincal.estimation import calibrate
from kincal.estimation import problem as P
from kincal.lie import _coeffs, se3, so3
from kincal.params import clear_caches, displacement
from kincal.params import kinds as K

ANGLES = [np.zeros(0), np.array([0.0]), np.array([1e-9, 1e-4, 0.3, 0.999999]), np.array([1.0]),
          np.array([0.2, 1.5, 3.0]), np.linspace(0.0, 0.9, 17), np.linspace(0.0, 3.1, 40), np.array([np.nan, 0.1])]


def _plain_exp_coeffs(t):
    return tuple(f(t).tolist() for f in (_coeffs.sin_over_t, _coeffs.one_minus_cos_over_t2,
                                          _coeffs.t_minus_sin_over_t3))


def _plain_log_with_jacobian_inv(T):
    x = se3.log(T)
    return x, se3.left_jacobian_inv(x)


def _same(a, b) -> bool:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("t", ANGLES, ids=range(len(ANGLES)))
def test_exp_coeffs_are_the_three_series(t):
    fast, plain = _coeffs.exp_coeffs(t), _plain_exp_coeffs(t)
    assert len(fast) == 3 and all(_same(f, p) for f, p in zip(fast, plain))


@pytest.mark.parametrize("t", ANGLES + [np.float64(0.3), np.float64(1.2), np.full((2, 3), 0.4), np.full((2, 9), 0.4)],
                         ids=range(len(ANGLES) + 4))
def test_series_of_a_few_angles_are_the_batched_ones(t):
    """``_branch`` and ``se3_jl_coeffs`` on Python floats for a few small angles: numpy's Horner bit for bit."""
    t = np.asarray(t)
    for s, f in ((_coeffs._SIN_OVER_T, _coeffs.sin_over_t), (_coeffs._LOG_D, _coeffs.log_coeff)):
        fast = f(t)
        small = t < _coeffs._TAYLOR_BELOW
        plain = np.where(small, _coeffs._horner(s.values, np.atleast_1d(t * t)).reshape(t.shape), fast)
        assert _same(fast, plain) and np.shape(fast) == t.shape
    jl = _coeffs.se3_jl_coeffs(t)
    for c, a in zip((_coeffs._A1, _coeffs._A2, _coeffs._A3, _coeffs._A4), jl):
        plain = np.where(t < _coeffs._TAYLOR_BELOW, _coeffs._horner(c.values, np.atleast_1d(t * t)).reshape(t.shape), a)
        assert _same(a, plain) and np.shape(a) == t.shape


def test_few_exponentials_are_the_batched_ones(rng):
    for scale in (1e-6, 1e-2, 0.5, 2.0):
        xi = rng.normal(size=(16, 6)) * scale
        few = se3.exp(xi)
        many = se3.exp(np.concatenate([xi, xi, xi]))[:16]  # above ``_FEW_JOINTS``: numpy's batched path
        assert _same(few, many), scale


def _poses(rng, n):
    """Poses with rotations tiny, ordinary, above pi/2 and near pi (``so3.log``'s every branch)."""
    w = rng.normal(size=(n, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    t = np.resize([1e-10, 1e-3, 0.7, 2.0, np.pi - 1e-7, np.pi], n)
    return se3.make(so3.exp(w * t[:, None]), rng.normal(size=(n, 3)))


def test_log_with_jacobian_inv_is_the_two_calls(rng):
    T = _poses(rng, 12)
    for X in (T, T[:3], T[:1], T[4], T[:6].reshape(2, 3, 4, 4)):
        x, J = se3.log_with_jacobian_inv(X)
        x0, J0 = _plain_log_with_jacobian_inv(X)
        assert _same(x, x0) and _same(J, J0)
    # the inverse of the left Jacobian indeed
    x, J = se3.log_with_jacobian_inv(T[:4])
    assert np.allclose(J @ se3.left_jacobian(x), np.eye(6), atol=1e-9)


def test_displacement_is_the_log_and_its_inverse_jacobian(cases, rng):
    from kincal.estimation import Problem
    from kincal.params import retract

    for name, robot, sets, free, noise in cases:
        p = Problem.build(robot, sets, free, noise=noise)
        state = retract(p.nominal, p.layout, rng.normal(size=p.layout.size) * 1e-2)
        disp, D = displacement(state, p.nominal, p.layout)
        poses = [b for b in p.layout.blocks if b.kind.pose_of(b.value(state)) is not None]
        for b in poses:
            T, T0 = b.kind.pose_of(b.value(state)), b.kind.pose_of(b.value(p.nominal))
            x, J = _plain_log_with_jacobian_inv(T @ se3.inverse(T0))
            assert _same(disp[b.slice], x) and _same(D[b.slice, b.slice], J), (name, b.name)
            x1, J1 = b.kind.displacement(b.value(state), b.value(p.nominal))
            assert _same(x1, x) and _same(J1, J), (name, b.name)


def test_calibrations_give_what_the_replaced_calls_give(monkeypatch, cases):
    for name, robot, sets, free, noise in cases:
        clear_caches()
        shipped = _digest(calibrate(robot, sets, free, noise=noise))
        with monkeypatch.context() as m:
            m.setattr(se3, "exp_coeffs", _plain_exp_coeffs)
            m.setattr(se3, "log_with_jacobian_inv", _plain_log_with_jacobian_inv)
            m.setattr(_coeffs, "_few_small", lambda theta: None)  # numpy's Horner for a few angles too
            m.setattr(P, "_UPPER", np.zeros((0, 0), bool))  # the triangle's mask made at every call
            clear_caches()
            plain = _digest(calibrate(robot, sets, free, noise=noise))
        assert shipped == plain, name


def test_the_comparison_can_fail(monkeypatch, cases):
    """A pose block's reported value is its displacement's log, and the retraction's exponentials move every
    estimate: either off by round-off, the digest differs."""
    _, robot, sets, free, noise = cases[0]
    shipped = _digest(calibrate(robot, sets, free, noise=noise))
    with monkeypatch.context() as m:
        m.setattr(se3, "log_with_jacobian_inv", lambda T: (se3.log(T) * (1 + 1e-15), se3.left_jacobian_inv(se3.log(T))))
        assert _digest(calibrate(robot, sets, free, noise=noise)) != shipped
    with monkeypatch.context() as m:
        m.setattr(se3, "exp_coeffs", lambda t: tuple([c * (1 + 1e-15) for c in cs] for cs in _plain_exp_coeffs(t)))
        assert _digest(calibrate(robot, sets, free, noise=noise)) != shipped


@pytest.mark.parametrize("m, n", [(150, 52), (5, 9), (128, 128), (300, 127), (200, 129), (1, 1), (40, 200)])
def test_triangular_factor_is_numpys_r(rng, m, n):
    """The triangle's mask read from the constant table (up to its size) or made (above): numpy's R bit for bit."""
    from kincal.estimation.problem import triangular_factor

    A = rng.normal(size=(m, n))
    cols = [A[:, : n // 2], A[:, n // 2:]]
    R = triangular_factor(cols)
    R0 = np.linalg.qr(A, mode="r")
    assert R.flags.c_contiguous and _same(R, R0)
