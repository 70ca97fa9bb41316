"""A minimal reference solver for the tracker problem of bench/bench_speed.py: the floor kincal is measured against.

Problem: a 6R arm (UR10) measured by a tracker at one marker on the tool (position only), tracker frame and
marker unknown. Model: modified DH (Craig) with Hayati's tilt for parallel neighbours, one link

    A_i(q_i) = Rx(alpha_{i-1}) Tx(a_{i-1}) Ry(beta_{i-1}) Rz(theta_i + q_i) Tz(d_i)

and the marker seen in the tracker frame ``y = T_tracker_base A_1(q_1) ... A_n(q_n) F x`` (F the constant
flange transform, x the marker in the flange frame). The estimated parameters are a minimal identifiable set
(27 for the UR10, the rank kincal finds): the tracker pose (6: translation, then rotation vector, applied on
the left), 18 link parameters and the marker (3). Held at nominal, because something else absorbs them: the
whole first link (the tracker pose), ``d`` of a joint whose successor is parallel (only the sum of ``d`` along
parallel axes matters; ``beta`` takes its place) and the last joint's ``theta`` and ``d`` (the marker).

Everything is vectorised over configurations (a Python loop over the joints only); the Jacobian is analytic:
a rotation about unit axis u through point o moves the marker by ``u x (y - o)``, a translation along u by u.
The solve is Gauss-Newton on the triangular factor of ``[J | r]`` with a Levenberg-Marquardt fallback.
Nothing of kincal is used here; bench/bench_speed.py and tests/test_bench_reference.py compare the two.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Universal Robots' standard DH table of the UR10 (CB3), the table kincal's built-in ur10 model is converted from.
UR10_DH = {"a": [0, -0.612, -0.5723, 0, 0, 0], "alpha": [np.pi / 2, 0, 0, np.pi / 2, -np.pi / 2, 0],
           "d": [0.1273, 0, 0, 0.163941, 0.1157, 0.0922], "theta": [0, 0, 0, 0, 0, 0]}

LINK_FIELDS = ("alpha", "a", "beta", "theta", "d")  # row i: alpha_{i-1}, a_{i-1}, beta_{i-1}, theta_i, d_i


@dataclass(frozen=True)
class Model:
    """Link parameters (n, 5) in ``LINK_FIELDS`` order, which of them are estimated (n, 5) bool, the constant
    flange transform (4, 4), the tracker pose ``T_tracker_base`` (4, 4) and the marker in the flange frame (3,)."""

    links: np.ndarray
    free: np.ndarray
    flange: np.ndarray
    T_tracker_base: np.ndarray
    marker: np.ndarray

    @property
    def size(self) -> int:
        return 6 + int(self.free.sum()) + 3


def from_standard_dh(a, alpha, d, theta) -> Model:
    """The modified-DH model of a standard DH table (``A_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``):
    regrouping the product gives row i = (alpha_{i-1}, a_{i-1}, 0, theta_i, d_i) and the flange
    ``Tx(a_n) Rx(alpha_n)``. Tracker at the base, marker at the flange until ``initial`` fits them."""
    a, alpha, d, theta = (np.asarray(v, dtype=float) for v in (a, alpha, d, theta))
    n = len(a)
    links = np.column_stack([np.r_[0.0, alpha[:-1]], np.r_[0.0, a[:-1]], np.zeros(n), theta, d])
    return Model(links, _minimal(links), _trans_x(a[-1]) @ _rot(0, alpha[-1]), np.eye(4), np.zeros(3))


def _minimal(links: np.ndarray) -> np.ndarray:
    """The identifiable link parameters for position measurements with an unknown tracker pose and marker."""
    n = len(links)
    parallel = np.r_[False, np.isclose(np.sin(links[1:, 0]), 0.0)]  # z_{i-1} parallel to z_i
    free = np.ones((n, 5), bool)
    free[:, 2] = parallel  # beta only between parallel axes
    free[:-1, 4] &= ~parallel[1:]  # d_i is held when z_{i+1} is parallel to z_i
    free[0] = False  # the first link: the tracker pose
    free[-1, 3:] = False  # theta_n, d_n: the marker
    return free


def _rot(axis: int, angle) -> np.ndarray:
    """Rotations about x (0), y (1) or z (2) by ``angle`` (scalar or (N,)): (..., 4, 4)."""
    angle = np.asarray(angle, dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    T = np.zeros(angle.shape + (4, 4))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    T[..., axis, axis] = T[..., 3, 3] = 1.0
    T[..., i, i], T[..., j, j], T[..., i, j], T[..., j, i] = c, c, -s, s
    return T


def _trans_x(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


def _trans_z(z: float) -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = z
    return T


def frames(model: Model, q: np.ndarray):
    """Per joint i: the frame before its link (``C_{i-1}``, tracker frame), the frame after ``Rx Tx Ry``
    (whose z is joint i's axis) and the frame after the link; each (N, 4, 4). Also the flange frame."""
    C = np.broadcast_to(model.T_tracker_base, (len(q), 4, 4))
    out = []
    for i, (alpha, a, beta, theta, d) in enumerate(model.links):
        fixed = _rot(0, alpha) @ _trans_x(a) @ _rot(1, beta)
        B = C @ fixed
        C_next = B @ _rot(2, theta + q[:, i]) @ _trans_z(d)
        out.append((C, B, C_next))
        C = C_next
    return out, C @ model.flange


def predict(model: Model, q: np.ndarray) -> np.ndarray:
    """Marker positions in the tracker frame, (N, 3)."""
    F = frames(model, q)[1]
    return F[:, :3, :3] @ model.marker + F[:, :3, 3]


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.stack([u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1], u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2],
                     u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]], axis=1)


