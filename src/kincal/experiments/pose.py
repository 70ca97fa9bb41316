"""External full-pose measurements: a tracker measures ``T_tracker_tool``.

Residual (N, 6): ``[p_pred - p_meas, log(R_pred R_meas^T)]`` in the tracker frame (where the noise is
stated), with ``T_pred = T_world_tracker^-1 T_world_tool(q)`` and ``T_meas = T_tracker_tool``. A rigid motion
of the whole arm together with the tracker is then an exact null direction. Optional ``wrench_tool`` loads
deflect compliant joints (``Experiment._kin``).
"""

from __future__ import annotations

import numpy as np

from kincal.errors import DataFormatError
from kincal.experiments._kernel import pose_gap, pose_mean
from kincal.experiments.base import WRENCH, Experiment, Residual
from kincal.experiments.handeye import hand_eye
from kincal.noise import ORIENTATION, POSITION
from kincal.lie import se3, so3
from kincal.schema import LENGTH, NONE, WORLD, Field, Role, Schema, covariance_problem


SCHEMA = Schema(
    "pose", arms=1,
    measured=(Field("T_tracker_tool", "pose", LENGTH, columns=("tool",), doc="tool pose in the tracker frame"), WRENCH,
              Field("pose_cov", "covariance", NONE, required=False, columns=("cov",),
                    doc="covariance of the pose's error (position, left rotation), tracker frame")),
    known=(Field("T_world_tracker", "pose", LENGTH, required=False),),
    roles=(Role("tracker", "T_world_tracker", WORLD, "pose"),),
)


# Below this rotation of the tool frame's error the solver's local steps find the solution from the nominal tool.
CORRECT_ABOVE_RAD = np.radians(30.0)


class PoseExperiment(Experiment):
    SCHEMA = SCHEMA
    COMPONENTS = (POSITION,) * 3 + (ORIENTATION,) * 3

    def residual(self, state, want=None, jq=True) -> Residual:
        arm = self.arms[0]
        W = state.extras[self.frames["tracker"]]
        kin = self._kin(state, arm)
        Wi = se3.inverse(W)
        r, GA, _ = pose_gap(Wi @ kin.tool, self.dataset.measured["T_tracker_tool"])
        GA = GA @ se3.adjoint(Wi)  # world left increments of the tool -> tracker-frame increments
        jac, jqs = {}, {}
        self._arm_jac(state, arm, kin, GA, want, jq, jac, jqs)
        if self._wanted("tracker", want):
            jac[self.frames["tracker"]] = -GA  # W -> exp(d) W moves W^-1 T by exp(-Ad(W^-1) d)
        return Residual(r, jac, jqs)

    def covariance(self):
        """``pose_cov``: the covariance of the measured pose's error ``(p_meas - p, log(R_meas R^T))``, tracker
        frame; the residual is minus that error at the truth, so it is the residual's covariance too."""
        return self.dataset.measured.get("pose_cov")

    def check(self):
        cov = self.covariance()
        bad = None if cov is None else covariance_problem(cov)
        if bad:
            lines = self.dataset.meta.get("lines")
            at = f" (line {lines[bad[0]]} of {self.dataset.meta.get('file')})" if lines is not None else ""
            raise DataFormatError(f"data set '{self.name}': sample {bad[0]}{at}, field pose_cov: expected a "
                                  f"symmetric positive definite 6x6 covariance, found {bad[1]}")

    def initial(self, state, known):
        if "tracker" in known:
            return {}
        F = self._fk(state, self.arms[0])
        return {"tracker": pose_mean(F @ se3.inverse(self.dataset.measured["T_tracker_tool"]))}

    def start(self, nominal, free_parts, unknown):
        """With an unknown tracker, a tool frame turned far from nominal (more than ``CORRECT_ABOVE_RAD``) would
        end the solve in a local minimum: the hand-eye solution (``experiments.handeye``) gives the tool's
        error X, to start from ``tool @ X``."""
        arm = self.arms[0]
        if self.frames["tracker"] not in unknown or not {f"{arm}.tool", f"{arm}.home"} & set(free_parts):
            return {}
        X = hand_eye(self._fk(nominal, arm), self.dataset.measured["T_tracker_tool"])
        if X is None or np.linalg.norm(so3.log(X[:3, :3])) < CORRECT_ABOVE_RAD:
            return {}
        return {f"{arm}.tool": X}
