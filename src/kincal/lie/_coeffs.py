"""Coefficient functions of the SO(3)/SE(3) closed forms, exact to machine precision at every angle.

Each closed form such as (theta - sin theta) / theta**3 loses digits to cancellation as theta -> 0.
Below ``_TAYLOR_BELOW`` we evaluate its Taylor series in theta**2 instead (12 terms: the truncation
error at theta = 1 is below 1e-25), above it the closed form (relative error of a few ulp there).
No branch snaps to identity.
"""

from __future__ import annotations

from math import factorial

import numpy as np

_TAYLOR_BELOW = 1.0
_TERMS = 12

# Bernoulli numbers B_2, B_4, ..., B_24 (for x cot x).
_BERNOULLI_EVEN = (
    1 / 6, -1 / 30, 1 / 42, -1 / 30, 5 / 66, -691 / 2730, 7 / 6, -3617 / 510,
    43867 / 798, -174611 / 330, 854513 / 138, -236364091 / 2730,
)


class _Series:
    """Series coefficients in powers theta**(2k): the array, and below its top one, highest first, as Python
    floats (``_horner_float``'s, made once)."""

    def __init__(self, k_term):
        self.values = np.array([k_term(k) for k in range(_TERMS)], dtype=float)
        self.rest, self.top = self.values[-2::-1].tolist(), float(self.values[-1])


_SIN_OVER_T = _Series(lambda k: (-1) ** k / factorial(2 * k + 1))
_ONE_MINUS_COS = _Series(lambda k: (-1) ** k / factorial(2 * k + 2))
_T_MINUS_SIN = _Series(lambda k: (-1) ** k / factorial(2 * k + 3))
_LOG_D = _Series(lambda k: (-1) ** k * _BERNOULLI_EVEN[k] / factorial(2 * k + 2))
_A1 = _Series(lambda k: (-1) ** (k + 1) * (k - 1) / factorial(2 * k + 2))
_A2 = _Series(lambda k: (-1) ** (k + 1) * (k - 1) / factorial(2 * k + 3))
_A3 = _Series(lambda k: (-1) ** k * (k + 1) / factorial(2 * k + 4))
_A4 = _Series(lambda k: (-1) ** k * (k + 1) / factorial(2 * k + 5))


def _horner(coeffs: np.ndarray, t2: np.ndarray) -> np.ndarray:
    out = np.full_like(t2, coeffs[-1])
    for c in coeffs[-2::-1].tolist():  # in place, on Python floats: the same IEEE operations, fewer arrays
        out *= t2
        out += c
    return out


# Up to this many angles, ``_branch`` evaluates the series on Python floats, one angle after the other.
_FEW = 16


def _horner_float(cs: list, out: float, t2: float) -> float:
    """Horner on Python floats: ``cs`` the coefficients below the top one, highest first; ``out`` the top one."""
    for c in cs:
        out = out * t2 + c
    return out


def series_at(series: _Series, ts: list) -> list:
    """``_branch``'s series at angles below the branch point (Python floats; ``t * t`` the square)."""
    cs, top = series.rest, series.top
    return [_horner_float(cs, top, t * t) for t in ts]


_JL_TOPS = (_A1.top, _A2.top, _A3.top, _A4.top)
_JL_RESTS = tuple(zip(_A1.rest, _A2.rest, _A3.rest, _A4.rest))


def jl_coeffs_at(ts: list) -> list[tuple[float, float, float, float]]:
    """``se3_jl_coeffs``' (a1, a2, a3, a4) at each angle below the branch point (Python floats): the four series
    side by side in one loop (``_horner_float``'s operations)."""
    out = []
    for t in ts:
        t2 = t * t
        a1, a2, a3, a4 = _JL_TOPS
        for c1, c2, c3, c4 in _JL_RESTS:
            a1, a2, a3, a4 = a1 * t2 + c1, a2 * t2 + c2, a3 * t2 + c3, a4 * t2 + c4
        out.append((a1, a2, a3, a4))
    return out


def _few_small(theta: np.ndarray) -> list | None:
    """The angles (an array of 1 to ``_FEW`` dimensions) as Python floats when there are at most ``_FEW`` of them,
    all below the branch point; else None."""
    if theta.ndim == 0 or theta.size > _FEW:
        return None
    ts = theta.ravel().tolist()
    return ts if all(t < _TAYLOR_BELOW for t in ts) else None


