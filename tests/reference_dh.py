"""An independent reference for DH / modified-DH forward kinematics: plain per-link matrix products of the
published tables, one configuration at a time (deliberately not kincal's code)."""

import numpy as np


def rx(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]])


def rz(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])


def tr(x, z):
    return np.array([[1, 0, 0, x], [0, 1, 0, 0], [0, 0, 1, z], [0, 0, 0, 1.0]])


def dh_fk(q, a, alpha, d, theta=None, prismatic=None, modified=False, flange=None):
    """Tool poses (N, 4, 4) for joint values q (N, n); ``theta`` are constant joint-angle offsets."""
    n = len(a)
    theta = np.zeros(n) if theta is None else theta
    prismatic = [False] * n if prismatic is None else prismatic
    out = np.empty((len(q), 4, 4))
    for k, qk in enumerate(q):
        T = np.eye(4)
        for i in range(n):
            th = theta[i] + (0 if prismatic[i] else qk[i])
            di = d[i] + (qk[i] if prismatic[i] else 0)
            T = T @ (rx(alpha[i]) @ tr(a[i], 0) @ rz(th) @ tr(0, di) if modified
                     else rz(th) @ tr(0, di) @ tr(a[i], 0) @ rx(alpha[i]))
        out[k] = T if flange is None else T @ flange
    return out
