"""Linear joint couplings within one arm: a coupled joint's reading is a linear function of other readings.

``couplings = {joint: {other: coefficient, ..., "constant": c}}`` (DLR Agile Justin's torso:
``{"t4": {"t2": -1, "t3": -1}}``, i.e. ``q_t4 = -q_t2 - q_t3``). A coupled joint keeps its own geometry and
offset parameters; only its reading is derived. Couplings may chain (``t5`` from ``t4`` from ``t2``); they are
resolved into ``q_full = q A^T + b`` with ``A`` (n, n) the identity on free joints and zero columns at coupled
joints, so ``A`` also carries the derivative w.r.t. the readings (encoder noise enters through free joints only).
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Mapping

import numpy as np

from kincal.errors import ModelError

CONSTANT = "constant"  # the key of a coupling's constant term (model units: rad or m)


def checked_couplings(couplings, names: tuple[str, ...], where: str) -> Mapping[str, Mapping[str, float]]:
    """``couplings`` validated against the joint ``names``: known joints, finite numbers, no joint depending on
    itself directly or through a chain of couplings; one-line ModelError otherwise."""
    out = {}
    for joint, terms in dict(couplings or {}).items():
        at = f"{where}: couplings.{joint}"
        if joint not in names:
            raise ModelError(f"{at}: no such joint; joints: {', '.join(names)}")
        if not isinstance(terms, Mapping) or not terms:
            raise ModelError(f"{at}: expected a mapping joint -> coefficient (and optionally '{CONSTANT}')")
        clean = {}
        for other, coef in terms.items():
            if other != CONSTANT and other not in names:
                raise ModelError(f"{at}.{other}: no such joint; joints: {', '.join(names)}")
            value = _finite(coef)
            if value is None:
                raise ModelError(f"{at}.{other}: expected a finite number, found {coef!r}")
            clean[str(other)] = value
        out[str(joint)] = MappingProxyType(clean)
    for joint in out:
        _check_acyclic(out, joint, (joint,), where)
    return MappingProxyType(out)


def _finite(x) -> float | None:
    """``x`` as a finite float, or None (booleans, text, arrays and non-finite values are not coefficients)."""
    if isinstance(x, (bool, str)) or np.ndim(x):
        return None
    try:
        value = float(x)
    except (TypeError, ValueError):
        return None
    return value if np.isfinite(value) else None


def _check_acyclic(couplings, joint: str, path: tuple[str, ...], where: str) -> None:
    for other in couplings[joint]:
        if other == CONSTANT:
            continue
        if other == path[0]:
            chain = " -> ".join((*path, other))
            raise ModelError(f"{where}: couplings.{path[0]}: joint {path[0]} depends on itself ({chain})")
        if other in couplings and other not in path:
            _check_acyclic(couplings, other, (*path, other), where)


def coupling_map(couplings: Mapping[str, Mapping[str, float]], names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """``(A (n, n), b (n,))`` with ``q_full = q A^T + b`` for readings q whose coupled entries are ignored."""
    n = len(names)
    A, b = np.eye(n), np.zeros(n)
    idx = {name: i for i, name in enumerate(names)}
    done: dict[str, tuple[np.ndarray, float]] = {}

    def resolve(joint: str) -> tuple[np.ndarray, float]:
        if joint not in couplings:
            return np.eye(n)[idx[joint]], 0.0
        if joint not in done:
            row, const = np.zeros(n), couplings[joint].get(CONSTANT, 0.0)
            for other, coef in couplings[joint].items():
                if other != CONSTANT:
                    r, c = resolve(other)
                    row, const = row + coef * r, const + coef * c
            done[joint] = (row, const)
        return done[joint]

    for joint in couplings:
        A[idx[joint]], b[idx[joint]] = resolve(joint)
    return A, b


def derive_readings(couplings, names, q) -> np.ndarray:
    """Readings q (..., n) with the coupled joints' entries replaced by their derived values."""
    if not couplings:
        return np.asarray(q, dtype=float)
    A, b = coupling_map(couplings, names)
    return np.asarray(q, dtype=float) @ A.T + b
