"""A singular value decomposition (and least squares) that does not give up: LAPACK's divide and conquer, else
its QR iteration.

numpy's ``svd`` calls LAPACK ``gesdd`` (divide and conquer), which raises "SVD did not converge" on some
ill-conditioned matrices (a kinematic + elastic Jacobian of DLR's Agile Justin); ``gesvd`` (QR iteration, in
scipy) is slower but converges on them. Every SVD of ``kincal.analysis`` and ``kincal.estimation`` goes through
``svd`` here, every least-squares solve through ``lstsq``.
"""

from __future__ import annotations

import math

import numpy as np

try:  # numpy's own LAPACK kernels (``numpy.linalg``'s calls, without their checks and wrappers)
    from numpy.linalg import _umath_linalg as _kernels
    _kernels.qr_r_raw, _kernels.qr_complete, _kernels.svd_s
except (ImportError, AttributeError):  # pragma: no cover - another numpy: ``numpy.linalg`` itself
    _kernels = None


def svd(a, full_matrices: bool = True, compute_uv: bool = True):
    """``numpy.linalg.svd(a, full_matrices, compute_uv)`` (``(U, S, Vt)``, or ``S`` without ``compute_uv``),
    redone with LAPACK's ``gesvd`` when ``gesdd`` does not converge. ``a`` (..., m, n): a stack is decomposed
    matrix by matrix on the fallback."""
    try:
        return np.linalg.svd(a, full_matrices=full_matrices, compute_uv=compute_uv)
    except np.linalg.LinAlgError:
        a = np.asarray(a, dtype=float)
        if not np.all(np.isfinite(a)):  # no driver decomposes nan or inf: numpy's error says what failed
            raise
        return _gesvd(a, full_matrices, compute_uv)


def thin_svd(a: np.ndarray):
    """``svd(a, full_matrices=False)`` as a tuple ``(U, S, Vt)``, bit for bit: for a float64 matrix numpy's
    ``gesdd`` kernel itself, without ``numpy.linalg.svd``'s checks and wrapping (the rank analysis asks at every
    linearization); anything else, or a ``gesdd`` that does not converge, through ``svd``."""
    if _kernels is None or type(a) is not np.ndarray or a.dtype != np.float64 or a.ndim != 2 or not a.size:
        return tuple(svd(a, full_matrices=False))
    try:
        with np.errstate(call=_svd_error, invalid="call", over="ignore", divide="ignore", under="ignore"):
            return _kernels.svd_s(a, signature="d->ddd")
    except np.linalg.LinAlgError:
        return tuple(svd(a, full_matrices=False))


def _svd_error(err, flag):
    raise np.linalg.LinAlgError("SVD did not converge")


def _gesvd(a: np.ndarray, full_matrices: bool, compute_uv: bool):
    """The same outputs as ``numpy.linalg.svd`` by scipy's ``gesvd`` driver (rare: only after gesdd failed)."""
    import scipy.linalg  # here, not at the top: importing it costs more than importing kincal.estimation

    if a.ndim == 2:
        return scipy.linalg.svd(a, full_matrices=full_matrices, compute_uv=compute_uv, lapack_driver="gesvd")
    parts = [_gesvd(m, full_matrices, compute_uv) for m in a.reshape(-1, *a.shape[-2:])]
    if not compute_uv:
        return np.stack(parts).reshape(*a.shape[:-2], -1)
    return tuple(np.stack(p).reshape(*a.shape[:-2], *p[0].shape) for p in zip(*parts))


def lstsq(a, b) -> np.ndarray:
    """The minimum-norm least-squares solution x of ``a x = b`` (``numpy.linalg.lstsq(a, b, rcond=None)[0]``:
    LAPACK ``gelsd``, an SVD by divide and conquer), redone with ``gelsy`` (complete orthogonal factorization)
    when ``gelsd`` does not converge."""
    try:
        return np.linalg.lstsq(a, b, rcond=None)[0]
    except np.linalg.LinAlgError:
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            raise
        import scipy.linalg  # here, not at the top: importing it costs more than importing kincal.estimation

        return scipy.linalg.lstsq(a, b, lapack_driver="gelsy")[0]


def norm(x: np.ndarray) -> float:
    """The 2-norm of a vector (Frobenius of a matrix): ``numpy.linalg.norm(x)``'s arithmetic (``sqrt(x . x)`` over
    the raveled real array, bit for bit) without its dispatch, which costs more than the sum at these sizes."""
    x = x.ravel() if type(x) is np.ndarray else np.ravel(x)  # the method: without ``np.ravel``'s dispatch
    return math.sqrt(x @ x)


def norms(x: np.ndarray, axis: int) -> np.ndarray:
    """The 2-norms along ``axis`` of a float array: ``numpy.linalg.norm(x, axis=axis)``'s arithmetic (``sqrt`` of
    ``add.reduce`` of the squares, bit for bit) without its dispatch (the analysis asks at every linearization)."""
    return np.sqrt(np.add.reduce(x * x, axis=axis))


def complete_q(a: np.ndarray, overwrite: bool = False) -> np.ndarray:
    """``numpy.linalg.qr(a, mode="complete")[0]``, bit for bit: for a float64 (m, n) array with m > n, numpy's two
    LAPACK calls (``geqrf``, ``orgqr``) without building R, which a caller wanting Q only discards (else numpy's
    call itself). ``overwrite``: ``a`` is the caller's scratch, used by the kernels instead of a copy."""
    if _kernels is None or a.dtype != np.float64 or a.ndim != 2 or not a.shape[0] > a.shape[1]:
        return np.linalg.qr(a, mode="complete")[0]
    if not overwrite:
        a = a.copy()  # overwritten by the kernels, as numpy's copy is
    with np.errstate(call=_qr_error, invalid="call", over="ignore", divide="ignore", under="ignore"):
        tau = _kernels.qr_r_raw(a, signature="d->d")
        return _kernels.qr_complete(a, tau, signature="dd->d")


def null_and_range(A: np.ndarray, scratch: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal bases of span(A) (p, k independent columns) and of its complement (p, p - k), from one complete
    QR (Householder: as accurate as an SVD for independent columns, half its cost at p = 45, k = 18). ``scratch``:
    A is the caller's to overwrite."""
    p, k = A.shape
    if k == 0:
        return A, np.eye(p)
    Q = complete_q(A, overwrite=scratch)
    return Q[:, :k], Q[:, k:]


def _qr_error(err, flag):
    raise np.linalg.LinAlgError("Incorrect argument found while performing QR factorization")
