"""The tool point held in a socket (ball joint): position constrained (3), orientation free.

Residual (N, 3), metres: ``p_world_tool(q) - p_world_socket``.
"""

from __future__ import annotations

import numpy as np

from kincal.experiments._kernel import point_jacobian
from kincal.experiments.base import Experiment, Residual
from kincal.noise import POSITION
from kincal.schema import LENGTH, WORLD, Field, Role, Schema


SCHEMA = Schema(
    "socket", arms=1,
    known=(Field("p_world_socket", "vector", LENGTH, required=False, size=3, doc="the socket, world frame"),),
    roles=(Role("socket", "p_world_socket", WORLD, "point"),),
)


class SocketExperiment(Experiment):
    SCHEMA = SCHEMA
    COMPONENTS = (POSITION,) * 3
    WORLD_VECTOR = True

    def residual(self, state, want=None, jq=True) -> Residual:
        arm = self.arms[0]
        kin = self._kin(state, arm)
        p = kin.tool[:, :3, 3]
        jac, jqs = {}, {}
        self._arm_jac(state, arm, kin, point_jacobian(p), want, jq, jac, jqs)
        if self._wanted("socket", want):
            jac[self.frames["socket"]] = np.broadcast_to(-np.eye(3), (len(p), 3, 3))
        return Residual(p - state.extras[self.frames["socket"]], jac, jqs)

    def initial(self, state, known):
        return {} if "socket" in known else {"socket": self._fk(state, self.arms[0])[:, :3, 3].mean(axis=0)}
