"""Parameter values: an arm's raw values with the tangent bases of its twists, planes, and the ``State``.

Values live in a ``State``: arms by name, and the frames of experiments (fixture pose, tracker, markers, a
plane, ...) by name with the parameter kind of each (``kincal.params.kinds``). Twists may sit slightly off the
joint-screw manifold during an inner solve; ``recentre`` (``kincal.params.ops``) conforms them.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field, fields, replace
from functools import cached_property
from typing import Mapping

import numpy as np

from kincal._memo import remember
from kincal.errors import ModelError
from kincal.kinematics import ArmModel, Robot, conform_twists, tangent_frames
from kincal.kinematics.couplings import coupling_map
from kincal.kinematics.elastic import compliance_basis, compliance_coefficients, node_angles
from kincal.kinematics.gravity import GravityLoad, gravity_load
from kincal.kinematics.model import same_array_bits
from kincal.kinematics.twists import Stacked
from kincal.lie import se3, so3


@dataclass(frozen=True)
class ArmValues:
    """Raw values of one arm's parameters plus the tangent bases of its twists at the linearization point."""

    screws: np.ndarray  # (n, 6)
    offsets: np.ndarray  # (n,)
    base: np.ndarray  # (4, 4) T_world_base
    home: np.ndarray  # (4, 4) T_base_flange(0)
    tool: np.ndarray  # (4, 4) T_flange_tool
    bases: tuple  # per joint (6, k_i): d screw / d tangent coordinates at the current values
    joint_names: tuple
    joint_types: tuple
    generators: tuple = ()  # per joint (6, k_i): Ad(exp(G d)) retraction generators at the linearization point
    compliance: np.ndarray | None = None  # (p,) coefficients, rad/(N m) or m/N; None: zeros
    compliance_nodes: tuple = ()  # per joint None or its compliance node angles (m,); (): no joint has nodes
    coupling: np.ndarray | None = None  # (n, n) d readings / d free readings (kinematics.couplings); None: identity
    weights: GravityLoad | None = None  # the arm's own weight (fixed, not a parameter); None: no gravity load
    lateral: np.ndarray | None = None  # (n, 2) lateral compliances (kinematics.lateral); None: the arm has none
    lateral_axes: np.ndarray | None = None  # (n, 2, 6) lateral axes, moved with their joint's twist

    @property
    def dof(self) -> int:
        return self.screws.shape[0]

    @property
    def joint_compliance(self) -> np.ndarray:
        """(p,) compliance coefficients (zeros when none are set): one per joint, or per node of a joint with
        ``compliance_nodes`` (``kincal.kinematics.elastic``); (n,) joint compliances when no joint has nodes."""
        return np.zeros(self.dof) if self.compliance is None else self.compliance

    def compliance_basis(self, q) -> tuple[np.ndarray, np.ndarray] | None:
        """``(W, S)`` of ``kincal.kinematics.elastic.compliance_basis`` at readings q (N, n); None without nodes."""
        return compliance_basis(self.compliance_nodes, q) if self.compliance_nodes else None

    def compliance_at(self, q) -> np.ndarray:
        """Each joint's compliance at readings q (N, n): (n,) without nodes, else (N, n)."""
        basis = self.compliance_basis(q)
        return self.joint_compliance if basis is None else basis[0] @ self.joint_compliance

    def compliance_columns(self) -> list[tuple[int, float | None]]:
        """Per coefficient: its joint index and node angle (None for a constant compliance)."""
        nodes = self.compliance_nodes or (None,) * self.dof
        return [(j, None if x is None else float(a)) for j, x in enumerate(nodes)
                for a in ([None] if x is None else x)]

    @cached_property
    def basis(self) -> np.ndarray:
        """Block-diagonal (6n, t) map from all tangent coordinates to the stacked twist coordinates."""
        t = sum(b.shape[1] for b in self.bases)
        out = np.zeros((6 * self.dof, t))
        c = 0
        for i, b in enumerate(self.bases):
            out[6 * i: 6 * i + 6, c: c + b.shape[1]] = b
            c += b.shape[1]
        return out

    @cached_property
    def basis_pinv(self) -> np.ndarray:
        """The pseudo-inverse (t, 6n) of ``basis``, block by block (it is block-diagonal), the joints of one
        shape in one batch: ``(B^T B)^-1 B^T`` (each block has independent, near-unit columns)."""
        out = np.zeros(self.basis.shape[::-1])
        cols = np.cumsum([0] + [b.shape[1] for b in self.bases])
        for k in sorted({b.shape[1] for b in self.bases}):
            js = [j for j, b in enumerate(self.bases) if b.shape[1] == k]
            B = np.stack([self.bases[j] for j in js])
            Bt = np.swapaxes(B, -1, -2)
            for j, P in zip(js, np.linalg.solve(Bt @ B, Bt)):
                out[cols[j]: cols[j + 1], 6 * j: 6 * j + 6] = P
        return out

    def tangent_coordinates(self, v: np.ndarray) -> np.ndarray:
        """``basis_pinv @ v.ravel()`` for twist changes ``v`` (n, 6), joint by joint (the joints of one shape in
        one batched solve) without forming ``basis_pinv``: what a state met once (the scale test at every
        linearization) needs."""
        widths = {b.shape[1] for b in self.bases}
        if len(widths) != 1:
            return self.basis_pinv @ np.ravel(v)
        B = np.stack(self.bases)
        Bt = np.swapaxes(B, -1, -2)
        return np.linalg.solve(Bt @ B, Bt @ np.reshape(v, (-1, 6, 1))).ravel()

    @staticmethod
    def from_model(model: ArmModel) -> "ArmValues":
        """The values of ``model`` (remembered per model object: models and values are immutable, and a Monte
        Carlo study or a batch builds its problems from the same nominal robot again and again)."""
        hit = _FROM_MODEL.get(id(model))
        if hit is not None and hit[0]() is model:
            return hit[1]
        values = ArmValues._of(model)
        for a in (values.screws, values.offsets, values.base, values.home, values.tool, values.compliance,
                  *values.bases, *values.generators):
            if isinstance(a, np.ndarray):
                a.flags.writeable = False  # shared by every problem built from this model: never changed in place
        remember(_FROM_MODEL, id(model), (weakref.ref(model), values), _FROM_MODEL_ENTRIES)
        return values

    @staticmethod
    def _of(model: ArmModel) -> "ArmValues":
        B, G = tangent_frames(model.screws, model.joint_types)
        return ArmValues(
            np.array(model.screws), np.array(model.offsets), np.array(model.base), np.array(model.home),
            np.array(model.tool), B, model.joint_names, model.joint_types, G, compliance_coefficients(model),
            node_angles(model) if model.compliance_nodes else (),
            coupling_map(model.couplings, model.joint_names)[0] if model.couplings else None,
            gravity_load(model),
            None if model.lateral is None else np.array(model.lateral),
            None if model.lateral is None else np.array(model.lateral_axes),
        )


