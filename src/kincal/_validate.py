"""Validation at public entry points: clear messages naming the argument, expected vs found."""

from __future__ import annotations

import numpy as np

from kincal.errors import ManifoldError, ShapeError


def as_array(x, name: str, tail: tuple[int, ...], *, finite: bool = True) -> np.ndarray:
    """Return ``x`` as a float array whose trailing dimensions equal ``tail``."""
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name}: expected a numeric array of shape (..., {_fmt(tail)}), got {type(x).__name__}") from exc
    if arr.ndim < len(tail) or arr.shape[arr.ndim - len(tail):] != tail:
        raise ShapeError(f"{name}: expected shape (..., {_fmt(tail)}), got {arr.shape}")
    if finite and not np.isfinite(arr).all():
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ShapeError(f"{name}: expected finite values, found {arr[tuple(bad)]} at index {tuple(int(i) for i in bad)}")
    return arr


def _fmt(tail: tuple[int, ...]) -> str:
    return ", ".join(str(t) for t in tail)


def check_rotation(R: np.ndarray, name: str, tol: float = 1e-9) -> None:
    """Raise ManifoldError unless every R is orthonormal with determinant +1 (within ``tol``)."""
    err = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(-2, -1))
    det = np.linalg.det(R)
    bad = (err > tol) | (np.abs(det - 1.0) > tol)
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(np.atleast_1d(bad))[0])
        e = np.atleast_1d(err)[idx]
        d = np.atleast_1d(det)[idx]
        where = f" at batch index {idx}" if np.ndim(bad) else ""
        raise ManifoldError(
            f"{name}: rotation{where} is not orthonormal: max |R^T R - I| = {e:.3g}, det = {d:.6g} "
            f"(expected within {tol:g} of an orthonormal matrix with det +1)"
        )


def check_transform(T: np.ndarray, name: str, tol: float = 1e-9) -> np.ndarray:
    """Validate homogeneous transforms (..., 4, 4): finite, last row (0, 0, 0, 1), orthonormal rotation."""
    T = as_array(T, name, (4, 4))
    if T.ndim == 2 and _one_transform_ok(T, tol):  # the common case, without the batch machinery
        return T
    last = T[..., 3, :]
    if np.any(np.abs(last - np.array([0.0, 0.0, 0.0, 1.0])) > tol):
        raise ManifoldError(f"{name}: last row must be (0, 0, 0, 1), got {np.asarray(last).reshape(-1, 4)[0].tolist()}")
    check_rotation(T[..., :3, :3], name, tol)
    return T


_EYE3 = np.eye(3)
_EYE3.setflags(write=False)


# The closed-form determinant of a near-orthonormal R is within 1e-14 of LAPACK's (np.linalg.det): passed here
# only this far inside the tolerance, nearer the batch path decides with LAPACK's.
DET_MARGIN = 1e-12


def _one_transform_ok(T: np.ndarray, tol: float) -> bool:
    """``check_transform``'s tests of one (finite) transform, the same numbers but the determinant's (by the
    rule of Sarrus, ``DET_MARGIN`` inside the tolerance): False where one fails or the determinant is near the
    tolerance (the batch path then decides, and raises with its message)."""
    x, y, z, w = T[3].tolist()
    if abs(x) > tol or abs(y) > tol or abs(z) > tol or abs(w - 1.0) > tol:
        return False
    R = T[:3, :3]
    err = float(np.abs(R.T @ R - _EYE3).max())
    return not (err > tol or abs(det3(R) - 1.0) > tol - DET_MARGIN)


def det3(M: np.ndarray) -> float:
    """The determinant of one 3 x 3 matrix by the rule of Sarrus on Python floats (within about 1e-15 of LAPACK's
    for a rotation; no numpy call)."""
    (a, b, c), (d, e, f), (g, h, i) = M.tolist()
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
