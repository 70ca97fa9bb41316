"""SO(3): rotations, batch-first. Rotation vectors ``w`` have shape (..., 3), matrices (..., 3, 3).

Conventions: ``exp(hat(w))`` rotates by |w| about w / |w| (right-handed). The left Jacobian ``J_l``
satisfies ``exp(w + dw) = exp(J_l(w) dw) exp(w)`` to first order; the right Jacobian
``J_r(w) = J_l(-w)`` satisfies ``exp(w + dw) = exp(w) exp(J_r(w) dw)``.
"""

from __future__ import annotations

import math

import numpy as np

from kincal.lie._coeffs import log_coeff, one_minus_cos_over_t2, sin_over_t, t_minus_sin_over_t3


def hat(w: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix of w: hat(a) @ b == cross(a, b). (..., 3) -> (..., 3, 3)."""
    w = np.asarray(w, dtype=float)
    if w.shape == (3,):  # one vector: a literal beats six strided assignments
        x, y, z = w.tolist()
        return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    out = np.zeros(w.shape + (3,))
    out[..., 0, 1] = -w[..., 2]
    out[..., 0, 2] = w[..., 1]
    out[..., 1, 0] = w[..., 2]
    out[..., 1, 2] = -w[..., 0]
    out[..., 2, 0] = -w[..., 1]
    out[..., 2, 1] = w[..., 0]
    return out


def vee(W: np.ndarray) -> np.ndarray:
    """Inverse of hat, taking the skew part: (..., 3, 3) -> (..., 3)."""
    W = np.asarray(W, dtype=float)
    flat = W.reshape(W.shape[:-2] + (9,))
    return 0.5 * (flat[..., _SKEW_PLUS] - flat[..., _SKEW_MINUS])  # (W[2, 1] - W[1, 2], ...) / 2


# Flat (row-major 3 x 3) indices of hat(w)'s entries w_k and -w_k.
_SKEW_PLUS, _SKEW_MINUS = np.array([7, 2, 3]), np.array([5, 6, 1])


def angle(w: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum("...i,...i->...", w, w))


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis (faster than np.cross for large batches)."""
    if a.shape == b.shape == (3,):  # one pair (tangent bases, frames): Python floats beat nine array indexings
        a0, a1, a2 = a.tolist()
        b0, b1, b2 = b.tolist()
        return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
    out = np.empty(a.shape if a.shape == b.shape else np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def cross_tuple(a, b) -> tuple:
    """``cross`` of two 3-sequences of Python floats (the same operations): an arm's few joints one by one."""
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


def unit_tuple(a) -> tuple:
    """``a / np.linalg.norm(a)`` of a 3-sequence of Python floats (the squares summed in order, as numpy's)."""
    n = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    return a[0] / n, a[1] / n, a[2] / n


def exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: (..., 3) -> (..., 3, 3).

    Uses hat(w)^2 = w w^T - |w|^2 I, so R = cos(t) I + sin(t)/t hat(w) + (1 - cos t)/t^2 w w^T,
    assembled entry by entry (contiguous elementwise work is much faster than tiny batched matmuls).
    """
    w = np.asarray(w, dtype=float)
    t = angle(w)
    a = sin_over_t(t)
    b = one_minus_cos_over_t2(t)
    c = np.cos(t)
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    bxy, bxz, byz = b * x * y, b * x * z, b * y * z
    ax, ay, az = a * x, a * y, a * z
    R = np.empty(w.shape + (3,))
    R[..., 0, 0], R[..., 0, 1], R[..., 0, 2] = c + b * x * x, bxy - az, bxz + ay
    R[..., 1, 0], R[..., 1, 1], R[..., 1, 2] = bxy + az, c + b * y * y, byz - ax
    R[..., 2, 0], R[..., 2, 1], R[..., 2, 2] = bxz - ay, byz + ax, c + b * z * z
    return R


def log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of R with angle in [0, pi]: (..., 3, 3) -> (..., 3).

    The angle comes from atan2(|s|, c), accurate everywhere. The axis comes from the skew part for
    angles below pi/2 and from the symmetric part above, so it stays accurate up to pi.
    """
    R = np.asarray(R, dtype=float)
    s = vee(R)  # sin(t) * axis
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    sin_t = np.sqrt(np.add.reduce(s * s, axis=-1))  # np.linalg.norm's own operations
    t = np.arctan2(sin_t, c)
    w_small = s / sin_over_t(t)[..., None]
    if (c >= 0.0) if R.ndim == 2 else bool(np.all(c >= 0.0)):  # every rotation below pi/2: the skew part
        return w_small  # alone (what np.where picks below)

    # Near pi: R + R^T = 2 c I + 2 (1 - c) a a^T; read a from the largest diagonal entry.
    # Evaluated everywhere, but with the identity standing in where c >= 0 (its result is unused there).
    large = c < 0.0
    sym = 0.5 * (R + np.swapaxes(R, -1, -2)) - c[..., None, None] * np.eye(3)
    B = np.where(large[..., None, None], sym / np.where(large, 1.0 - c, 1.0)[..., None, None], np.eye(3))
    i = np.argmax(np.diagonal(B, axis1=-2, axis2=-1), axis=-1)
    col = np.take_along_axis(B, np.broadcast_to(i[..., None, None], B.shape[:-1] + (1,)), axis=-1)[..., 0]
    a = col / np.sqrt(np.take_along_axis(col, i[..., None], axis=-1))
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    sign = np.where(np.sum(a * s, axis=-1) < 0.0, -1.0, 1.0)
    w_large = (sign * t)[..., None] * a
    return np.where(large[..., None], w_large, w_small)


_I3 = np.eye(3)
_I3.flags.writeable = False


def left_jacobian(w: np.ndarray) -> np.ndarray:
    """J_l(w) = I + (1 - cos t)/t^2 W + (t - sin t)/t^3 W^2: (..., 3) -> (..., 3, 3)."""
    w = np.asarray(w, dtype=float)
    t = angle(w)[..., None, None]
    W = hat(w)
    return _I3 + one_minus_cos_over_t2(t) * W + t_minus_sin_over_t3(t) * (W @ W)


def left_jacobian_inv(w: np.ndarray) -> np.ndarray:
    """Inverse of J_l: I - W/2 + (1 - (t/2)cot(t/2))/t^2 W^2. Singular at t = 2 pi k, k != 0."""
    w = np.asarray(w, dtype=float)
    t = angle(w)[..., None, None]
    W = hat(w)
    return _I3 - 0.5 * W + log_coeff(t) * (W @ W)


def right_jacobian(w: np.ndarray) -> np.ndarray:
    return left_jacobian(-np.asarray(w, dtype=float))


def right_jacobian_inv(w: np.ndarray) -> np.ndarray:
    return left_jacobian_inv(-np.asarray(w, dtype=float))


def project(M: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius norm) to each 3x3 matrix, via SVD. Only for explicit user requests."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    d = np.sign(np.linalg.det(U @ Vt))
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    return U @ Vt
