"""The gauge: which coordinates the solver moves when the data do not determine them all, and the pivot order
of the named null directions."""

from __future__ import annotations

import fnmatch

import numpy as np

from kincal.analysis import Identifiability, identify, select_columns
from kincal.analysis.naming import blocks_of, pivot_order
from kincal.errors import ModelError
from kincal.estimation import steps
from kincal.params import COMPLIANCE, LATERAL, State, retract

def priority(problem, gauge) -> list[int]:
    """Free-coordinate order for pivots: user globs first (if any), then arm offsets, twists, home, base, tool,
    then experiment frames."""
    layout = problem.layout
    default = pivot_order(layout, problem.free_idx)  # stable: by (rank, k)
    if isinstance(gauge, str):
        return default
    blk = blocks_of(layout, problem.free_idx)
    names = [layout.names[i] for i in problem.free_idx]
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


def rigid_gauges(problem, lin) -> np.ndarray | None:
    """The exact gauges of the rigid model at ``lin``'s state where the weight lifts them (p, k natural units,
    free coordinates), else None: the null space of the Jacobian there with every compliance at 0.

    Redundant POE coordinates (a joint offset against the next twists and the home pose, a common shift of all
    axes against a free world frame) give the same joint screws in space, so the same torques under a tool
    load, and stay exact gauges. But the centres of mass of a mass model are given in the nominal frames, which
    such a move carries along with a choice the geometry cannot see: the weight's lever arms change, and lift
    the gauge by that convention and the noise alone; a tilt of the whole arm relative to gravity, against an
    unknown tracker, changes the sag bilinearly in the compliances. The solver would walk metres along them
    (Agile Justin: the torso's axes 40 m off after a few hundred steps). ``identify`` holds them (its ``hold``: taken once, at
    the start), pinning one coordinate per direction.

    All of the rigid model's gauges, lifted at the start or not: at a start with every compliance at 0 the
    weight lifts nothing yet, and would once the compliances move."""
    if not _weight_loads_compliance(problem, lin.state):
        return None
    rigid = steps.linearize(problem, _rigid(problem.layout, lin.state), lin.W, False)
    null = identify(rigid, problem.layout, problem.experiments, report=False).null_space
    return null if null.shape[1] else None


def _weight_loads_compliance(problem, state: State) -> bool:
    """Some arm has a weight, and some compliance is free or not 0."""
    if not any(a.weights is not None for a in state.arms.values()):
        return False
    layout = problem.layout
    return any(layout.free[b.slice].any() or np.any(b.kind.values(b.value(state)))
               for b in layout.blocks if b.kind in (COMPLIANCE, LATERAL) and b.stop > b.start)


def _rigid(layout, state: State) -> State:
    """``state`` with every compliance at 0."""
    delta = np.zeros(layout.size)
    for b in layout.blocks:
        if b.kind in (COMPLIANCE, LATERAL) and b.stop > b.start:
            delta[b.slice] = -b.kind.values(b.value(state))
    return retract(state, layout, delta)
