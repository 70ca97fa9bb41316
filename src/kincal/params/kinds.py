"""Parameter kinds: how one block of parameters is named, moved and compared (compare jaxls' ``Var``).

A kind owns every fact about its block: the names and units of its local coordinates, the retraction
``value -> value (+) d``, the displacement of a value from a nominal one (the chart used for priors and
reports) with its derivative, re-centring between linearizations, the direction that scales every length,
and how a rigid motion of the world moves a frame of this kind. Nothing else switches on what a block is.

Arm kinds act on an arm's ``ArmValues`` (offsets, twists, home/base/tool poses, compliance); frame kinds on
a frame's value (pose 4x4, point (3,), points (m, 3), ``Plane``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kincal._memo import remember
from kincal.errors import ModelError
from kincal.kinematics import PRISMATIC, REVOLUTE, TWIST_COORDS, conform_twists, tangent_frames
from kincal.kinematics.lateral import LATERAL_COORDS
from kincal.lie import se3, so3
from kincal.params.values import Plane, arm_replace, retract_twists

POSE_COORDS = TWIST_COORDS  # a pose increment is a twist
POSE_UNITS = ("m", "m", "m", "rad", "rad", "rad")
COMPLIANCE_UNITS = {REVOLUTE: "rad/Nm", PRISMATIC: "m/N"}


class ParamKind:
    """Base of every parameter kind. ``rank``: default pivot priority in the gauge (lower first);
    ``absolute``: estimates are reported as values (offsets, points) rather than displacements from nominal."""

    name = ""
    rank = 9
    absolute = False
    on_arm = False
    additive = False  # displacement ``value - nominal`` (``offset``), its derivative the identity

    def __reduce__(self):
        # the module's own instance when unpickled (a result sent back by a Dask worker): kinds are compared by
        # identity (``b.kind is POSE``), which a copy would fail silently
        if _BY_NAME.get(self.name) is self:
            return kind_named, (self.name,)
        return super().__reduce__()

    def coordinates(self, prefix: str, value) -> tuple[list[str], list[str]]:
        raise NotImplementedError

    def retract(self, value, d: np.ndarray):
        raise NotImplementedError

    def recentre(self, value):
        """The value as the next linearization point (re-normalized, tangent bases recomputed)."""
        return value

    def displacement(self, value, nominal) -> tuple[np.ndarray, np.ndarray]:
        """Local displacement from ``nominal`` and its derivative w.r.t. ``value``'s own local coordinates."""
        raise NotImplementedError

    def offset(self, value, nominal) -> np.ndarray:
        """The local displacement from ``nominal`` alone (``displacement`` without its derivative)."""
        return self.displacement(value, nominal)[0]

    def pose_of(self, value) -> np.ndarray | None:
        """The 4 x 4 pose a pose kind's displacement is taken of (``log(T T0^-1)``, batched over blocks by
        ``ops.displacement``); None for the other kinds."""
        return None

    def with_pose(self, value, T: np.ndarray):
        """``value`` with its pose (``pose_of``) replaced by ``T`` (pose kinds only)."""
        raise ModelError(f"parameter kind '{self.name}' is no pose")

    def scale(self, value) -> np.ndarray:
        """Local direction scaling every length of the value (zeros: nothing to scale)."""
        raise NotImplementedError

    def values(self, value) -> np.ndarray:
        """The coordinates' own values (absolute kinds only)."""
        raise ModelError(f"parameter kind '{self.name}' has no absolute values")

    def world_motion(self, value, xi: np.ndarray) -> np.ndarray:
        """Local coordinates of turning this frame along with the world by the twist ``xi`` (first order)."""
        raise ModelError(f"parameter kind '{self.name}' does not move with the world")

    def retraction_jacobian(self, d: np.ndarray) -> np.ndarray | None:
        """d(retract(value, d)) / dd in the kind's own increments at d, when it is not the identity (poses:
        the left Jacobian ``J_l(d)``); None otherwise (additive kinds; twists carry theirs in their bases)."""
        return None

    def origin(self, value) -> np.ndarray | None:
        """The frame's origin (3,) in world coordinates, if it has one (poses, single points)."""
        return None

    def origin_jacobian(self, value) -> np.ndarray:
        """d origin / d local coordinates (3, k)."""
        raise ModelError(f"parameter kind '{self.name}' has no origin")

    def from_raw(self, raw):
        """A frame value from a known or initial array."""
        return np.array(raw, dtype=float)

    def __eq__(self, other):
        if isinstance(other, str):  # kinds are objects: a leftover string comparison is a bug, not False
            raise TypeError(f"compare parameter kinds by identity, not with the string {other!r}")
        return self is other

    __hash__ = object.__hash__

    def __repr__(self) -> str:
        return f"<parameter kind {self.name}>"


