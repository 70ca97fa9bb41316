"""Joint compliance under a known load at the tool (first-order elastostatics, seed 001 eq. 2).

Sign convention: ``wrench_tool = (f, m)`` (N, N m) is the load applied TO the tool BY the environment (a
payload hanging from the tool: ``f = m g``, pointing down), in the tool frame, acting at the tool origin.
Its torque on joint i is ``tau = J_b(theta0)^T wrench`` (``J_b`` the body Jacobian, columns (v, w), at the
unloaded configuration ``theta0 = q + o``), and each joint yields like a linear spring in the direction of
that torque::

    theta = q + o + c * tau        (c: joint compliance, rad/(N m) revolute, m/N prismatic; c(q) below)

so a downward force on a horizontal arm makes the tool sag. First order, as in the paper: ``tau`` is
evaluated at the unloaded configuration (the change of the lever arms by the deflection itself, of order
``c |tau|`` relative, is neglected), links are rigid and only the actuated joints are compliant.

Angle-dependent compliance (``ArmModel.compliance_nodes``; seed 001 Sec. V, the KR-270's joint 2 with its
gravity compensator): joint j's compliance is given at node angles ``x_1 < .. < x_m`` of its *reading* q_j
(where the paper's chi_21..chi_25 were identified) and interpolated linearly between them, held constant
beyond the end nodes. The paper identifies one value per measured q2 and does not say what lies between; a
linear interpolation keeps the virtual spring continuous, and at the nodes (where data are taken) it is the
paper's model exactly. The reading, not ``q + o``, so the nodes stay where the table puts them while offsets
are calibrated and the compliance has no offset derivative. Every compliance is linear in the *coefficients*
``k`` (one per constant joint, one per node): ``c(q) = W(q) k`` with ``W`` (N, n, p) the interpolation weights
(``compliance_basis``).

In world coordinates ``tau_i = xi_s_i . F_s`` with ``xi_s_i = Ad(P_{i-1}) xi_i`` the current joint axis and
``F_s = Ad(T_world_tool^-1)^T wrench`` the load as a spatial wrench (the same number in any frame).

The arm's own weight (``ArmModel`` mass model and gravity, ``kincal.kinematics.gravity``) adds the weight beyond
each joint to the load it transmits: ``tau_i = xi_s_i . (W_i + F_s)``, same sign and first-order model.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from kincal._validate import as_array
from kincal.kinematics.couplings import coupling_map
from kincal.kinematics.fk import Kinematics, chain, expanded_chain, forward_kinematics, joint_array
from kincal.kinematics.gravity import GravityLoad, _Inserter, gravity_load, mass_beyond, weight_wrenches
from kincal.kinematics.lateral import expand_coupling, expand_load, expand_screws, expand_values, real_columns
from kincal.kinematics.model import ArmModel
from kincal.lie import se3


@dataclass(frozen=True)
class LoadedKinematics(Kinematics):
    """Kinematics at the deflected joint values, with the unloaded pass that gave the load torques.

    ``unloaded``: the chain at ``theta0``; ``coupling``: as ``deflection``'s; ``wrench_space`` (..., 6): ``F_s``;
    ``axes`` (..., n, 6): ``xi_s_i`` at ``theta0``; ``tau`` (..., n): load torques (N m; N for prismatic joints). With weights
    (``kincal.kinematics.gravity``): ``gravity`` (3,), the mass beyond each joint ``masses_beyond`` (n + 1,), its
    first moment ``moments_beyond`` (..., n + 1, 3) and ``wrench_beyond`` (..., n + 1, 6), weights plus ``F_s``;
    on a tree, ``branches``: the other arms hung on the chain (``kincal.kinematics.branches.Branch``), kept so
    the Jacobians reuse them instead of weighing the branches again.
    """

    unloaded: Kinematics | None = None
    coupling: np.ndarray | None = None  # (n, n) the chain's couplings (``deflection``); None: none
    wrench_space: np.ndarray | None = None
    axes: np.ndarray | None = None
    tau: np.ndarray | None = None
    gravity: np.ndarray | None = None
    masses_beyond: np.ndarray | None = None
    moments_beyond: np.ndarray | None = None
    wrench_beyond: np.ndarray | None = None
    branches: tuple = ()

    @cached_property
    def inserter(self) -> _Inserter:
        """The weights' torque derivatives (``gravity._Inserter``), built once per chain for every part."""
        return _Inserter(self)


