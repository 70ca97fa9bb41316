"""Two arms clamped tool to tool: ``T_world_toolA(q_A) @ T_toolA_toolB = T_world_toolB(q_B)``.

One residual per configuration over both arms' parameters and the clamp (no halving of the error):
pose gap (N, 6) between ``T_world_toolA @ T_toolA_toolB`` and ``T_world_toolB``, in arm B's tool frame. The clamp's left increment
is expressed in arm A's tool frame. Using one arm as the measuring device of the other is this residual with
that arm's parameters fixed.
"""

from __future__ import annotations

from kincal.experiments._kernel import pose_gap_in_b, pose_mean
from kincal.experiments.base import Experiment, Residual
from kincal.noise import ORIENTATION, POSITION
from kincal.lie import se3
from kincal.schema import BETWEEN, LENGTH, Field, Role, Schema


SCHEMA = Schema(
    "dual", arms=2,
    known=(Field("T_toolA_toolB", "pose", LENGTH, required=False, doc="arm B's tool in arm A's tool"),),
    roles=(Role("clamp", "T_toolA_toolB", BETWEEN, "pose"),),
)


class DualExperiment(Experiment):
    SCHEMA = SCHEMA
    COMPONENTS = (POSITION,) * 3 + (ORIENTATION,) * 3

    def residual(self, state, want=None, jq=True) -> Residual:
        a, b = self.arms
        C = state.extras[self.frames["clamp"]]
        kinA, kinB = self._kin(state, a), self._kin(state, b)
        r, GA, GB = pose_gap_in_b(kinA.tool @ C, kinB.tool)
        jac, jqs = {}, {}
        self._arm_jac(state, a, kinA, GA, want, jq, jac, jqs)
        self._arm_jac(state, b, kinB, GB, want, jq, jac, jqs)
        if self._wanted("clamp", want):
            jac[self.frames["clamp"]] = GA @ se3.adjoint(kinA.tool)
        return Residual(r, jac, jqs)

    def initial(self, state, known):
        if "clamp" in known:
            return {}
        a, b = self.arms
        return {"clamp": pose_mean(se3.inverse(self._fk(state, a)) @ self._fk(state, b))}

    def increment_frames(self, state):
        return {"clamp": self._fk(state, self.arms[0])[0]}
