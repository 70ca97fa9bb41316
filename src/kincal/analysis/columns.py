"""Block Jacobians into columns of the parameter layout: the one place that scatters them."""

from __future__ import annotations

from typing import Mapping

import numpy as np

from kincal._memo import remember
from kincal.params import Layout


def scatter_columns(blocks: Mapping[str, np.ndarray], layout: Layout, cols: np.ndarray, shape: tuple[int, ...],
                    right: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
    """``(*shape, len(cols))``: each block's Jacobian ``blocks[name]`` (``(*shape, d)``, d the block's size) in the
    columns of ``cols`` (layout indices) that fall in the block; columns of other coordinates stay zero.
    ``right``: per block, a (d, d) matrix multiplying its Jacobian first (retraction Jacobians of pose blocks
    stepped away from their linearization point)."""
    plan, covered = _plan(layout, cols)
    every = covered and all(name in blocks for name, _, _ in plan)  # every column written: no zeros first
    J = (np.empty if every else np.zeros)(tuple(shape) + (len(cols),))
    for name, dst, sel in plan:
        Jb = blocks.get(name)
        if Jb is None:
            continue
        if right is not None and name in right:
            Jb = Jb @ right[name]
        if sel is None:
            J[..., dst] = Jb  # the whole block in consecutive columns: a slice, not fancy indexing
        else:
            J[..., dst] = Jb[..., sel]
    return J


def _plan(layout: Layout, cols: np.ndarray) -> tuple:
    """(per layout block with a column in ``cols``: (name, destination columns, the block's selected coordinates or
    None for all of them, in consecutive columns), whether they write every column of ``cols``). Remembered by
    what it is made of, the blocks' names and ranges, the layout's size and the bytes of ``cols``: the same for
    every evaluation of a solve and for every calibration of the same structure (each builds its own layout)."""
    key = (tuple((b.name, b.start, b.stop) for b in layout.blocks), layout.size, np.asarray(cols).tobytes())
    plan = _PLANS.get(key)
    if plan is not None:
        return plan
    col = np.full(layout.size, -1)
    col[cols] = np.arange(len(cols))
    plan = []
    for b in layout.blocks:
        c = col[b.start: b.stop]
        sel = c >= 0
        if len(c) and c[0] >= 0 and c[-1] - c[0] == len(c) - 1 and (len(c) == 1 or (np.diff(c) == 1).all()):
            plan.append((b.name, slice(int(c[0]), int(c[-1]) + 1), None))
        elif sel.any():
            plan.append((b.name, _frozen(c[sel]), _frozen(sel)))
    covered = int((col >= 0).sum()) == len(cols)  # repeated columns: some stay unwritten
    return remember(_PLANS, key, (tuple(plan), covered), PLAN_ENTRIES)


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


PLAN_ENTRIES = 64
_PLANS: dict = {}


def clear_plans() -> None:
    """Forget every remembered plan (``symmetries.clear_structure_cache`` calls this)."""
    _PLANS.clear()