def _pose_disp(T, T0):
    return se3.log_with_jacobian_inv(T @ se3.inverse(T0))


def _pose_offset(T, T0):
    return se3.log(T @ se3.inverse(T0))


def _translation_scale(T) -> np.ndarray:
    return np.array([*T[:3, 3].tolist(), 0.0, 0.0, 0.0])


class _Offsets(ParamKind):
    name, rank, absolute, on_arm = "offsets", 0, True, True
    additive = True

    def coordinates(self, prefix, a):
        return ([f"{prefix}.{j}.offset" for j in a.joint_names],
                ["rad" if t == REVOLUTE else "m" for t in a.joint_types])

    def retract(self, a, d):
        return arm_replace(a, offsets=a.offsets + d)

    def displacement(self, a, a0):
        return self.offset(a, a0), np.eye(a.dof)

    def offset(self, a, a0):
        return a.offsets - a0.offsets

    def scale(self, a):
        if PRISMATIC not in a.joint_types:  # revolute offsets are angles: nothing scales
            return np.zeros(len(a.offsets))
        return np.where(np.array(a.joint_types) == PRISMATIC, a.offsets, 0.0)

    def values(self, a):
        return a.offsets


class _Twists(ParamKind):
    """Joint screws moved rigidly: ``Ad(exp(G d)) xi`` (4 coordinates per revolute joint, 2 per prismatic)."""

    name, rank, on_arm = "twists", 1, True

    def coordinates(self, prefix, a):
        names, units = [], []
        for j, t in zip(a.joint_names, a.joint_types):
            locs = ("shift_1", "shift_2", "tilt_1", "tilt_2") if t == REVOLUTE else ("tilt_1", "tilt_2")
            names += [f"{prefix}.{j}.xi.{c}" for c in locs]
            units += ["m" if c.startswith("shift") else "rad" for c in locs]
        return names, units

    def retract(self, a, d):
        return retract_twists(a, d)

    def recentre(self, a):
        """``with_tangents(conform(a))`` in one ``replace``."""
        screws = conform_twists(a.screws, a.joint_types)
        B, G = tangent_frames(screws, a.joint_types)
        return arm_replace(a, screws=screws, bases=B, generators=G)

    def conform(self, a):
        """The screws conformed (``conform_twists``: removes round-off only, the retraction is exact)."""
        return arm_replace(a, screws=conform_twists(a.screws, a.joint_types))

    def with_tangents(self, a):
        """The tangent bases and generators at the screws as they are."""
        B, G = tangent_frames(a.screws, a.joint_types)
        return arm_replace(a, bases=B, generators=G)

    def displacement(self, a, a0):
        return self.offset(a, a0), a0.basis_pinv @ a.basis

    def offset(self, a, a0):
        return a0.basis_pinv @ (a.screws - a0.screws).ravel()

    def scale(self, a):
        """Remembered for screws and bases that cannot change (read-only: a model's own, ``ArmValues.from_model``,
        the start of every calibration from that model, and the values retracted from them in other blocks only),
        by the screws array (held with the entry, so its id is not reused meanwhile)."""
        hit = _TWIST_SCALES.get(id(a.screws))
        if hit is not None and hit[0] is a.screws and hit[1] is a.bases and hit[2] == a.joint_types:
            return hit[3].copy()
        out = self._scale(a)
        if not a.screws.flags.writeable and a.bases and not any(B.flags.writeable for B in a.bases):
            out.flags.writeable = False
            remember(_TWIST_SCALES, id(a.screws), (a.screws, a.bases, a.joint_types, out), _TWIST_SCALE_ENTRIES)
            return out.copy()
        return out

    def _scale(self, a):
        v = np.zeros_like(a.screws)
        if PRISMATIC not in a.joint_types:  # every joint revolute: its moment scales (``rev`` all true)
            v[:, :3] = a.screws[:, :3]
        else:
            rev = np.array(a.joint_types) == REVOLUTE
            v[rev, :3] = a.screws[rev, :3]
        return a.tangent_coordinates(v)


