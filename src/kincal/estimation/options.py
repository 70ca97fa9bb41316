"""How ``solve`` runs: gauge, loss, iteration budget, rank tolerance, reporting."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

from kincal.errors import ModelError


@dataclass(frozen=True)
class SolverOptions:
    """Options of ``solve`` (and of ``calibrate``, which takes them as keywords).

    ``gauge``: ``"min-change"`` (the minimum-norm step in natural units, m and rad, over the identifiable
    subspace) or a priority list of parameter globs (keep the first identifiable parameters in that order,
    hold the rest). ``loss`` and ``f_scale``: ``scipy.optimize.least_squares``' robust loss (``"linear"``: plain
    least squares, Gauss-Newton first). ``max_outer``: outer re-linearizations. ``rank_rtol``: relative
    singular value below which a direction is unidentifiable (``kincal.analysis.analyse``).
    ``correlation_threshold``: |rho| from which parameter pairs are reported as correlated. ``progress``:
    called with (outer iteration, whitened cost) after every step.
    """

    gauge: str | Sequence[str] = "min-change"
    loss: str = "linear"
    f_scale: float = 1.0
    max_outer: int = 20
    rank_rtol: float = 1e-9
    correlation_threshold: float = 0.9
    progress: Callable[[int, float], None] | None = None

    def __post_init__(self) -> None:
        if isinstance(self.gauge, str) and self.gauge != "min-change":
            raise ModelError(f"gauge must be 'min-change' or a list of parameter globs in priority order, "
                             f"got {self.gauge!r}")
