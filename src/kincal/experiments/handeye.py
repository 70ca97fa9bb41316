"""A starting value for a tool frame far from nominal: the hand-eye problem ``A X = X B``.

Full-pose data with an unknown tracker say ``T_world_tracker T_tracker_tool_i = F_i X``, with ``F_i`` the
nominal model's tool poses and X the tool frame's error. Relative motions between configurations remove the
tracker: ``A_ij X = X B_ij`` with ``A_ij = F_i^-1 F_j`` and ``B_ij = M_i^-1 M_j``. The rotation follows from the
rotation vectors (``a_ij = R_X b_ij``: an uncentred Procrustes fit), the translation from
``(R_A - I) t_X = R_X t_B - t_A`` by least squares. The nominal arm's own errors only perturb the result: it is
a starting point for the solver, whose local steps fail when the tool is turned by more than about 110 deg.
"""

from __future__ import annotations

import numpy as np

from kincal.lie import se3, so3

_USABLE = (0.1, 2.8)  # relative rotation angles (rad) whose axis is well defined and away from pi


def hand_eye(F: np.ndarray, M: np.ndarray) -> np.ndarray | None:
    """X (4, 4) with ``F_i X ~ W M_i`` for some W; None when the motions do not determine it (fewer than two
    usable relative rotations about different axes)."""
    i, j = _pairs(len(F))
    A = se3.inverse(F[i]) @ F[j]
    B = se3.inverse(M[i]) @ M[j]
    a, b = so3.log(A[:, :3, :3]), so3.log(B[:, :3, :3])
    ta, tb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
    use = (ta > _USABLE[0]) & (ta < _USABLE[1]) & (tb > _USABLE[0]) & (tb < _USABLE[1])
    if use.sum() < 2:
        return None
    a, b = a[use], b[use]
    if np.linalg.matrix_rank(b, tol=1e-3 * np.max(tb[use])) < 2:
        return None
    U, _, Vt = np.linalg.svd(a.T @ b)
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    RA = A[use, :3, :3]
    lhs = (RA - np.eye(3)).reshape(-1, 3)
    rhs = ((R @ B[use, :3, 3, None])[..., 0] - A[use, :3, 3]).reshape(-1)
    t = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    return se3.make(R, t)


PAIRS = 4000  # relative motions used at most: plenty, and cheap
_ENUMERATED = 2000  # up to this many configurations the subset is drawn from every pair


def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs i < j of ``n`` configurations, at most PAIRS of them (a fixed random subset); drawn directly
    for large ``n``, whose list of every pair would take memory quadratic in ``n``."""
    rng = np.random.default_rng(0)
    if n <= _ENUMERATED:
        i, j = np.triu_indices(n, 1)
        if len(i) > PAIRS:
            keep = rng.choice(len(i), PAIRS, replace=False)
            i, j = i[keep], j[keep]
        return i, j
    a, b = rng.integers(0, n, (2, 2 * PAIRS))
    pairs = np.unique(np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)[a != b], axis=0)[:PAIRS]
    return pairs[:, 0], pairs[:, 1]
