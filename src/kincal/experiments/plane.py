"""A tool point touching a plane ``n . p = d`` (1 constraint per configuration).

Residual (N, 1), metres: ``n . p_world_tool(q) - d``. An unknown plane is a parameter: its normal moves in
its 2-dimensional tangent (``plane.n_1``, ``plane.n_2``), its offset by ``plane.d``.
"""

from __future__ import annotations

import numpy as np

from kincal.experiments._kernel import point_jacobian
from kincal.experiments.base import Experiment, Residual
from kincal.noise import POSITION
from kincal.schema import LENGTH, WORLD, Field, Role, Schema


SCHEMA = Schema(
    "plane", arms=1,
    known=(Field("plane_world", "plane", LENGTH, required=False, doc="n . p = d with unit n, world frame"),),
    roles=(Role("plane", "plane_world", WORLD, "plane"),),
)


class PlaneExperiment(Experiment):
    SCHEMA = SCHEMA
    COMPONENTS = (POSITION,)

    def residual(self, state, want=None, jq=True) -> Residual:
        arm = self.arms[0]
        pl = state.extras[self.frames["plane"]]
        n, d = pl.unit()
        kin = self._kin(state, arm)
        p = kin.tool[:, :3, 3]
        jac, jqs = {}, {}
        self._arm_jac(state, arm, kin, (n @ point_jacobian(p))[:, None, :], want, jq, jac, jqs)
        if self._wanted("plane", want):
            dn = (p @ (np.eye(3) - np.outer(n, n)) / np.linalg.norm(pl.normal)) @ pl.U  # (N, 2)
            jac[self.frames["plane"]] = np.concatenate([dn, -np.ones((len(p), 1))], axis=-1)[:, None, :]
        return Residual((p @ n - d)[:, None], jac, jqs)

    def initial(self, state, known):
        if "plane" in known:
            return {}
        p = self._fk(state, self.arms[0])[:, :3, 3]
        c = p.mean(axis=0)
        n = np.linalg.svd(p - c)[2][-1]
        return {"plane": np.append(n, n @ c)}