_ARM_FIELDS = tuple(f.name for f in fields(ArmValues))
_ARM_FIELD_SET = frozenset(_ARM_FIELDS)
# constructing one runs no check of its own and sets every field from its argument
_ARM_PLAIN = not hasattr(ArmValues, "__post_init__") and all(f.init for f in fields(ArmValues))


def arm_replace(a: ArmValues, **changes) -> ArmValues:
    """``dataclasses.replace(a, **changes)`` without its field-by-field ``__init__`` (several per solver step): the
    same fields, none of ``a``'s cached properties (``basis``, ``basis_pinv``: they depend on the fields)."""
    if type(a) is not ArmValues or not _ARM_PLAIN or not _ARM_FIELD_SET.issuperset(changes):
        return replace(a, **changes)  # its checks and errors
    new = object.__new__(ArmValues)
    old, d = a.__dict__, new.__dict__
    for name in _ARM_FIELDS:
        d[name] = old[name]
    d.update(changes)
    return new

# ArmValues.from_model's memory: id(model) -> (weak reference to the model, its values), oldest first
_FROM_MODEL: dict[int, tuple[weakref.ref, ArmValues]] = {}
_FROM_MODEL_ENTRIES = 64


def twist_motions(a: ArmValues, d: np.ndarray) -> np.ndarray:
    """The rigid motions ``G_j d_j`` (n, 6) that retract the joint screws by tangent coordinates ``d``."""
    G = _one_width(a.generators)
    if G is not None:  # joints of one kind (all revolute, say): one batched product
        return np.einsum("jak,jk->ja", G, d.reshape(len(G), -1))
    cuts = np.cumsum([0] + [G.shape[1] for G in a.generators])
    return np.stack([G @ d[i:k] for G, i, k in zip(a.generators, cuts[:-1], cuts[1:])])  # all joints at once


