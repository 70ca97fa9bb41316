"""The gauge: which coordinates the solver moves when the data do not determine them all, and the pivot order
of the named null directions."""

from __future__ import annotations

import fnmatch

import numpy as np

from kincal.analysis import Identifiability, select_columns
from kincal.analysis.naming import blocks_of
from kincal.errors import ModelError

def priority(problem, gauge) -> list[int]:
    """Free-coordinate order for pivots: user globs first (if any), then arm offsets, twists, home, base, tool,
    then experiment frames."""
    layout = problem.layout
    names = [layout.names[i] for i in problem.free_idx]
    blk = blocks_of(layout, problem.free_idx)
    default = sorted(range(len(names)), key=lambda k: (blk[k].kind.rank, k))
    if isinstance(gauge, str):
        return default
    order: list[int] = []
    for pat in gauge:
        hit = [k for k in default if k not in order and (
            fnmatch.fnmatchcase(names[k], pat) or fnmatch.fnmatchcase(blk[k].name, pat))]
        if not hit:
            raise ModelError(f"gauge priority pattern {pat!r} matches no free parameter")
        order += hit
    return order + [k for k in default if k not in order]


def gauge_basis(Rf: np.ndarray, ana: Identifiability, gauge, order) -> np.ndarray:
    """Columns spanning the coordinates the solver moves: the identifiable subspace (min-change) or the
    identifiable parameters first in the user's priority order (the rest held)."""
    if isinstance(gauge, str):
        return ana.range_space
    R = ana.range_space  # columns independent there avoid every null direction, a held scale included
    return np.eye(Rf.shape[1])[:, select_columns(Rf @ R @ R.T, order, ana.rank)]