def loaded_chain(screws, theta0, base, home, tool, compliance, wrench_tool,
                 weights: GravityLoad | None = None, hung=(), lateral=None, coupling=None) -> LoadedKinematics:
    """Unvalidated kernel on raw arrays: ``theta0`` (..., n) unloaded joint values, ``wrench_tool`` (..., 6) or
    None (no tool load), ``compliance`` (n,) or per sample (..., n), ``weights`` the arm's mass model or None;
    ``hung``: weights beyond the chain (``gravity.mass_beyond``; other branches of a tree); ``lateral``: None or
    (lateral axes (n, 2, 6), lateral compliances (n, 2)): then the result is the *expanded* chain of 3n joints
    (``kincal.kinematics.lateral``); ``coupling``: the chain's coupling map (n, n) or None (``deflection``)."""
    if lateral is None:
        kin0 = chain(screws, theta0, base, home, tool, frames=False)
    else:  # the virtual joints are at zero before the load
        kin0 = expanded_chain(screws, theta0, base, home, tool, frames=False)
        screws = expand_screws(screws, lateral[0])
        compliance, weights = expand_values(compliance, lateral[1]), expand_load(weights)
        hung = [(3 * m, mass, moment) for m, mass, moment in hung]
        coupling = expand_coupling(coupling)
    if wrench_tool is None:
        F_s = np.zeros(kin0.theta.shape[:-1] + (6,))
    else:
        F_s = np.einsum("...ji,...j->...i", se3.adjoint_inv(kin0.tool), wrench_tool)  # Ad(T^-1)^T F_b
    axes = np.einsum("...kij,kj->...ki", se3.adjoint(kin0.prefixes[..., :-1, :, :]), screws)
    extra = ()
    if weights is None:
        tau = np.einsum("...ki,...i->...k", axes, F_s)
    else:
        M, S = mass_beyond(weights, kin0.prefixes, kin0.tool, hung)
        W = weight_wrenches(M, S, weights.g) + F_s[..., None, :]
        tau = np.einsum("...ki,...ki->...k", axes, W[..., :-1, :])
        extra = (weights.g, M, S, W)
    kin = chain(screws, kin0.theta + deflection(compliance, tau, coupling), base, home, tool, frames=False)
    return LoadedKinematics(kin.theta, kin.screws, kin.prefixes, kin.flange, kin.tool, kin0, coupling, F_s, axes, tau,
                            *extra)


def deflection(c, tau, coupling):
    """Joint deflections (..., n) of compliances ``c`` under joint torques ``tau`` (..., n): ``c * tau``, or on a
    chain with couplings ``coupling`` = A (n, n) (``kinematics.couplings``: readings = A free readings, zero
    columns at coupled joints) ``A (c * A^T tau) + c_k tau_k`` at each coupled joint k. A coupled joint has no
    drive of its own: by virtual work the drives of the joints it follows hold its torque too (Agile Justin's
    passive t4 = -t2 - t3: the t2 and t3 drives hold ``tau_2 - tau_4`` and ``tau_3 - tau_4``), their deflections
    move it through the coupling, and its own compliance is the mechanism's."""
    if coupling is None:
        return c * tau
    own = ~coupling.any(axis=0)
    return (c * (tau @ coupling)) @ coupling.T + own * c * tau


def deflection_map(jq, c, coupling):
    """``jq @ d deflection / d tau``: ``jq * c`` per column, or through the coupling (``deflection``); ``jq``
    (N, k, n), ``c`` (n,) or (N, n)."""
    c = np.asarray(c)[..., None, :]
    if coupling is None:
        return jq * c
    own = ~coupling.any(axis=0)
    return ((jq @ coupling) * c) @ coupling.T + jq * (own * c)


def compliance_columns(jq, tau, coupling):
    """``jq @ d deflection / d c`` (N, k, n): ``jq * tau`` per column, or through the coupling (``deflection``)."""
    if coupling is None:
        return jq * tau[:, None, :]
    own = ~coupling.any(axis=0)
    return (jq @ coupling) * (tau @ coupling)[:, None, :] + jq * (own * tau)[:, None, :]


def chain_coupling(arms) -> np.ndarray | None:
    """The coupling map of a chain of segments (``ArmModel`` or ``ArmValues``, root first): block diagonal of
    theirs, None when no segment has couplings."""
    maps = [_coupling(a) for a in arms]
    if all(m is None for m in maps):
        return None
    blocks = [np.eye(a.dof) if m is None else m for a, m in zip(arms, maps)]
    n = sum(len(b) for b in blocks)
    out, at = np.zeros((n, n)), 0
    for b in blocks:
        out[at: at + len(b), at: at + len(b)] = b
        at += len(b)
    return out