def _one_width(frames) -> np.ndarray | None:
    """The joints' frames (bases or generators, (6, k) each) stacked (n, 6, k) when every joint has the same k
    (``tangent_frames``' ``Stacked``: its own array); else None."""
    if type(frames) is Stacked:
        return frames.stack if frames else None
    return np.stack(frames) if len({G.shape[1] for G in frames}) == 1 else None


def retract_twists(a: ArmValues, d: np.ndarray, tangents: bool = True, motion=None) -> ArmValues:
    """Exact retraction of the joint screws: xi_j = Ad(exp(G_j d_j)) xi_j, which stays a valid joint screw,
    with the basis at d: d xi_j = -ad(xi_j) J_l(G_j d_j) G_j dd_j. ``tangents=False``: the screws only, for a
    residual without Jacobian (a trial point, re-centred if kept): ``bases`` and ``generators`` are None.
    ``motion``: ``(twist_motions(a, d), their exponentials)`` when computed already (``ops.retract`` takes every
    exponential of a retraction in one batch)."""
    g, E = motion if motion is not None else (twist_motions(a, d), None)
    Ad = se3.adjoint(se3.exp(g) if E is None else E)
    screws = np.einsum("jab,jb->ja", Ad, a.screws)
    axes = None if a.lateral_axes is None else np.einsum("jab,jkb->jka", Ad, a.lateral_axes)
    if not tangents:
        return arm_replace(a, screws=screws, bases=None, generators=None, lateral_axes=axes)
    Jl, ad = se3.left_jacobian(g), se3.ad(screws)
    G = _one_width(a.generators)
    if G is not None:
        G = Jl @ G  # retracting again from here keeps basis == -ad(xi) G
        gens, bs = Stacked(G), Stacked(-ad @ G)
    else:
        gens = tuple(Jl[j] @ G for j, G in enumerate(a.generators))
        bs = tuple(-ad[j] @ G for j, G in enumerate(gens))
    return arm_replace(a, screws=screws, bases=bs, generators=gens, lateral_axes=axes)



def _compliance_fields(a: ArmValues, model: ArmModel | None = None) -> dict:
    """``compliance`` (n,) and ``compliance_nodes`` of an ArmModel from the coefficients, as estimated: one below 0
    is kept (``allow_negative_compliance``), so the model predicts what the solver fitted; the calibration's
    verdict reports it (``kincal.estimation.plausibility.negative_compliances``). None of them where they are
    ``model``'s own bit for bit (compliance not estimated, ``to_robot``): its checked copy is kept."""
    k = a.joint_compliance
    below = any(c < 0 for c in k.tolist()) or (a.lateral is not None and any(c < 0 for c in a.lateral.ravel().tolist()))
    negative = {"allow_negative_compliance": True} if below else {}
    if a.lateral is not None:
        negative.update(lateral=a.lateral, lateral_axes=a.lateral_axes)
    if not a.compliance_nodes:
        if not negative and model is not None and same_array_bits(k, model.compliance):
            return {}
        return {"compliance": k, **negative}
    c, nodes = np.zeros(a.dof), {}
    for (j, at), value in zip(a.compliance_columns(), k):
        if at is None:
            c[j] = value
        else:
            nodes.setdefault(a.joint_names[j], []).append((at, value))
    return {"compliance": c, "compliance_nodes": nodes, **negative}


