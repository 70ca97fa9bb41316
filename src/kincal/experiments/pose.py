"""External full-pose measurements: a tracker measures ``T_tracker_tool``.

Residual (N, 6): ``[p_pred - p_meas, log(R_pred R_meas^T)]`` in world coordinates, with
``T_pred = T_world_tool(q)`` and ``T_meas = T_world_tracker @ T_tracker_tool``.
"""

from __future__ import annotations

from kincal.experiments._kernel import pose_gap, pose_mean
from kincal.experiments.base import Experiment, Residual, chain_rule
from kincal.lie import se3


class PoseExperiment(Experiment):
    KIND = "pose"
    ROLES = {"tracker": "T_world_tracker"}
    COMPONENTS = ("position",) * 3 + ("orientation",) * 3

    def residual(self, state, want=None) -> Residual:
        arm = self.arms[0]
        W = state.extras[self.frames["tracker"]]
        kin, J, jq = self._arm(state, arm, want)
        r, GA, GB = pose_gap(kin.tool, W @ self.dataset.measured["T_tracker_tool"])
        jac = chain_rule(GA, arm, J)
        if self._wanted("tracker", want):
            jac[self.frames["tracker"]] = GB
        return Residual(r, jac, {arm: GA @ jq})

    def initial(self, state, known):
        if "tracker" in known:
            return {}
        F = self._fk(state, self.arms[0])
        return {"tracker": pose_mean(F @ se3.inverse(self.dataset.measured["T_tracker_tool"]))}
