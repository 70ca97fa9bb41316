"""SE(3): rigid transforms, batch-first. Twists ``xi = (v, w)`` have shape (..., 6), transforms (..., 4, 4).

Conventions (see docs/conventions.md):
- ``hat(xi) = [[hat(w), v], [0, 0]]``; a revolute joint through p with unit axis w has v = -w x p.
- ``adjoint(T) = [[R, hat(p) R], [0, R]]`` maps twists: T hat(xi) T^-1 = hat(adjoint(T) xi).
- ``ad(xi) = [[hat(w), hat(v)], [0, hat(w)]]`` (the thesis' Omega).
- Left Jacobian: exp(xi + d) = exp(J_l(xi) d) exp(xi) to first order, i.e.
  [d exp(xi) exp(-xi)]^vee = J_l(xi) d.
"""

from __future__ import annotations

import math

import numpy as np

from kincal._memo import remember
from kincal.lie import so3
from kincal.lie._coeffs import (_LOG_D, _SIN_OVER_T, _TAYLOR_BELOW, exp_coeffs, jl_coeffs_at, one_minus_cos_over_t2,
                                se3_jl_coeffs, series_at, t_minus_sin_over_t3)


def split(xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(v, w) views of a twist array (..., 6)."""
    xi = np.asarray(xi)
    return xi[..., :3], xi[..., 3:]


def join(v: np.ndarray, w: np.ndarray) -> np.ndarray:
    v, w = np.asarray(v, dtype=float), np.asarray(w, dtype=float)
    if v.shape == w.shape:  # nothing to broadcast (one twist, or batches alike)
        return np.concatenate([v, w], axis=-1)
    v, w = np.broadcast_arrays(v, w)
    return np.concatenate([v, w], axis=-1)


def hat(xi: np.ndarray) -> np.ndarray:
    xi = np.asarray(xi, dtype=float)
    v, w = split(xi)
    out = np.zeros(xi.shape[:-1] + (4, 4))
    out[..., :3, :3] = so3.hat(w)
    out[..., :3, 3] = v
    return out


def vee(X: np.ndarray) -> np.ndarray:
    X = np.asarray(X, dtype=float)
    return join(X[..., :3, 3], so3.vee(X[..., :3, :3]))


def make(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Assemble transforms from rotations (..., 3, 3) and translations (..., 3)."""
    R = np.asarray(R, dtype=float)
    p = np.asarray(p, dtype=float)
    batch = R.shape[:-2] if R.shape[:-2] == p.shape[:-1] else np.broadcast_shapes(R.shape[:-2], p.shape[:-1])
    out = np.zeros(batch + (4, 4))
    out[..., :3, :3] = R
    out[..., :3, 3] = p
    out[..., 3, 3] = 1.0
    return out


def identity(batch: tuple[int, ...] = ()) -> np.ndarray:
    return np.broadcast_to(np.eye(4), batch + (4, 4)).copy()


def exp(xi: np.ndarray) -> np.ndarray:
    """exp(hat(xi)) = [[exp(w), J_l(w) v], [0, 1]]: (..., 6) -> (..., 4, 4).

    J_l(w) v = v + (1 - cos t)/t^2 (w x v) + (t - sin t)/t^3 (w x (w x v)), without forming J_l.
    """
    xi = np.asarray(xi, dtype=float)
    v, w = split(xi)
    t = so3.angle(w)
    if xi.ndim == 2 and len(xi) <= _FEW_JOINTS:  # a retraction's few twists: ``_few_exps``
        return _few_exps(xi, t)
    wv = so3.cross(w, v)
    p = v + one_minus_cos_over_t2(t)[..., None] * wv + t_minus_sin_over_t3(t)[..., None] * so3.cross(w, wv)
    return make(so3.exp(w), p)


def _few_exps(xi: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``exp`` of a few twists (m, 6) at angles t (m,): the coefficients (``exp_coeffs``) and cosines (numpy's),
    the rest twist by twist on Python floats with ``exp``'s and ``so3.exp``'s operations (one coefficient each for
    both, as they compute the same)."""
    a, b, c3 = exp_coeffs(t)
    out = []
    for (v0, v1, v2, x, y, z), ak, bk, ck, c in zip(xi.tolist(), a, b, c3, np.cos(t).tolist()):
        p0, p1, p2 = y * v2 - z * v1, z * v0 - x * v2, x * v1 - y * v0  # w x v (``so3.cross_tuple``'s operations)
        q0, q1, q2 = y * p2 - z * p1, z * p0 - x * p2, x * p1 - y * p0  # w x (w x v)
        bxy, bxz, byz = bk * x * y, bk * x * z, bk * y * z
        out += [c + bk * x * x, bxy - ak * z, bxz + ak * y, v0 + bk * p0 + ck * q0,
                bxy + ak * z, c + bk * y * y, byz - ak * x, v1 + bk * p1 + ck * q1,
                bxz - ak * y, byz + ak * x, c + bk * z * z, v2 + bk * p2 + ck * q2, 0.0, 0.0, 0.0, 1.0]
    return np.array(out).reshape(len(xi), 4, 4)


def exp_joint_screws(screws: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """exp(hat(xi_j) theta_j) for exact joint screws: (n, 6) and theta (..., n) -> (..., n, 4, 4).

    Revolute (unit w, zero pitch, axis through p = w x v): with K = hat(w), R = I + sin t K + (1 - cos t) K^2
    and translation (I - R) p = -(sin t K p + (1 - cos t) K^2 p). Prismatic (w = 0, unit v): K = 0 and
    translation t v. So the top 3 x 4 block is ``[I | 0] + sin t E1 + (1 - cos t) E2 + t E3`` with constant
    E1, E2, E3 per joint: three scaled sums, no series branches, no per-element assembly.
    """
    theta = np.asarray(theta, dtype=float)
    E1, E2, E3 = _screw_terms(np.asarray(screws, dtype=float))
    top = np.sin(theta)[..., None] * E1
    top += (1.0 - np.cos(theta))[..., None] * E2
    top += theta[..., None] * E3
    out = np.zeros(theta.shape + (4, 4))
    out[..., :3, :] = top.reshape(theta.shape + (3, 4))
    for i in range(4):
        out[..., i, i] += 1.0
    return out


# ``_screw_terms`` of the last few screw arrays, by their bytes: one state's screws serve many evaluations.
_TERMS: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
_TERMS_ENTRIES = 16


def _remembered(cache: dict, screws: np.ndarray, compute) -> tuple:
    """``compute(screws)`` (a tuple of arrays, made read-only), remembered in ``cache`` by the screws' bytes."""
    key = screws.tobytes()
    hit = cache.get(key)
    if hit is None:
        hit = compute(screws)
        for a in hit:
            a.flags.writeable = False
        remember(cache, key, hit, _TERMS_ENTRIES)
    return hit


def _screw_terms(screws: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """E1, E2, E3 (n, 12) of ``exp_joint_screws`` for exact joint screws (n, 6) (read-only arrays)."""
    return _remembered(_TERMS, screws, _compute_terms)


def _compute_terms(screws: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    v, w = screws[:, :3], screws[:, 3:]
    revolute = np.sum(w * w, axis=1) > 0.5
    K = so3.hat(np.where(revolute[:, None], w, 0.0))
    K2 = K @ K
    p = so3.cross(w, v)[:, :, None]  # the axis point nearest the origin (revolute)
    E1 = np.concatenate([K, -(K @ p)], axis=-1).reshape(-1, 12)
    E2 = np.concatenate([K2, -(K2 @ p)], axis=-1).reshape(-1, 12)
    E3 = np.zeros((len(screws), 3, 4))
    E3[:, :, 3] = np.where(revolute[:, None], 0.0, v)
    return E1, E2, E3.reshape(-1, 12)


def joint_frames(screws: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For exact joint screws (n, 6): frames ``C`` (n, 4, 4) whose z axis is each joint's axis (origin on it),
    so that ``exp(hat(xi_j) t) = C_j Z_j(t) C_j^-1`` with ``Z_j`` a rotation about z (revolute) or a translation
    along it (prismatic); their inverses, the revolute mask (n,) and ``Ad(C)``, ``Ad(C^-1)`` (n, 6, 6). A chain
    then multiplies per sample by ``Z`` only (two columns change) and by constants (read-only arrays)."""
    return _remembered(_FRAMES, screws, _compute_frames)


def _compute_frames(screws: np.ndarray) -> tuple:
    if len(screws) <= _FEW_JOINTS:  # an arm's joints: on Python floats, the same IEEE operations
        rows = [_frame_rows(*_cut(x)) for x in screws.tolist()]
        n = len(rows)
        T = np.array([r[0] for r in rows] + [r[1] for r in rows]).reshape(2 * n, 4, 4)  # C then C^-1
        hats = [(0.0, -p[11], p[7], p[11], 0.0, -p[3], -p[7], p[3], 0.0) for p in [r[k] for k in (0, 1) for r in rows]]
        R = T[:, :3, :3]
        Ad = np.zeros((2 * n, 6, 6))  # ``adjoint(T)``: its hat(p) entries from the same floats
        Ad[:, :3, :3] = R
        Ad[:, 3:, 3:] = R
        Ad[:, :3, 3:] = np.array(hats).reshape(2 * n, 3, 3) @ R
        return T[:n], T[n:], np.array([r[2] for r in rows], bool), Ad[:n], Ad[n:]
    v, w = screws[:, :3], screws[:, 3:]
    revolute = np.sum(w * w, axis=1) > 0.5
    z = np.where(revolute[:, None], w, v)
    z = z / np.linalg.norm(z, axis=1, keepdims=True)
    helper = np.where((np.abs(z[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    x = so3.cross(helper, z)
    x = x / np.linalg.norm(x, axis=1, keepdims=True)
    R = np.stack([x, so3.cross(z, x), z], axis=-1)
    p = np.where(revolute[:, None], so3.cross(w, v), 0.0)  # a point of the axis (revolute)
    Rt = np.swapaxes(R, -1, -2)
    C, Ci = make(R, p), make(Rt, -(Rt[..., 0] * p[:, 0, None] + Rt[..., 1] * p[:, 1, None] + Rt[..., 2] * p[:, 2, None]))
    return C, Ci, revolute, adjoint(C), adjoint(Ci)


_FRAMES: dict[bytes, tuple] = {}  # joint_frames of the last few screw arrays
_FEW_JOINTS = 16  # up to this many joints, ``_compute_frames`` goes joint by joint on Python floats


def _cut(x: list) -> tuple:
    return x[:3], x[3:]


def _frame_rows(v, w) -> tuple[list, list, bool]:
    """One joint's ``C`` and ``C^-1`` (16 floats each, row by row) and whether it is revolute, with the batched
    ``_compute_frames``' operations (``x, y, z`` the frame's axes, the columns of R)."""
    revolute = w[0] * w[0] + w[1] * w[1] + w[2] * w[2] > 0.5
    z = so3.unit_tuple(w if revolute else v)
    x = so3.unit_tuple(so3.cross_tuple((1.0, 0.0, 0.0) if abs(z[0]) < 0.9 else (0.0, 1.0, 0.0), z))
    y = so3.cross_tuple(z, x)
    p = so3.cross_tuple(w, v) if revolute else (0.0, 0.0, 0.0)
    t = [-(e[0] * p[0] + e[1] * p[1] + e[2] * p[2]) for e in (x, y, z)]
    C = [x[0], y[0], z[0], p[0], x[1], y[1], z[1], p[1], x[2], y[2], z[2], p[2], 0.0, 0.0, 0.0, 1.0]
    Ci = [*x, t[0], *y, t[1], *z, t[2], 0.0, 0.0, 0.0, 1.0]
    return C, Ci, revolute


def joint_screw_jacobian_coeffs(screws: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(f1, f2), each (..., n), with ``theta J_l(theta xi) = theta I + f1 ad(xi) + f2 ad(xi)^2`` for exact joint
    screws (see ``exact_joint_screws``).

    Revolute (unit w, zero pitch): ad(xi)^3 = -ad(xi), so f1 = 1 - cos theta, f2 = theta - sin theta (no series
    needed at small theta: both terms are simply small). Prismatic: ad(xi)^2 = 0 and f1 = theta^2 / 2.
    """
    theta = np.asarray(theta, dtype=float)
    revolute = np.sum(np.asarray(screws)[:, 3:] ** 2, axis=1) > 0.5
    f1 = np.where(revolute, 1.0 - np.cos(theta), 0.5 * theta * theta)
    f2 = np.where(revolute, theta - np.sin(theta), 0.0)
    return f1, f2


def exact_joint_screws(screws: np.ndarray, tol: float = 1e-12) -> bool:
    """True when every screw is a unit zero-pitch revolute screw or a unit prismatic one."""
    screws = np.asarray(screws)
    key = (screws.dtype.str, screws.shape, screws.tobytes(), tol)
    hit = _EXACT.get(key)
    if hit is None:
        hit = remember(_EXACT, key, _exact(screws, tol), _TERMS_ENTRIES)
    return hit


_EXACT: dict[tuple, bool] = {}  # exact_joint_screws of the last few screw arrays


def clear_caches() -> None:
    """Forget the joint-screw terms and exactness verdicts remembered per screw array, and the remembered
    inverses and adjoints of single poses (tests, cold timings)."""
    _TERMS.clear()
    _EXACT.clear()
    _FRAMES.clear()
    _ONE_POSE.clear()


def _exact(screws: np.ndarray, tol: float) -> bool:
    if len(screws) <= _FEW_JOINTS:  # an arm's joints: the same sums on Python floats
        return all(_exact_one(x, tol) for x in screws.tolist())
    v, w = np.asarray(screws[:, :3]), np.asarray(screws[:, 3:])
    ww, vv, wv = np.sum(w * w, axis=1), np.sum(v * v, axis=1), np.sum(w * v, axis=1)
    revolute = ww > 0.5
    return bool(np.all(np.where(revolute, np.abs(ww - 1) <= tol, (ww <= tol**2) & (np.abs(vv - 1) <= tol))
                       & (np.abs(wv) <= tol)))


def _exact_one(x: list, tol: float) -> bool:
    """``_exact`` of one screw (6 floats): the squares and products summed in order, as ``np.sum`` does."""
    v0, v1, v2, w0, w1, w2 = x
    ww, vv, wv = w0 * w0 + w1 * w1 + w2 * w2, v0 * v0 + v1 * v1 + v2 * v2, w0 * v0 + w1 * v1 + w2 * v2
    unit = abs(ww - 1) <= tol if ww > 0.5 else ww <= tol**2 and abs(vv - 1) <= tol
    return unit and abs(wv) <= tol


def log(T: np.ndarray) -> np.ndarray:
    """Twist with rotation angle in [0, pi]: (..., 4, 4) -> (..., 6)."""
    T = np.asarray(T, dtype=float)
    few = _few_logs(T)
    return _log(T)[0] if few is None else few[0]


def log_with_jacobian_inv(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(x, left_jacobian_inv(x))`` with ``x = log(T)``, the rotation's inverse Jacobian computed once: the same
    numbers as the two calls to round-off (not always bit for bit: a batch's ``einsum`` sums arrays laid out
    differently from the two calls', which can move the last bit, mostly at angles of 1 rad or more)."""
    T = np.asarray(T, dtype=float)
    few = _few_logs(T)
    if few is not None:
        return few[0], _few_jacobians_inv(*few)
    x, Ji = _log(T)
    return x, _inverse_blocks(Ji, left_jacobian(x)[..., :3, 3:])


_FEW_POSES = 4  # up to this many poses (m, 4, 4), ``_few_logs`` goes pose by pose on Python floats (above, the
# batched path is faster: some 10 us a pose on floats against its fixed 80-90 us)
_I9 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


def _few_logs(T: np.ndarray) -> tuple | None:
    """``_log`` of a few poses (m, 4, 4) whose angles are all below the series' branch point (else None): its
    elementwise steps on Python floats, in its order (``so3.log``'s skew-part branch, ``so3.left_jacobian_inv``);
    the arctangent, the dot products (``einsum``) and ``W @ W`` by numpy on arrays shaped and laid out as ``_log``'s.
    Returns x (m, 6), Ji (m, 3, 3) and the angles of x's rotations (a list) for ``_few_jacobians_inv``."""
    if T.ndim != 3 or not 0 < len(T) <= _FEW_POSES:
        return None
    s, c, sin_t = [], [], []
    for (r0, r1, r2, _), (r3, r4, r5, _), (r6, r7, r8, _), _ in T.tolist():
        sk = (0.5 * (r7 - r5), 0.5 * (r2 - r6), 0.5 * (r3 - r1))  # ``so3.vee``
        s.append(sk)
        c.append(0.5 * (r0 + r4 + r8 - 1.0))  # the trace summed in order, as numpy's
        sin_t.append(math.sqrt(sk[0] * sk[0] + sk[1] * sk[1] + sk[2] * sk[2]))
    t = np.arctan2(np.array(sin_t), np.array(c)).tolist()
    if not all(a < _TAYLOR_BELOW and b >= 0.0 for a, b in zip(t, c)):
        return None
    w = [(s0 / k, s1 / k, s2 / k) for (s0, s1, s2), k in zip(s, series_at(_SIN_OVER_T, t))]
    # laid out as ``so3.log``'s (its fancy indexing's): column by column. ``einsum``'s sums depend on the layout
    wa = np.array(list(zip(*w))).T
    theta = so3.angle(wa).tolist()
    if not all(a < _TAYLOR_BELOW for a in theta):
        return None
    hats = [(0.0, -z, y, z, 0.0, -x, -y, x, 0.0) for x, y, z in w]  # ``so3.hat``
    Wa = np.array(hats).reshape(-1, 3, 3)
    WW = (Wa @ Wa).reshape(-1, 9).tolist()
    Ji = [[(i - 0.5 * h) + d * q for i, h, q in zip(_I9, hk, wk)]
          for hk, wk, d in zip(hats, WW, series_at(_LOG_D, theta))]
    Jia = np.array(Ji).reshape(-1, 3, 3)
    x = np.concatenate([np.einsum("...ij,...j->...i", Jia, T[..., :3, 3]), wa], axis=-1)
    return x, Jia, so3.angle(x[:, 3:]).tolist()  # the angles as ``left_jacobian`` takes them (x's columns)


_Q = (3, 4, 5, 9, 10, 11, 15, 16, 17)  # flat indices of a 6 x 6 matrix's top right 3 x 3 block


def _few_jacobians_inv(x: np.ndarray, Jia: np.ndarray, theta: list) -> np.ndarray:
    """``_inverse_blocks(Ji, left_jacobian(x)[..., :3, 3:])`` of ``_few_logs``: ``left_jacobian``'s top right block
    on Python floats (its sums in its order), its powers of ``ad(x)`` and the block products by numpy."""
    if not all(a < _TAYLOR_BELOW for a in theta):  # ``left_jacobian``'s closed form: its own path
        return _inverse_blocks(Jia, left_jacobian(x)[..., :3, 3:])
    X = ad(x)
    X2 = X @ X
    powers = zip(X.reshape(-1, 36).tolist(), X2.reshape(-1, 36).tolist(), (X2 @ X).reshape(-1, 36).tolist(),
                 (X2 @ X2).reshape(-1, 36).tolist())
    a = jl_coeffs_at(theta)
    Q = [[(((0.0 + a1 * p1[i]) + a2 * p2[i]) + a3 * p3[i]) + a4 * p4[i] for i in _Q]
         for (a1, a2, a3, a4), (p1, p2, p3, p4) in zip(a, powers)]
    return _inverse_blocks(Jia, np.array(Q).reshape(-1, 3, 3))


def _log(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``log(T)`` and its rotation's inverse left Jacobian (3, 3), which maps the translation to ``v``."""
    T = np.asarray(T, dtype=float)
    w = so3.log(T[..., :3, :3])
    Ji = so3.left_jacobian_inv(w)
    return join(np.einsum("...ij,...j->...i", Ji, T[..., :3, 3]), w), Ji


def inverse(T: np.ndarray) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def remembered(fn, T: np.ndarray) -> np.ndarray:
    """``fn(T)`` (``inverse`` or ``adjoint``) of one pose (4, 4), remembered by the function and T's bytes (a
    tracker frame or base met at every evaluation of a solve); read-only. Other shapes: computed."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4):
        return fn(T)
    key = (fn, T.tobytes())
    hit = _ONE_POSE.get(key)
    if hit is None:
        hit = fn(T)
        hit.flags.writeable = False
        remember(_ONE_POSE, key, hit, _TERMS_ENTRIES)
    return hit


_ONE_POSE: dict[tuple, np.ndarray] = {}  # ``remembered``'s values by (function, bytes of the pose)


def adjoint(T: np.ndarray) -> np.ndarray:
    """Ad_T = [[R, hat(p) R], [0, R]]: (..., 4, 4) -> (..., 6, 6)."""
    T = np.asarray(T, dtype=float)
    R = T[..., :3, :3]
    out = np.zeros(T.shape[:-2] + (6, 6))
    out[..., :3, :3] = R
    out[..., 3:, 3:] = R
    out[..., :3, 3:] = so3.hat(T[..., :3, 3]) @ R
    return out


def adjoint_inv(T: np.ndarray) -> np.ndarray:
    """Ad_{T^-1} without forming T^-1: [[R^T, -R^T hat(p)], [0, R^T]]."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros(T.shape[:-2] + (6, 6))
    out[..., :3, :3] = Rt
    out[..., 3:, 3:] = Rt
    out[..., :3, 3:] = -Rt @ so3.hat(T[..., :3, 3])
    return out


def ad(xi: np.ndarray) -> np.ndarray:
    """Small adjoint: ad(a) b is the Lie bracket [a, b]; (..., 6) -> (..., 6, 6): ``[[hat(w), hat(v)],
    [0, hat(w)]]`` written entry by entry from the twist's coordinates (``_AD_PLUS``, ``_AD_MINUS``)."""
    xi = np.asarray(xi, dtype=float)
    out = np.zeros(xi.shape[:-1] + (36,))
    out[..., _AD_PLUS[0]] = xi[..., _AD_PLUS[1]]
    out[..., _AD_MINUS[0]] = -xi[..., _AD_MINUS[1]]
    return out.reshape(xi.shape[:-1] + (6, 6))


def _ad_entries(sign: int) -> tuple[np.ndarray, np.ndarray]:
    """(flat indices in a 6 x 6 ``ad``, twist coordinates there) of the entries ``sign * coordinate``: ``hat(u)``
    holds ``u_k`` at (k + 2, k + 1) (mod 3) and ``-u_k`` at the transposed place."""
    places = []
    for r0, c0, u in ((0, 0, 3), (3, 3, 3), (0, 3, 0)):  # hat(w) twice, hat(v) top right
        for k in range(3):
            r, c = ((k + 2) % 3, (k + 1) % 3) if sign > 0 else ((k + 1) % 3, (k + 2) % 3)
            places.append((6 * (r0 + r) + c0 + c, u + k))
    return np.array([p for p, _ in places]), np.array([k for _, k in places])


_AD_PLUS, _AD_MINUS = _ad_entries(1), _ad_entries(-1)


_I6 = np.eye(6)
_I6.flags.writeable = False


def left_jacobian(xi: np.ndarray) -> np.ndarray:
    """J_l(xi) = sum_k ad(xi)^k / (k+1)!, in the thesis' four-term closed form (eq. 2.44): (..., 6, 6)."""
    xi = np.asarray(xi, dtype=float)
    a1, a2, a3, a4 = (c[..., None, None] for c in se3_jl_coeffs(so3.angle(split(xi)[1])))
    X = ad(xi)
    X2 = X @ X
    X3 = X2 @ X
    return _I6 + a1 * X + a2 * X2 + a3 * X3 + a4 * (X2 @ X2)


def left_jacobian_inv(xi: np.ndarray) -> np.ndarray:
    """Inverse of J_l from its block structure [[J, Q], [0, J]]^-1 = [[J^-1, -J^-1 Q J^-1], [0, J^-1]]."""
    xi = np.asarray(xi, dtype=float)
    w = split(xi)[1]
    Q = left_jacobian(xi)[..., :3, 3:]
    return _inverse_blocks(so3.left_jacobian_inv(w), Q)


def _inverse_blocks(Ji: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """[[J, Q], [0, J]]^-1 from J^-1 (..., 3, 3) and Q."""
    out = np.zeros(Ji.shape[:-2] + (6, 6))
    out[..., :3, :3] = Ji
    out[..., 3:, 3:] = Ji
    out[..., :3, 3:] = -Ji @ Q @ Ji
    return out


def right_jacobian(xi: np.ndarray) -> np.ndarray:
    return left_jacobian(-np.asarray(xi, dtype=float))


def right_jacobian_inv(xi: np.ndarray) -> np.ndarray:
    return left_jacobian_inv(-np.asarray(xi, dtype=float))


def transform_points(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """T @ p for points (..., 3)."""
    T = np.asarray(T, dtype=float)
    return (T[..., :3, :3] @ np.asarray(p, dtype=float)[..., None])[..., 0] + T[..., :3, 3]
