"""Two arms' tool points at a known distance (1 constraint per configuration).

Residual (N, 1), metres: ``|p_A - p_B| - distance``.
"""

from __future__ import annotations

import numpy as np

from kincal.experiments._kernel import point_jacobian
from kincal.experiments.base import Experiment, Residual


class DistanceExperiment(Experiment):
    KIND = "distance"
    COMPONENTS = ("position",)

    def residual(self, state, want=None) -> Residual:
        a, b = self.arms
        kinA, JA, jqA = self._arm(state, a, want)
        kinB, JB, jqB = self._arm(state, b, want)
        diff = kinA.tool[:, :3, 3] - kinB.tool[:, :3, 3]
        dist = np.linalg.norm(diff, axis=-1, keepdims=True)
        u = (diff / dist)[:, None, :]  # (N, 1, 3)
        GA = u @ point_jacobian(kinA.tool[:, :3, 3])
        GB = -(u @ point_jacobian(kinB.tool[:, :3, 3]))
        jac = {f"{a}.{k}": GA @ v for k, v in JA.items()}
        jac.update({f"{b}.{k}": GB @ v for k, v in JB.items()})
        return Residual(dist - self.dataset.known["distance"], jac, {a: GA @ jqA, b: GB @ jqB})

    def initial(self, state, known):
        return {}