# _Twists.scale's memory: id(screws) -> (screws, bases, joint types, their scale direction), oldest first
_TWIST_SCALES: dict[int, tuple] = {}
_TWIST_SCALE_ENTRIES = 64


class _ArmPose(ParamKind):
    """One of an arm's fixed poses (``home``, ``base``, ``tool``), moved by a left increment ``exp(d) T``."""

    on_arm = True

    def __init__(self, field: str, rank: int):
        self.name, self.rank, self.field = field, rank, field

    def coordinates(self, prefix, a):
        return [f"{prefix}.{self.field}.{c}" for c in POSE_COORDS], list(POSE_UNITS)

    def retract(self, a, d):
        return arm_replace(a, **{self.field: se3.exp(d) @ getattr(a, self.field)})

    def displacement(self, a, a0):
        return _pose_disp(getattr(a, self.field), getattr(a0, self.field))

    def pose_of(self, a):
        return getattr(a, self.field)

    def with_pose(self, a, T):
        return arm_replace(a, **{self.field: T})

    def offset(self, a, a0):
        return _pose_offset(getattr(a, self.field), getattr(a0, self.field))

    def scale(self, a):
        return _translation_scale(getattr(a, self.field))

    def retraction_jacobian(self, d):
        return se3.left_jacobian(d)


def with_arm_poses(a, poses):
    """``a`` with several of its poses replaced at once: ``poses`` [(arm pose kind, T)] (one ``replace``, the
    same values as the kinds' ``with_pose`` one after the other)."""
    return arm_replace(a, **{kind.field: T for kind, T in poses})


class _Compliance(ParamKind):
    """Compliance coefficients, ``k + d``: one per joint (``arm.j3.compliance``), or one per node of a joint
    whose compliance depends on its angle (``arm.j2.compliance@-57deg``: the node angle to the nearest degree)."""

    name, rank, absolute, on_arm = "compliance", 5, True, True
    additive = True

    def coordinates(self, prefix, a):
        names, units = [], []
        for j, at in a.compliance_columns():
            node = "" if at is None else f"@{np.degrees(at):.0f}deg".replace("@-0deg", "@0deg")
            names.append(f"{prefix}.{a.joint_names[j]}.compliance{node}")
            units.append(COMPLIANCE_UNITS[a.joint_types[j]])
        return names, units

    def retract(self, a, d):
        return arm_replace(a, compliance=a.joint_compliance + d)

    def displacement(self, a, a0):
        d = self.offset(a, a0)
        return d, np.eye(len(d))

    def offset(self, a, a0):
        return a.joint_compliance - a0.joint_compliance

    def scale(self, a):  # same deflection under a pure force: torques scale with length
        c = a.joint_compliance
        if PRISMATIC not in a.joint_types:
            return -c
        prismatic = np.array([a.joint_types[j] == PRISMATIC for j, _ in a.compliance_columns()])
        return np.where(prismatic, c, -c)

    def values(self, a):
        return a.joint_compliance


class _Lateral(ParamKind):
    """Lateral compliances (``kincal.kinematics.lateral``), ``l + d``: two per joint of an arm that declares them
    (``arm.j2.lateral_x``, ``arm.j2.lateral_y``, rad/(N m)); none for an arm without."""

    name, rank, absolute, on_arm = "lateral", 6, True, True
    additive = True

    def coordinates(self, prefix, a):
        if a.lateral is None:
            return [], []
        return [f"{prefix}.{j}.{c}" for j in a.joint_names for c in LATERAL_COORDS], ["rad/Nm"] * (2 * a.dof)

    def retract(self, a, d):
        return arm_replace(a, lateral=a.lateral + d.reshape(-1, 2)) if a.lateral is not None else a

    def displacement(self, a, a0):
        d = self.offset(a, a0)
        return d, np.eye(d.size)

    def offset(self, a, a0):
        return np.ravel(a.lateral) - np.ravel(a0.lateral)

    def scale(self, a):  # rotational compliance: torques scale with length
        return -np.ravel(a.lateral)

    def values(self, a):
        return np.ravel(a.lateral)