@dataclass(frozen=True)
class Plane:
    """A plane ``n . p = d``; ``normal`` may be unnormalized inside an inner solve, ``U`` spans its tangent."""

    normal: np.ndarray  # (3,)
    d: float
    U: np.ndarray  # (3, 2)

    @staticmethod
    def from_array(a) -> "Plane":
        a = np.asarray(a, dtype=float)
        n = a[:3] / np.linalg.norm(a[:3])
        return Plane(n, float(a[3] / np.linalg.norm(a[:3])), _perp(n))

    def unit(self) -> tuple[np.ndarray, float]:
        return self.normal / np.linalg.norm(self.normal), self.d

    def as_array(self) -> np.ndarray:
        n, d = self.unit()
        return np.append(n, d)


def _perp(n: np.ndarray) -> np.ndarray:
    a = np.eye(3)[np.argmin(np.abs(n))]
    u1 = so3.cross(n, a)
    u1 /= np.linalg.norm(u1)
    return np.stack([u1, so3.cross(n, u1)], axis=-1)


@dataclass(frozen=True)
class State:
    """All parameter values: arms by name, experiment frames (``extras``) by name, and each frame's
    parameter kind (``kinds``, name -> ``kincal.params.kinds.ParamKind``)."""

    arms: Mapping[str, ArmValues]
    extras: Mapping[str, object] = field(default_factory=dict)
    kinds: Mapping[str, object] = field(default_factory=dict)
    mounts: Mapping[str, str] = field(default_factory=dict)  # child arm -> parent arm (``Robot.mounts``)

    def __post_init__(self) -> None:
        missing = [k for k in self.extras if k not in self.kinds]
        if missing:
            raise ModelError(f"frame(s) {', '.join(map(repr, missing))} have no parameter kind")

    @staticmethod
    def from_robot(robot: Robot, extras: Mapping[str, object] | None = None,
                   kinds: Mapping[str, object] | None = None) -> "State":
        return State({k: ArmValues.from_model(m) for k, m in robot.arms.items()}, dict(extras or {}),
                     dict(kinds or {}), dict(robot.mounts))

    def replace(self, arms: Mapping[str, ArmValues] | None = None, extras: Mapping[str, object] | None = None,
                kinds: Mapping[str, object] | None = None) -> "State":
        """A new state with ``arms`` and/or ``extras`` (and their ``kinds``) replaced."""
        return State(dict(self.arms if arms is None else arms), dict(self.extras if extras is None else extras),
                     {**self.kinds, **(kinds or {})}, self.mounts)

    def moved(self, arms: dict[str, ArmValues], extras: dict[str, object]) -> "State":
        """``replace(arms, extras)`` for new values of the same frames (a retraction, a re-centring): the dicts
        are the new state's own (the caller made them), the kinds and mounts this state's, and no frame without
        a kind can come in (the frames' names are checked to be this state's)."""
        if type(self) is not State or extras.keys() != self.extras.keys():
            return self.replace(arms, extras)
        new = object.__new__(State)
        new.__dict__.update(arms=arms, extras=extras, kinds=self.kinds, mounts=self.mounts)
        return new

    def to_robot(self, robot: Robot) -> Robot:
        """The calibrated Robot: ``robot`` with this state's (conformed) values."""
        arms = {}
        for key, model in robot.arms.items():
            if key not in self.arms:  # an arm no experiment involves stays as it was
                arms[key] = model
                continue
            a = self.arms[key]
            screws = conform_twists(a.screws, a.joint_types)
            arms[key] = model.replace(
                screws=screws, offsets=a.offsets, base=a.base, home=a.home, tool=a.tool, **_compliance_fields(a, model))
        return Robot(robot.name, arms, dict(robot.meta), robot.mounts)
