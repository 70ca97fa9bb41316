"""A calibrated pinhole camera sees one point fixed to the tool: measured pixel coordinates (u, v).

The camera sits at ``T_world_camera`` (x right, y down, z along the optical axis) with known intrinsics
``[fx, fy, cx, cy]`` (px); the point is ``p_tool_point`` in the tool frame. With ``c = T_world_camera^-1
T_world_tool(q) p_tool_point`` the residual (N, 2), pixels, is ``[fx c_x / c_z + cx, fy c_y / c_z + cy] - (u, v)``.
A rigid motion of the arm together with the camera leaves it unchanged (an exact null direction, as a tracker's).
A projection does not change when every length scales together: the pixels see the robot's size only through
lengths fixed in the calibration (the nominal twists at level ``offsets``, a known length elsewhere).
"""

from __future__ import annotations

import numpy as np

from kincal.errors import DegenerateExperimentError
from kincal.experiments._kernel import point_jacobian
from kincal.experiments.base import Experiment, Residual
from kincal.lie import se3
from kincal.noise import PIXEL
from kincal.schema import LENGTH, TOOL, WORLD, Field, Role, Schema

SCHEMA = Schema(
    "camera", arms=1,
    measured=(Field("pixel", "vector", size=2, columns=("pixel.u", "pixel.v"), doc="image coordinates (px)"),),
    known=(Field("intrinsics", "vector", size=4, doc="[fx, fy, cx, cy] (px)"),
           Field("T_world_camera", "pose", LENGTH, required=False, doc="the camera, world frame"),
           Field("p_tool_point", "vector", LENGTH, required=False, size=3, doc="the observed point, tool frame")),
    roles=(Role("camera", "T_world_camera", WORLD, "pose"), Role("point", "p_tool_point", TOOL, "point")),
)


def project(c: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (..., 2) of camera-frame points c (..., 3) and their derivative d pixel / d c (..., 2, 3)."""
    fx, fy, cx, cy = K
    x, y, z = c[..., 0], c[..., 1], c[..., 2]
    uv = np.stack([fx * x / z + cx, fy * y / z + cy], axis=-1)
    D = np.zeros(c.shape[:-1] + (2, 3))
    D[..., 0, 0] = fx / z
    D[..., 0, 2] = -fx * x / z**2
    D[..., 1, 1] = fy / z
    D[..., 1, 2] = -fy * y / z**2
    return uv, D


def camera_from_views(p_world: np.ndarray, uv: np.ndarray, K: np.ndarray) -> np.ndarray | None:
    """``T_world_camera`` seeing world points (N, 3) at pixels (N, 2): the direct linear transform on
    normalized image coordinates, rotation made orthonormal; None when the points do not determine it."""
    fx, fy, cx, cy = K
    m = np.stack([(uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy], axis=-1)
    P = np.concatenate([p_world, np.ones((len(p_world), 1))], axis=1)  # (N, 4)
    zero = np.zeros_like(P)
    A = np.concatenate([np.concatenate([P, zero, -m[:, :1] * P], axis=1),
                        np.concatenate([zero, P, -m[:, 1:] * P], axis=1)])
    if len(p_world) < 6 or np.linalg.matrix_rank(P) < 4:
        return None
    M = np.linalg.svd(A)[2][-1].reshape(3, 4)
    if np.mean(P @ M[2]) < 0:  # points in front of the camera
        M = -M
    U, S, Vt = np.linalg.svd(M[:, :3])
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return se3.inverse(se3.make(R, M[:, 3] / S.mean()))


def point_from_views(F: np.ndarray, uv: np.ndarray, K: np.ndarray, C: np.ndarray) -> np.ndarray:
    """The tool point (3,) whose rays through the pixels (N, 2) best meet it, with tool poses F (N, 4, 4) and the
    camera at C: each view says ``(e_k - m_k e_3) . R_C^T (F x - t_C) = 0`` (k = x, y), linear in x."""
    fx, fy, cx, cy = K
    m = np.stack([(uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy], axis=-1)
    Rt = C[:3, :3].T
    A = (Rt[None, :2, :] - m[:, :, None] * Rt[None, 2:, :])  # (N, 2, 3)
    lhs = (A @ F[:, :3, :3]).reshape(-1, 3)
    rhs = -(A @ (F[:, :3, 3] - C[:3, 3])[:, :, None]).reshape(-1)
    return np.linalg.lstsq(lhs, rhs, rcond=None)[0]


_ROUNDS = 10  # camera and point placed in turn when both are unknown


class CameraExperiment(Experiment):
    SCHEMA = SCHEMA
    COMPONENTS = (PIXEL, PIXEL)

    def check(self):
        K = self.dataset.known["intrinsics"]
        if not (K[0] > 0 and K[1] > 0):
            raise DegenerateExperimentError(f"data set '{self.name}': field known['intrinsics'] is {K.tolist()}, "
                                            "expected [fx, fy, cx, cy] with focal lengths fx, fy > 0 (px)")

    def residual(self, state, want=None, jq=True) -> Residual:
        arm = self.arms[0]
        C = state.extras[self.frames["camera"]]
        x = np.asarray(state.extras[self.frames["point"]])
        kin = self._kin(state, arm)
        F = kin.tool
        p = se3.transform_points(F, x)  # (N, 3) world
        Rt = C[:3, :3].T
        uv, D = project(se3.transform_points(se3.inverse(C), p), self.dataset.known["intrinsics"])
        DR = D @ Rt  # d pixel / d world point
        G = DR @ point_jacobian(p)  # (N, 2, 6): d pixel / d left increment of the tool (and minus the camera's)
        jac, jqs = {}, {}
        self._arm_jac(state, arm, kin, G, want, jq, jac, jqs)
        if self._wanted("point", want):
            jac[self.frames["point"]] = DR @ F[:, :3, :3]
        if self._wanted("camera", want):
            jac[self.frames["camera"]] = -G
        return Residual(uv - self.dataset.measured["pixel"], jac, jqs)

    def initial(self, state, known):
        """Camera by the direct linear transform of the tool point's world positions; an unknown point starts at
        the tool origin and is refined with the camera in turn (``point_from_views``, a few rounds)."""
        F = self._fk(state, self.arms[0])
        uv, K = self.dataset.measured["pixel"], self.dataset.known["intrinsics"]
        x = np.asarray(known["point"]) if "point" in known else np.zeros(3)
        C = known.get("camera")
        for _ in range(1 if "point" in known or C is not None else _ROUNDS):
            if "camera" not in known:
                C = camera_from_views(se3.transform_points(F, x), uv, K)
                if C is None:
                    raise DegenerateExperimentError(
                        f"data set '{self.name}': cannot place the camera: expected at least 6 views of the point "
                        f"in general position, found {self.size}")
            if "point" not in known:
                x = point_from_views(F, uv, K, C)
        out = {} if "camera" in known else {"camera": C}
        return out if "point" in known else {**out, "point": x}
