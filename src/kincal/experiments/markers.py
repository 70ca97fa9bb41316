"""External marker positions (partial pose): a tracker measures m points fixed to the tool, no orientation.

Residual (N, 3m), metres, in the tracker frame (where the noise is stated and isotropic):
``T_world_tracker^-1 T_world_tool(q) x_j - y_ij`` with x_j the marker positions in the tool frame
(``p_tool_marker``) and y_ij the measured ``p_tracker_marker``. In the tracker frame a rigid motion of the
whole arm together with the tracker leaves the residual exactly unchanged, so that gauge shows up as an
exact null direction rather than a residual-sized "weak" one.
Optional ``wrench_tool`` loads (N, 6) deflect the arm's compliant joints (``Experiment._kin``, the compliance
block and its Jacobian terms in ``kincal.kinematics.jacobians``).
"""

from __future__ import annotations

import weakref

import numpy as np

from kincal.experiments._kernel import fit_transform, point_jacobian
from kincal.experiments.base import WRENCH, Experiment, Residual
from kincal.noise import POSITION
from kincal.lie import se3
from kincal.schema import LENGTH, TOOL, WORLD, Field, Role, Schema


SCHEMA = Schema(
    "markers", arms=1,
    measured=(Field("p_tracker_marker", "points", LENGTH, columns=("m",), doc="marker positions, tracker frame"),
              WRENCH),
    known=(Field("T_world_tracker", "pose", LENGTH, required=False),
           Field("p_tool_marker", "points", LENGTH, required=False, doc="marker positions, tool frame")),
    roles=(Role("tracker", "T_world_tracker", WORLD, "pose"), Role("markers", "p_tool_marker", TOOL, "points")),
)


_POINTS = "_markers_points"  # where ``MarkersExperiment._points`` keeps its last values on the kinematics


class MarkersExperiment(Experiment):
    SCHEMA = SCHEMA

    def components(self):
        return (POSITION,) * (3 * self.dataset.measured["p_tracker_marker"].shape[1])

    def residual(self, state, want=None, jq=True) -> Residual:
        arm = self.arms[0]
        W = state.extras[self.frames["tracker"]]
        x = np.asarray(state.extras[self.frames["markers"]])
        y = self.dataset.measured["p_tracker_marker"]
        N, m = y.shape[:2]
        kin = self._kin(state, arm)
        F = kin.tool
        pA, r = self._points(kin, W, x, y)
        if self._residual_only(want, jq):
            return Residual(r.reshape(N, 3 * m), {}, {})
        Rt = W[:3, :3].T
        GA = Rt @ point_jacobian(pA)  # (N, m, 3, 6)
        jac, jqs = {}, {}
        self._arm_jac(state, arm, kin, GA.reshape(N, 3 * m, 6), want, jq, jac, jqs)
        if self._wanted("markers", want):
            RtR = Rt @ F[:, :3, :3]
            if m == 1:  # the block is RtR itself
                jac[self.frames["markers"]] = RtR
            else:
                Jx = np.zeros((N, m, 3, m, 3))
                for j in range(m):  # loop over markers, not samples
                    Jx[:, j, :, j, :] = RtR
                jac[self.frames["markers"]] = Jx.reshape(N, 3 * m, 3 * m)
        if self._wanted("tracker", want):
            jac[self.frames["tracker"]] = -GA.reshape(N, 3 * m, 6)
        return Residual(r.reshape(N, 3 * m), jac, jqs)

    def _points(self, kin, W, x, y) -> tuple[np.ndarray, np.ndarray]:
        """The markers in the world (N, m, 3) and the residual (N, m, 3) at ``kin``; those of the last call on the
        same kinematics (remembered ones, ``base.remembered_kinematics``: an accepted trial, then its Jacobian)
        when this experiment's tracker and markers are the same bit for bit."""
        key = (W.tobytes(), x.shape, x.tobytes())
        last = kin.__dict__.get(_POINTS)
        if last is not None and last[0]() is self and last[1] == key:
            return last[2], last[3]
        pA = se3.transform_points(kin.tool[:, None], x)
        r = se3.transform_points(se3.remembered(se3.inverse, W), pA) - y
        kin.__dict__[_POINTS] = (weakref.ref(self), key, pA, r)
        return pA, r

    def initial(self, state, known):
        F = self._fk(state, self.arms[0])
        y = self.dataset.measured["p_tracker_marker"]
        out = {}
        x = np.asarray(known["markers"]) if "markers" in known else np.zeros(y.shape[1:])
        W = known.get("tracker")
        if W is None:
            W = fit_transform(y.reshape(-1, 3), se3.transform_points(F[:, None], x).reshape(-1, 3))
            out["tracker"] = W
        if "markers" not in known:
            # ``transform_points(inverse(F)[:, None], W y)``: the same products, without making the inverses
            Rt = F[:, :3, :3].swapaxes(-1, -2)
            t = -np.einsum("...ij,...j->...i", Rt, F[:, :3, 3])
            local = (np.ascontiguousarray(Rt)[:, None] @ se3.transform_points(W, y)[..., None])[..., 0] + t[:, None]
            out["markers"] = np.add.reduce(local, axis=0) / len(local)  # ``np.mean``'s sum and division
        return out