def _branch(theta: np.ndarray, series: _Series, closed_form) -> np.ndarray:
    theta = np.asarray(theta, dtype=float)
    ts = _few_small(theta)
    if ts is not None:  # a few angles (one per joint), all below the branch point: Python floats, the same IEEE
        cs, top = series.rest, series.top  # operations (``t * t`` is ``theta * theta``'s product)
        return np.array([_horner_float(cs, top, t * t) for t in ts]).reshape(theta.shape)
    small = theta < _TAYLOR_BELOW
    if theta.ndim == 0:  # one angle: Horner on Python floats (the same IEEE operations, without array overhead)
        if not small:
            return closed_form(theta)
        return np.float64(_horner_float(series.rest, series.top, float(theta * theta)))
    if small.all():  # every angle below the branch point (joint screws' small steps): no masking
        return _horner(series.values, theta * theta)
    out = np.empty_like(theta)
    out[small] = _horner(series.values, theta[small] ** 2)
    large = ~small
    out[large] = closed_form(theta[large])
    return out


def sin_over_t(theta):
    """sin(t) / t."""
    return _branch(theta, _SIN_OVER_T, lambda t: np.sin(t) / t)


def one_minus_cos_over_t2(theta):
    """(1 - cos t) / t**2."""
    return _branch(theta, _ONE_MINUS_COS, lambda t: (1.0 - np.cos(t)) / t**2)


def t_minus_sin_over_t3(theta):
    """(t - sin t) / t**3."""
    return _branch(theta, _T_MINUS_SIN, lambda t: (t - np.sin(t)) / t**3)


def log_coeff(theta):
    """(1 - (t/2) cot(t/2)) / t**2, the W**2 coefficient of the inverse SO(3) left Jacobian."""
    return _branch(theta, _LOG_D, lambda t: (1.0 - 0.5 * t * np.sin(t) / (1.0 - np.cos(t))) / t**2)


_EXP_TOPS = (_SIN_OVER_T.top, _ONE_MINUS_COS.top, _T_MINUS_SIN.top)
_EXP_RESTS = tuple(zip(_SIN_OVER_T.rest, _ONE_MINUS_COS.rest, _T_MINUS_SIN.rest))


def exp_coeffs(theta: np.ndarray) -> tuple[list, list, list]:
    """(sin_over_t, one_minus_cos_over_t2, t_minus_sin_over_t3) of angles (m,), as lists of Python floats: below
    the branch point, a few of them, in one loop (``_branch``'s series, the same IEEE operations)."""
    ts = _few_small(theta)
    if ts is not None:
        out = ([], [], [])
        for t in ts:
            t2 = t * t  # ``theta * theta``'s product
            a, b, c = _EXP_TOPS
            for ca, cb, cc in _EXP_RESTS:  # ``_horner_float`` of the three, side by side
                a, b, c = a * t2 + ca, b * t2 + cb, c * t2 + cc
            out[0].append(a)
            out[1].append(b)
            out[2].append(c)
        return out
    return tuple(f(theta).tolist() for f in (sin_over_t, one_minus_cos_over_t2, t_minus_sin_over_t3))


def se3_jl_coeffs(theta):
    """Coefficients (a1, a2, a3, a4) with J_l(xi) = I + a1 X + a2 X^2 + a3 X^3 + a4 X^4, X = ad(xi).

    These are the thesis' closed forms (eq. 2.44 with q = 1), theta = |w|.
    """
    theta = np.asarray(theta, dtype=float)
    ts = _few_small(theta)
    if ts is not None:  # ``_branch``'s series on floats, all four
        t2 = [t * t for t in ts]
        return tuple(np.array([_horner_float(c.rest, c.top, x) for x in t2]).reshape(theta.shape)
                     for c in (_A1, _A2, _A3, _A4))
    a1 = _branch(theta, _A1, lambda t: (4 - t * np.sin(t) - 4 * np.cos(t)) / (2 * t**2))
    a2 = _branch(theta, _A2, lambda t: (4 * t - 5 * np.sin(t) + t * np.cos(t)) / (2 * t**3))
    a3 = _branch(theta, _A3, lambda t: (2 - t * np.sin(t) - 2 * np.cos(t)) / (2 * t**4))
    a4 = _branch(theta, _A4, lambda t: (2 * t - 3 * np.sin(t) + t * np.cos(t)) / (2 * t**5))
    return a1, a2, a3, a4
