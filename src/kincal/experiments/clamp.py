"""One arm clamped to a fixture: every configuration puts the tool at the same pose ``T_world_fixture``.

Residual (N, 6): the pose gap of the tool from the fixture, in the fixture frame (``pose_gap_in_b``). With the fixture
unknown its pose is a parameter (not a mean of uncalibrated poses).
"""

from __future__ import annotations

from kincal.experiments._kernel import pose_gap_in_b, pose_mean
from kincal.experiments.base import Experiment, Residual
from kincal.noise import ORIENTATION, POSITION
from kincal.schema import LENGTH, WORLD, Field, Role, Schema


SCHEMA = Schema(
    "clamp", arms=1,
    known=(Field("T_world_fixture", "pose", LENGTH, required=False),),
    roles=(Role("fixture", "T_world_fixture", WORLD, "pose"),),
)


class ClampExperiment(Experiment):
    SCHEMA = SCHEMA
    COMPONENTS = (POSITION,) * 3 + (ORIENTATION,) * 3

    def residual(self, state, want=None, jq=True) -> Residual:
        arm = self.arms[0]
        kin = self._kin(state, arm)
        r, GA, GB = pose_gap_in_b(kin.tool, state.extras[self.frames["fixture"]])
        jac, jqs = {}, {}
        self._arm_jac(state, arm, kin, GA, want, jq, jac, jqs)
        if self._wanted("fixture", want):
            jac[self.frames["fixture"]] = GB
        return Residual(r, jac, jqs)

    def initial(self, state, known):
        return {} if "fixture" in known else {"fixture": pose_mean(self._fk(state, self.arms[0]))}
