"""A plate with K fixtures at known relative transforms; sample i is clamped at fixture k_i.

Residual (N, 6): pose gap between ``T_world_tool(q_i)`` and ``T_world_plate @ T_plate_fixture[k_i]``, in
that fixture's frame (``pose_gap_in_b``).
"""

from __future__ import annotations

import numpy as np

from kincal.errors import DegenerateExperimentError
from kincal.experiments._kernel import pose_gap_in_b, pose_mean
from kincal.experiments.base import Experiment, Residual
from kincal.noise import ORIENTATION, POSITION
from kincal.lie import se3
from kincal.schema import LENGTH, WORLD, Field, Role, Schema


SCHEMA = Schema(
    "plate", arms=1,
    measured=(Field("fixture", "index", columns=("fixture",), bound="T_plate_fixture",
                    doc="0-based index of the fixture each sample is clamped at"),),
    known=(Field("T_plate_fixture", "poses", LENGTH, size="K", doc="the fixtures in the plate frame"),
           Field("T_world_plate", "pose", LENGTH, required=False)),
    roles=(Role("plate", "T_world_plate", WORLD, "pose"),),
)


class PlateExperiment(Experiment):
    SCHEMA = SCHEMA
    COMPONENTS = (POSITION,) * 3 + (ORIENTATION,) * 3

    def check(self):
        k = self.dataset.measured["fixture"]
        K = self.dataset.known["T_plate_fixture"].shape[0]
        bad = np.flatnonzero((k < 0) | (k >= K) | (k != np.round(k)))
        if len(bad):
            raise DegenerateExperimentError(
                f"data set '{self.name}': sample {bad[0]} field 'fixture' is {k[bad[0]]}, expected an integer in [0, {K})"
            )

    def _fixtures(self):
        return self.dataset.known["T_plate_fixture"][self.dataset.measured["fixture"].astype(int)]

    def residual(self, state, want=None, jq=True) -> Residual:
        arm = self.arms[0]
        kin = self._kin(state, arm)
        r, GA, GB = pose_gap_in_b(kin.tool, state.extras[self.frames["plate"]] @ self._fixtures())
        jac, jqs = {}, {}
        self._arm_jac(state, arm, kin, GA, want, jq, jac, jqs)
        if self._wanted("plate", want):
            jac[self.frames["plate"]] = GB
        return Residual(r, jac, jqs)

    def initial(self, state, known):
        if "plate" in known:
            return {}
        return {"plate": pose_mean(self._fk(state, self.arms[0]) @ se3.inverse(self._fixtures()))}