def _coupling(a) -> np.ndarray | None:
    if isinstance(a, ArmModel):
        return coupling_map(a.couplings, a.joint_names)[0] if a.couplings else None
    return a.coupling


def compliance_coefficients(model: ArmModel) -> np.ndarray:
    """The compliance coefficients k (p,): per joint its constant compliance, or its node values."""
    nodes = model.compliance_nodes
    return np.concatenate([nodes[j][:, 1] if j in nodes else model.compliance[i: i + 1]
                           for i, j in enumerate(model.joint_names)])


def compliance_basis(nodes, q) -> tuple[np.ndarray, np.ndarray]:
    """``W`` (N, n, p) with ``c(q) = W k`` and its derivative ``S = dW/dq_j`` (N, n, p) for readings q (N, n);
    ``nodes``: per joint None (constant compliance, one coefficient) or its node angles (m,) (m coefficients)."""
    q = np.asarray(q, dtype=float)
    N, n = q.shape
    sizes = [1 if x is None else len(x) for x in nodes]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    W = np.zeros((N, n, starts[-1]))
    S = np.zeros_like(W)
    rows = np.arange(N)
    for j, x in enumerate(nodes):  # loop over joints, vectorized over samples
        if x is None:
            W[:, j, starts[j]] = 1.0
            continue
        qj = np.clip(q[:, j], x[0], x[-1])
        k = np.clip(np.searchsorted(x, qj, side="right") - 1, 0, len(x) - 2)
        h = x[k + 1] - x[k]
        t = (qj - x[k]) / h
        inside = ((q[:, j] > x[0]) & (q[:, j] < x[-1])).astype(float)
        W[rows, j, starts[j] + k] = 1.0 - t
        W[rows, j, starts[j] + k + 1] = t
        S[rows, j, starts[j] + k] = -inside / h
        S[rows, j, starts[j] + k + 1] = inside / h
    return W, S


def node_angles(model: ArmModel) -> tuple:
    """Per joint None or its compliance node angles (m,): the ``nodes`` of ``compliance_basis``."""
    return tuple(model.compliance_nodes[j][:, 0] if j in model.compliance_nodes else None for j in model.joint_names)


def joint_compliance(model: ArmModel, q: np.ndarray) -> np.ndarray:
    """Each joint's compliance at readings q (..., n): (n,) without nodes, else (..., n)."""
    if not model.compliance_nodes:
        return model.compliance
    q = np.asarray(q, dtype=float)
    W, _ = compliance_basis(node_angles(model), q.reshape(-1, model.dof))
    return (W @ compliance_coefficients(model)).reshape(q.shape)


def _wrench(wrench_tool, shape) -> np.ndarray:
    w = as_array(wrench_tool, "wrench_tool", (6,))
    return np.broadcast_to(w, shape + (6,))


def loaded_kinematics(model: ArmModel, q, wrench_tool=None) -> LoadedKinematics:
    """Forward kinematics of ``model`` at readings q (..., n) under ``wrench_tool`` (6,) or (..., 6) (None: no
    tool load) and the model's own weight when it has a mass model and gravity."""
    q = joint_array(model, q)
    w = None if wrench_tool is None else _wrench(wrench_tool, q.shape[:-1])
    c = joint_compliance(model, q)
    return loaded_chain(model.screws, q + model.offsets, model.base, model.home, model.tool, c, w, gravity_load(model),
                        lateral=model_lateral(model), coupling=chain_coupling([model]))


def model_lateral(model) -> tuple[np.ndarray, np.ndarray] | None:
    """(lateral axes, lateral compliances) of an ``ArmModel`` or ``ArmValues``, None without lateral compliance:
    the ``lateral`` of ``loaded_chain``."""
    return None if model.lateral is None else (model.lateral_axes, model.lateral)


def loaded_forward_kinematics(model: ArmModel, q, wrench_tool=None) -> np.ndarray:
    """``T_world_tool`` of the deflected arm: (..., n) readings, (6,) or (..., 6) loads (None: none) -> (..., 4, 4);
    deflected by the arm's own weight too when the model has one (the rigid pose when nothing loads it)."""
    if wrench_tool is None and not model.has_gravity_load:
        return forward_kinematics(model, q)
    return loaded_kinematics(model, q, wrench_tool).tool


def load_torques(model: ArmModel, q, wrench_tool=None) -> np.ndarray:
    """Joint load torques ``J_b(q + o)^T wrench_tool`` (..., n) at the unloaded configuration, plus the arm's
    own weight when the model has a mass model and gravity (the joints' own, without lateral moments)."""
    tau = loaded_kinematics(model, q, wrench_tool).tau
    return tau if model.lateral is None else real_columns(tau)
