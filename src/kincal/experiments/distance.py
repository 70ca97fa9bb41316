"""Two arms' tool points at a known distance (1 constraint per configuration).

Residual (N, 1), metres: ``|p_A - p_B| - distance``.
"""

from __future__ import annotations

import numpy as np

from kincal.experiments._kernel import point_jacobian
from kincal.experiments.base import Experiment, Residual
from kincal.noise import POSITION
from kincal.schema import LENGTH, Field, Schema


SCHEMA = Schema(
    "distance", arms=2,
    known=(Field("distance", "scalar", LENGTH, doc="|p_A - p_B| of the two arms' tool points"),),
)


class DistanceExperiment(Experiment):
    SCHEMA = SCHEMA
    COMPONENTS = (POSITION,)

    def residual(self, state, want=None, jq=True) -> Residual:
        a, b = self.arms
        kinA, kinB = self._kin(state, a), self._kin(state, b)
        diff = kinA.tool[:, :3, 3] - kinB.tool[:, :3, 3]
        dist = np.linalg.norm(diff, axis=-1, keepdims=True)
        u = (diff / dist)[:, None, :]  # (N, 1, 3)
        jac, jqs = {}, {}
        self._arm_jac(state, a, kinA, u @ point_jacobian(kinA.tool[:, :3, 3]), want, jq, jac, jqs)
        self._arm_jac(state, b, kinB, -(u @ point_jacobian(kinB.tool[:, :3, 3])), want, jq, jac, jqs)
        return Residual(dist - self.dataset.known["distance"], jac, jqs)

    def initial(self, state, known):
        return {}