def jacobian(model: Model, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Predicted marker positions (N, 3) and their Jacobian (N, 3, P) in ``params`` order."""
    per_joint, F = frames(model, q)
    y = F[:, :3, :3] @ model.marker + F[:, :3, 3]
    cols = [np.broadcast_to(np.eye(3), (len(q), 3, 3)),  # tracker translation
            -_skew(y)]  # tracker rotation vector, applied on the left: d y = phi x y
    for (C, B, C_next), free in zip(per_joint, model.free):
        x_axis, y_axis, z_axis = C[:, :3, 0], B[:, :3, 1], C_next[:, :3, 2]
        candidates = (_cross(x_axis, y - C[:, :3, 3]), x_axis,  # alpha about x_{i-1}, a along it
                      _cross(y_axis, y - B[:, :3, 3]),  # beta about the tilted y
                      _cross(z_axis, y - C_next[:, :3, 3]), z_axis)  # theta about z_i, d along it
        cols += [c[:, :, None] for c, f in zip(candidates, free) if f]
    cols.append(F[:, :3, :3])  # marker
    return y, np.concatenate(cols, axis=2)


def _skew(v: np.ndarray) -> np.ndarray:
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return S - np.swapaxes(S, -1, -2)


def retract(model: Model, delta: np.ndarray) -> Model:
    """``model`` moved by ``delta`` (``jacobian``'s column order)."""
    T = np.eye(4)
    T[:3, :3] = _exp_so3(delta[3:6])
    T[:3, 3] = delta[:3]
    links = model.links.copy()
    links[model.free] += delta[6:-3]
    return Model(links, model.free, model.flange, T @ model.T_tracker_base, model.marker + delta[-3:])


def _exp_so3(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula."""
    theta = float(np.linalg.norm(w))
    K = _skew(w)
    if theta < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + np.sin(theta) / theta * K + (1 - np.cos(theta)) / theta**2 * K @ K


def initial(model: Model, q: np.ndarray, y: np.ndarray) -> Model:
    """Tracker pose by Kabsch on the flange origins, then the marker as the mean of the measurements in the
    flange frames (the same start as kincal's markers experiment)."""
    F = frames(model, q)[1]
    p = F[:, :3, 3]
    pc, yc = p - p.mean(0), y - y.mean(0)
    U, _, Vt = np.linalg.svd(yc.T @ pc)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, y.mean(0) - R @ p.mean(0)
    in_flange = np.einsum("nji,nj->ni", F[:, :3, :3], (y - T[:3, 3]) @ R - p)  # R_F^T (T^-1 y - p)
    return Model(model.links, model.free, model.flange, T, in_flange.mean(0))


@dataclass(frozen=True)
class Fit:
    model: Model
    iterations: int
    cost2: float  # |r|^2 at the end (m^2)
    converged: bool


def solve(model: Model, q: np.ndarray, y: np.ndarray, max_iterations: int = 30) -> Fit:
    """Least squares of ``predict(model, q) - y`` from ``initial``: Gauss-Newton steps from the triangular factor
    of ``[J | r]``; Levenberg-Marquardt damping when a step does not reduce the cost. Stops when the step moves
    the fit by less than 1e-2 of the scatter (whitened step length, as kincal's own test)."""
    model = initial(model, q, y)
    dof = 3 * len(q) - model.size
    for it in range(1, max_iterations + 1):
        pred, J = jacobian(model, q)
        r = (pred - y).reshape(-1)
        R = np.linalg.qr(np.column_stack([J.reshape(-1, model.size), r]), mode="r")
        Rj, qtr, cost2 = R[:-1, :-1], R[:-1, -1], float(r @ r)
        delta = np.linalg.solve(np.triu(Rj), -qtr)
        trial = retract(model, delta)
        new_cost2 = _cost2(trial, q, y)
        if new_cost2 > cost2:
            trial, new_cost2, delta = _damped(model, q, y, Rj, qtr, cost2)
        model = trial
        if np.linalg.norm(Rj @ delta) < max(1e-6 * (1 + np.sqrt(cost2)), 1e-2 * np.sqrt(new_cost2 / max(dof, 1))):
            return Fit(model, it, new_cost2, True)
    return Fit(model, max_iterations, new_cost2, False)


def _cost2(model: Model, q: np.ndarray, y: np.ndarray) -> float:
    e = predict(model, q) - y
    return float(np.sum(e * e))


def _damped(model, q, y, Rj, qtr, cost2):
    """Levenberg-Marquardt steps with growing damping until the cost falls (the current model if it never does)."""
    D = np.diag(np.linalg.norm(Rj, axis=0))
    for lam in 10.0 ** np.arange(-4, 9):
        A = np.vstack([Rj, np.sqrt(lam) * D])
        delta = np.linalg.lstsq(A, np.r_[-qtr, np.zeros(len(qtr))], rcond=None)[0]
        trial = retract(model, delta)
        new_cost2 = _cost2(trial, q, y)
        if new_cost2 < cost2:
            return trial, new_cost2, delta
    return model, cost2, np.zeros(len(qtr))


def ur10() -> Model:
    """The nominal UR10 of ``UR10_DH``."""
    return from_standard_dh(**UR10_DH)
