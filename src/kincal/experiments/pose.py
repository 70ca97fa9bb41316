"""External full-pose measurements: a tracker measures ``T_tracker_tool``.

Residual (N, 6): ``[p_pred - p_meas, log(R_pred R_meas^T)]`` in the tracker frame (where the noise is
stated), with ``T_pred = T_world_tracker^-1 T_world_tool(q)`` and ``T_meas = T_tracker_tool``. A rigid motion
of the whole arm together with the tracker is then an exact null direction. Optional ``wrench_tool`` loads
deflect compliant joints (``Experiment._kin``).

Optional ``pose_cov`` (N, 6, 6): the covariance of the measured pose's error ``e = (p_meas - p, log(R_meas R^T))``
(true pose p, R), both parts in the tracker frame: a position error and a left rotation increment, as the
residual's. At the true parameters ``r = -e`` (the rotation part exactly: ``log(R R^T exp(-e_w)^) = -e_w``), so
``pose_cov`` is the residual's covariance and whitening uses it in place of the stated position and orientation
noise (docs/calibration.md "Pose data with a full covariance").

``weighted`` weights a fit otherwise for comparisons (the covariance's diagonal, or 1 m = 1 rad); it then keeps
the pose error's covariance as ``noise_cov``, which the fit does not weight by but the reported covariance uses
(the sandwich, ``kincal.estimation.sandwich``).
"""

from __future__ import annotations

import numpy as np

from kincal.data import Dataset
from kincal.errors import DataFormatError, ModelError, ShapeError
from kincal.experiments._kernel import pose_gap, pose_mean
from kincal.experiments.base import WRENCH, Experiment, Residual
from kincal.experiments.handeye import hand_eye
from kincal.noise import ORIENTATION, POSITION, effective
from kincal.lie import se3, so3
from kincal.schema import LENGTH, NONE, WORLD, Field, Role, Schema, covariance_problem


SCHEMA = Schema(
    "pose", arms=1,
    measured=(Field("T_tracker_tool", "pose", LENGTH, columns=("tool",), doc="tool pose in the tracker frame"), WRENCH,
              Field("pose_cov", "covariance", NONE, required=False, columns=("cov",),
                    doc="covariance of the pose's error (position, left rotation), tracker frame"),
              Field("noise_cov", "covariance", NONE, required=False, columns=("noise_cov",),
                    doc="the pose error's covariance where the fit weights by another (pose_cov, or the stated "
                        "noise): standard deviations follow it")),
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
        alone = self._residual_only(want, jq)
        r, GA, _ = pose_gap(Wi @ kin.tool, self.dataset.measured["T_tracker_tool"], of_b=False, jacobians=not alone)
        if alone:
            return Residual(r, {}, {})
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

    def noise_covariance(self):
        """``noise_cov``: the pose error's covariance where the fit weights by another (``weighted``), else None."""
        return self.dataset.measured.get("noise_cov")

    def check(self):
        for key in ("pose_cov", "noise_cov"):
            cov = self.dataset.measured.get(key)
            bad = None if cov is None else covariance_problem(cov)
            if bad:
                raise DataFormatError(f"data set '{self.name}': sample {bad[0]}{file_line(self.dataset, bad[0])}, "
                                      f"field {key}: expected a symmetric positive definite 6x6 covariance, found "
                                      f"{bad[1]}")

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


def file_line(dataset: Dataset, i: int) -> str:
    """`` (line L of FILE)`` for sample ``i`` of a data set read from a file, else empty."""
    lines = dataset.meta.get("lines")
    return f" (line {lines[i]} of {dataset.meta.get('file', 'the file')})" if lines is not None else ""


WEIGHTS = ("full", "diagonal", "equal")


def weighted(dataset: Dataset, how: str, sigma: float | None = None, keep_noise: bool = True) -> Dataset:
    """A ``pose`` data set with ``pose_cov`` (``pose_from_markers.markers_to_pose``) weighted another way.

    ``"full"``: whitened by the pose error's covariance; ``"diagonal"``: ``pose_cov`` without its correlations
    (each component by its own variance); ``"equal"``: the partial-pose paper's unweighted approach 1,
    1 m = 1 rad: no ``pose_cov``, stated noise ``position = sigma`` m and ``orientation = sigma`` rad
    (default: the data set's stated position noise, else ``kincal.noise.DEFAULT``'s). The pose error's
    covariance (``noise_cov`` if the data set has one, else ``pose_cov``) stays as ``noise_cov`` when the
    weights differ from it, so the reported standard deviations remain the estimator's (the sandwich);
    ``keep_noise=False`` drops it: the fit then reports the standard deviations its weights imply, as the paper's
    approach 1 does (for comparisons; they are not the estimates' scatter).
    """
    where = f"data set '{dataset.name}'"
    if how not in WEIGHTS:
        raise ModelError(f"{where}: weights: expected one of {', '.join(WEIGHTS)}, found {how!r}")
    cov = dataset.measured.get("pose_cov")
    if dataset.kind != "pose" or cov is None:
        raise ShapeError(f"{where}: expected a pose data set with pose_cov to reweight, found kind "
                         f"'{dataset.kind}'{'' if cov is None else ' with pose_cov'}")
    measured, meta = dict(dataset.measured), dict(dataset.meta)
    noise_cov = measured.pop("noise_cov", cov)
    if how == "full":
        measured["pose_cov"] = noise_cov
    elif keep_noise:
        measured["noise_cov"] = noise_cov
    if how == "diagonal":
        measured["pose_cov"] = noise_cov * np.eye(6)
    elif how == "equal":
        del measured["pose_cov"]
        noise = dict(meta.get("noise") or {})
        s = effective(None, noise).position if sigma is None else sigma
        meta["noise"] = {**noise, "position_m": float(s), "orientation_rad": float(s)}
    return Dataset(dataset.kind, dataset.robot, dataset.arms, dict(dataset.q), measured, dict(dataset.known),
                   dataset.name, meta, dict(dataset.frames))
