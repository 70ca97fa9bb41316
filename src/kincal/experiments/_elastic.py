"""Jacobian terms of joint compliance: the compliance block and the load torques' dependence on the geometry.

With ``theta = theta0 + c * tau(p, theta0)`` (``kincal.kinematics.elastic``) and ``Jq = G dT/dtheta`` at the
deflected ``theta``:

* compliance: ``Jq[..., i] tau_i``;
* every other part p (and the joint readings): ``Jq (dtheta0/dp + c * dtau/dp)``; the first term is what
  ``arm_jacobians`` computes at the deflected theta, the second is added here.

``dtau/dp``: a parameter acts as a world twist ``zeta`` inserted at some position k of the chain (after the
prefix ``P_k``). It moves the axes after it (``xi_s_i -> xi_s_i + ad(zeta) xi_s_i``, i > k) and the tool
(``F_s -> F_s - ad(zeta)^T F_s``), so ``dtau_i = [i <= k] h_i . zeta`` with ``h_i = F_s^T ad(xi_s_i)``: only
the axes the parameter does not carry see the load turn. Offset j inserts ``xi_s_j`` at k = j (0-based:
rows i < j), a twist tangent ``+Ad(P_j) G_j`` before joint j and ``-Ad(P_{j+1}) G_j`` after it, home
``Ad(P_n)`` and tool ``Ad(T_world_flange)`` after every joint; the base moves everything (no change).
"""

from __future__ import annotations

import numpy as np

from kincal.kinematics import LoadedKinematics
from kincal.lie import se3

CORRECTED = ("offsets", "twists", "home", "tool")


def torque_derivatives(a, kin: LoadedKinematics, parts) -> dict[str, np.ndarray]:
    """``dtau/dp`` (N, n, d) for the parts in ``parts`` among offsets, twists, home, tool (unloaded chain)."""
    k0 = kin.unloaded
    n = a.dof
    H = np.einsum("Ni,Nkij->Nkj", kin.wrench_space, se3.ad(kin.axes))  # (N, n, 6): h_i
    out = {}
    rows = np.arange(n)
    if "offsets" in parts:
        out["offsets"] = np.einsum("Nik,Njk->Nij", H, kin.axes) * (rows[:, None] < rows[None, :])
    Ad = se3.adjoint(k0.prefixes) if ("twists" in parts or "home" in parts) else None
    if "twists" in parts:
        cols = []
        for j, Gj in enumerate(a.generators):  # loop over joints, batched over samples
            before = H * (rows < j)[None, :, None]
            upto = H * (rows <= j)[None, :, None]
            cols.append(before @ (Ad[:, j] @ Gj) - upto @ (Ad[:, j + 1] @ Gj))
        out["twists"] = np.concatenate(cols, axis=-1)
    if "home" in parts:
        out["home"] = H @ Ad[:, n]
    if "tool" in parts:
        out["tool"] = H @ se3.adjoint(k0.flange)
    return out


def add_compliance(a, kin: LoadedKinematics, jq: np.ndarray, out: dict, parts) -> np.ndarray:
    """Add the compliance block and the ``c * dtau/dp`` terms to ``out`` (in place); returns the corrected
    derivative w.r.t. the joint readings. ``jq`` (N, k, n): ``G dT/dtheta`` at the deflected theta."""
    c = a.joint_compliance
    if "compliance" in parts:
        out["compliance"] = jq * kin.tau[:, None, :]
    want = [p for p in CORRECTED if p in parts] + ([] if "offsets" in parts else ["offsets"])
    if not np.any(c):
        return jq
    cjq = jq * c
    D = torque_derivatives(a, kin, want)
    for p in CORRECTED:
        if p in parts:
            out[p] = out[p] + cjq @ D[p]
    return jq + cjq @ D["offsets"]