class _Pose(ParamKind):
    name = "pose"

    def coordinates(self, prefix, T):
        return [f"{prefix}.{c}" for c in POSE_COORDS], list(POSE_UNITS)

    def retract(self, T, d):
        return se3.exp(d) @ T

    def displacement(self, T, T0):
        return _pose_disp(T, T0)

    def pose_of(self, T):
        return T

    def with_pose(self, T, T_new):
        return T_new

    def offset(self, T, T0):
        return _pose_offset(T, T0)

    def scale(self, T):
        return _translation_scale(T)

    def world_motion(self, T, xi):
        return np.array(xi, dtype=float)

    def origin(self, T):
        return T[:3, 3]

    def origin_jacobian(self, T):  # a left increment moves the origin p by v + w x p
        return np.concatenate([np.eye(3), -so3.hat(T[:3, 3])], axis=1)

    def retraction_jacobian(self, d):
        return se3.left_jacobian(d)


class _Points(ParamKind):
    """Points, ``p + d``: one point (3,) named ``x, y, z``, or several (m, 3) named ``m1.x ...``."""

    absolute = additive = True

    def __init__(self, single: bool):
        self.single = single
        self.name = "point" if single else "points"

    def coordinates(self, prefix, p):
        p = np.asarray(p)
        if self.single:
            return [f"{prefix}.{c}" for c in "xyz"], ["m"] * 3
        return [f"{prefix}.m{i + 1}.{c}" for i in range(p.shape[0]) for c in "xyz"], ["m"] * p.size

    def retract(self, p, d):
        return p + d.reshape(np.shape(p))

    def displacement(self, p, p0):
        d = self.offset(p, p0)
        return d, np.eye(d.size)

    def offset(self, p, p0):
        return (np.asarray(p) - np.asarray(p0)).ravel()

    def scale(self, p):
        return np.asarray(p, dtype=float).ravel()

    def values(self, p):
        return np.ravel(p)

    def world_motion(self, p, xi):
        v, w = se3.split(xi)
        return (v + so3.cross(w, np.asarray(p))).ravel()

    def origin(self, p):
        return np.asarray(p) if self.single else None

    def origin_jacobian(self, p):
        if not self.single:
            return super().origin_jacobian(p)
        return np.eye(3)


class _Plane(ParamKind):
    """A plane ``n . p = d``: the normal moves in its 2-dimensional tangent, the offset additively."""

    name = "plane"

    def coordinates(self, prefix, pl):
        return [f"{prefix}.n_1", f"{prefix}.n_2", f"{prefix}.d"], ["rad", "rad", "m"]

    def retract(self, pl, d):
        return replace(pl, normal=pl.normal + pl.U @ d[:2], d=pl.d + d[2])

    def recentre(self, pl):
        return Plane.from_array(pl.as_array())

    def displacement(self, pl, pl0):
        n, d = pl.unit()
        m = np.linalg.norm(pl.normal)
        D = np.zeros((3, 3))
        D[:2, :2] = pl0.U.T @ ((np.eye(3) - np.outer(n, n)) / m) @ pl.U
        D[2, 2] = 1.0
        return np.append(pl0.U.T @ (n - pl0.normal), d - pl0.d), D

    def scale(self, pl):
        return np.array([0.0, 0.0, pl.d])

    def world_motion(self, pl, xi):
        v, w = se3.split(xi)
        n, _ = pl.unit()
        return np.append(pl.U.T @ so3.cross(w, n), n @ v)

    def from_raw(self, raw):
        return raw if isinstance(raw, Plane) else Plane.from_array(raw)


OFFSETS = _Offsets()
TWISTS = _Twists()
HOME, BASE, TOOL = _ArmPose("home", 2), _ArmPose("base", 3), _ArmPose("tool", 4)
COMPLIANCE = _Compliance()
LATERAL = _Lateral()
ARM_KINDS = (OFFSETS, TWISTS, HOME, BASE, TOOL, COMPLIANCE, LATERAL)  # every arm's blocks, in this order
POSE = _Pose()
POINT = _Points(single=True)
POINTS = _Points(single=False)
PLANE = _Plane()
FRAME_KINDS = {k.name: k for k in (POSE, POINT, POINTS, PLANE)}  # by the names experiment schemas use
_BY_NAME = {k.name: k for k in (*ARM_KINDS, *FRAME_KINDS.values())}


def kind_named(name: str) -> ParamKind:
    """The module's kind of that name (what a pickled kind unpickles to)."""
    return _BY_NAME[name]
