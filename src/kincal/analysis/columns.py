"""Block Jacobians into columns of the parameter layout: the one place that scatters them."""

from __future__ import annotations

from typing import Mapping

import numpy as np

from kincal.params import Layout


def scatter_columns(blocks: Mapping[str, np.ndarray], layout: Layout, cols: np.ndarray, shape: tuple[int, ...],
                    right: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
    """``(*shape, len(cols))``: each block's Jacobian ``blocks[name]`` (``(*shape, d)``, d the block's size) in the
    columns of ``cols`` (layout indices) that fall in the block; columns of other coordinates stay zero.
    ``right``: per block, a (d, d) matrix multiplying its Jacobian first (retraction Jacobians of pose blocks
    stepped away from their linearization point)."""
    col = np.full(layout.size, -1)
    col[cols] = np.arange(len(cols))
    J = np.zeros(tuple(shape) + (len(cols),))
    for b in layout.blocks:
        Jb = blocks.get(b.name)
        if Jb is None:
            continue
        if right is not None and b.name in right:
            Jb = Jb @ right[b.name]
        c = col[b.start: b.stop]
        sel = c >= 0
        if len(c) and c[0] >= 0 and c[-1] - c[0] == len(c) - 1 and (len(c) == 1 or (np.diff(c) == 1).all()):
            J[..., c[0]: c[-1] + 1] = Jb  # the whole block in consecutive columns: a slice, not fancy indexing
        elif sel.any():
            J[..., c[sel]] = Jb[..., sel]
    return J
