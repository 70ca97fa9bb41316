"""Known relations between experiment frames, as extra residual rows: a known distance between two frames.

Fixed-point calibration (a tool ball held in one of two sockets a known distance apart, MUKCa) has no measured
length in any experiment: without one the arm's size cannot be identified, and at level ``kinematic`` the
least-squares optimum is an arm collapsed onto the ball. ``FrameDistance`` states the distance between two
frames' origins (socket points, fixture or tracker poses) with its uncertainty; its row,
``(|p_a - p_b| - distance) / sigma``, joins the whitened problem like a prior.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from kincal.analysis.columns import scatter_columns
from kincal.errors import ModelError
from kincal.params import Layout, State


@dataclass(frozen=True)
class FrameDistance:
    """``|origin(a) - origin(b)| = distance`` (m) with standard deviation ``sigma`` (m); ``a``, ``b`` name frames
    of the calibration (``socket``, ``s1.socket``, ``fixture``, ...)."""

    a: str
    b: str
    distance: float
    sigma: float

    def check(self, state: State) -> None:
        frames = [k for k, v in state.extras.items() if state.kinds[k].origin(v) is not None]
        for name in (self.a, self.b):
            if name not in frames:
                raise ModelError(f"distance constraint {self.a!r}-{self.b!r}: {name!r} is no frame with an origin of "
                                 f"this calibration; frames: {', '.join(frames) or 'none'}")
        if self.a == self.b:
            raise ModelError(f"distance constraint: expected two different frames, found {self.a!r} twice")
        if not (np.isfinite(self.distance) and self.distance > 0):
            raise ModelError(f"distance constraint {self.a!r}-{self.b!r}: distance must be > 0, found {self.distance}")
        if not (np.isfinite(self.sigma) and self.sigma > 0):
            raise ModelError(f"distance constraint {self.a!r}-{self.b!r}: sigma must be > 0, found {self.sigma}")


def constraint_rows(constraints: Sequence[FrameDistance], state: State, layout: Layout, Rl, cols=None) -> tuple:
    """Whitened rows (c,) and their Jacobian (c, len(cols)) over the layout coordinates ``cols`` (default: every
    one); ``Rl`` are the retraction Jacobians of pose blocks stepped away from their linearization point."""
    r = np.zeros(len(constraints))
    blocks: dict[str, np.ndarray] = {}
    for i, c in enumerate(constraints):
        d = _origin(state, c.a) - _origin(state, c.b)
        n = np.linalg.norm(d)
        r[i] = (n - c.distance) / c.sigma
        u = d / max(n, 1e-300) / c.sigma
        for name, sign in ((c.a, 1.0), (c.b, -1.0)):
            g = sign * u @ state.kinds[name].origin_jacobian(state.extras[name])
            blocks.setdefault(name, np.zeros((len(constraints), len(g))))[i] += g
    cols = np.arange(layout.size) if cols is None else cols
    return r, scatter_columns(blocks, layout, cols, (len(constraints),), Rl)


def _origin(state: State, name: str) -> np.ndarray:
    return state.kinds[name].origin(state.extras[name])
