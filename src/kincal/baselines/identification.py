"""The thesis' identification Jacobian of the pose error twist (thesis eq. 2.40-2.53, He et al. 2010).

Used by the thesis baselines (``thesis_dual``) only: kincal's solver differentiates w.r.t. tangent coordinates
of the joint screws with ``kincal.kinematics.tool_jacobians``.

Error twist (space, left): ``y = log(T(p + dp) T(p)^-1)^vee = J dp + O(dp^2)`` with T = T_world_tool.
Parametrization (additive in every coordinate):

- ``base``: twist coordinates of ``T_world_base = exp(xi_base)``.
- ``twists``: the 6 coordinates of every joint twist xi_i (joint-major, ``v_x .. w_z``).
- ``offsets``: joint offsets, ``theta_i = q_i + o_i``.
- ``home``: twist coordinates of ``T_base_flange(0) = exp(xi_st)`` (the thesis' xi_st).
- ``tool``: twist coordinates of ``T_flange_tool = exp(xi_tool)``.

Columns (the adjoint/left-Jacobian form, identical to the thesis' closed form):

- base:   ``J_l(xi_base)``
- xi_i:   ``Ad(P_{i-1}) theta_i J_l(theta_i xi_i)``   (thesis A_i: q_i I + ... Omega_i^4 terms)
- o_i:    ``Ad(P_{i-1}) xi_i``
- xi_st:  ``Ad(P_n) J_l(xi_st)``
- tool:   ``Ad(P_n home) J_l(xi_tool)``

where ``P_i = base exp(xi_1 theta_1) ... exp(xi_i theta_i)``. With ``frame="body"`` every block is
premultiplied by ``Ad(T^-1)``, i.e. the error is ``log(T(p)^-1 T(p + dp))``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kincal.kinematics import TWIST_COORDS, ArmModel, Kinematics, kinematics
from kincal.lie import se3

BLOCKS = ("base", "twists", "offsets", "home", "tool")


@dataclass(frozen=True)
class IdentificationJacobian:
    """Blocks of the identification Jacobian, each (..., 6, k)."""

    base: np.ndarray
    twists: np.ndarray
    offsets: np.ndarray
    home: np.ndarray
    tool: np.ndarray
    joint_names: tuple[str, ...]

    def block_names(self, block: str, prefix: str = "") -> list[str]:
        p = f"{prefix}." if prefix else ""
        if block == "twists":
            return [f"{p}{j}.xi.{c}" for j in self.joint_names for c in TWIST_COORDS]
        if block == "offsets":
            return [f"{p}{j}.offset" for j in self.joint_names]
        return [f"{p}{block}.{c}" for c in TWIST_COORDS]

    def stacked(self, blocks: tuple[str, ...] = BLOCKS, prefix: str = "") -> tuple[np.ndarray, list[str]]:
        """Concatenate the named blocks: ((..., 6, p), p names)."""
        mats = [getattr(self, b) for b in blocks]
        names = [n for b in blocks for n in self.block_names(b, prefix)]
        return np.concatenate(mats, axis=-1), names

    def thesis(self) -> np.ndarray:
        """The thesis' ordering (eq. 2.50-2.51): [xi_1, o_1, ..., xi_n, o_n, xi_st]; (..., 6, 7n + 6)."""
        n = len(self.joint_names)
        tw = self.twists.reshape(self.twists.shape[:-1] + (n, 6))
        per_joint = np.concatenate([tw, self.offsets[..., None]], axis=-1)
        return np.concatenate([per_joint.reshape(per_joint.shape[:-2] + (7 * n,)), self.home], axis=-1)


def identification_jacobian(
    model: ArmModel, q, *, frame: str = "space", kin: Kinematics | None = None
) -> IdentificationJacobian:
    """Identification Jacobian for joint readings q (..., n); see the module docstring."""
    if frame not in ("space", "body"):
        raise ValueError(f"frame must be 'space' or 'body', got {frame!r}")
    kin = kinematics(model, q) if kin is None else kin
    n = model.dof
    batch = kin.theta.shape[:-1]
    Ad_prefix = se3.adjoint(kin.prefixes)  # (..., n+1, 6, 6)

    th = kin.theta[..., None, None]
    if se3.exact_joint_screws(model.screws):
        X = se3.ad(model.screws)
        f1, f2 = (f[..., None, None] for f in se3.joint_screw_jacobian_coeffs(model.screws, kin.theta))
        A = th * np.eye(6) + f1 * X + f2 * (X @ X)
    else:
        A = th * se3.left_jacobian(model.screws * kin.theta[..., None])  # (..., n, 6, 6)
    twists = Ad_prefix[..., :-1, :, :] @ A  # (..., n, 6, 6)
    twists = np.moveaxis(twists, -3, -2).reshape(batch + (6, 6 * n))
    offsets = np.swapaxes(np.einsum("...kij,kj->...ki", Ad_prefix[..., :-1, :, :], model.screws), -1, -2)

    base = np.broadcast_to(se3.left_jacobian(se3.log(model.base)), batch + (6, 6))
    home = Ad_prefix[..., -1, :, :] @ se3.left_jacobian(se3.log(model.home))
    tool = se3.adjoint(kin.flange) @ se3.left_jacobian(se3.log(model.tool))

    blocks = [base, twists, offsets, home, tool]
    if frame == "body":
        Ad_inv = se3.adjoint_inv(kin.tool)
        blocks = [Ad_inv @ b for b in blocks]
    return IdentificationJacobian(*[np.ascontiguousarray(b) for b in blocks], joint_names=model.joint_names)
