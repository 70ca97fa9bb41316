"""Immutable product-of-exponentials arm and robot models."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Mapping

import numpy as np

from kincal._validate import DET_MARGIN, as_array, check_transform
from kincal.errors import ModelError
from kincal.kinematics.couplings import checked_couplings
from kincal.kinematics.lateral import lateral_axes
from kincal.lie import se3

REVOLUTE = "revolute"
PRISMATIC = "prismatic"
_UNIT_TOL = 1e-9


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class ArmModel:
    """A serial arm in product-of-exponentials form.

    ``T_world_tool(q) = base @ exp(hat(xi_1) (q_1 + o_1)) ... exp(hat(xi_n) (q_n + o_n)) @ home @ tool``

    Attributes
    ----------
    name : str
    screws : ndarray, shape (n, 6)
        Joint twists ``(v, w)`` in the arm base frame at q = 0. Revolute: unit w, v = -w x p (zero pitch).
        Prismatic: w = 0, unit v.
    home : ndarray, shape (4, 4)
        ``T_base_flange`` at q = 0 (the thesis' T_st).
    base : ndarray, shape (4, 4)
        ``T_world_base``, pose of the arm base in the robot/world frame.
    tool : ndarray, shape (4, 4)
        ``T_flange_tool``.
    offsets : ndarray, shape (n,)
        Joint offsets o (rad or m): the true joint value is the reading plus the offset.
    lower, upper : ndarray, shape (n,)
        Joint limits in model units (rad or m), applied to the reading q.
    compliance : ndarray, shape (n,)
        Joint compliances c >= 0 (rad/(N m) revolute, m/N prismatic), default zeros: under a load the joint
        deflects by ``c_i tau_i`` (``kincal.kinematics.elastic``).
    compliance_nodes : mapping joint name -> ndarray (m, 2), optional
        Joints whose compliance depends on their own reading (seed 001 Sec. V: joint 2 of a KR-270, whose
        gravity compensator makes its spring non-linear): rows ``(angle rad, compliance)`` with strictly
        increasing angles within the joint's limits, at least 2; the compliance is interpolated linearly in
        the reading between them and held at the end values beyond (``kincal.kinematics.elastic``). Revolute
        joints only; their entry in ``compliance`` must be 0 (the table replaces it).
    allow_negative_compliance : bool
        False (default): every compliance must be >= 0, as a real joint's. True: a calibrated model, whose
        compliances are estimates kept as the solver fitted them, also below 0 (the calibration's verdict reports
        those: ``kincal.estimation.plausibility.negative_compliances``).
    gear_ratios : ndarray, shape (n,)
        Motor units per joint unit (motor rad = ratio * arm rad), in model joint order.
    controller_order : tuple of int
        0-based model joint index carried by each controller channel (Frida: (0, 1, 3, 4, 5, 6, 2):
        its axes are numbered 1, 2, 7, 3, 4, 5, 6 from the base, so channel 7 carries model joint 3).
    joint_names, joint_types : tuple of str
    link_masses : ndarray, shape (n,)
        Mass (kg) of link i, the body moved by joint i (and by no later joint); default zeros.
    link_coms : ndarray, shape (n, 3)
        Centre of mass of link i (m) in the arm base frame at q = 0, like the screws; default zeros.
    payload_mass : float
        Mass (kg) carried by the tool; default 0.
    payload_com : ndarray, shape (3,)
        The payload's centre of mass (m) in the tool frame.
    gravity : ndarray, shape (3,), optional
        Gravitational acceleration (m/s^2) in the world frame, e.g. (0, 0, -9.81); None (default): the mass
        model loads nothing. With masses and gravity, the weights load the joint compliances in every
        configuration (``kincal.kinematics.gravity``).
    lateral : ndarray, shape (n, 2), optional
        Lateral compliances (rad/(N m)) about each joint's two lateral axes (``kincal.kinematics.lateral``); None
        (default): the arm has no lateral compliance (no ``lateral`` parameters).
    lateral_axes : ndarray, shape (n, 2, 6), optional
        The lateral axes as screws at q = 0 (arm base frame), default ``kincal.kinematics.lateral.lateral_axes``
        of the screws; stored, so calibrated twists carry them (``replace(screws=...)`` keeps them as they are).
    meta : mapping
        Free-form provenance (source, notes); not used in computation.
    """

    name: str
    screws: np.ndarray
    home: np.ndarray
    base: np.ndarray = field(default_factory=lambda: np.eye(4))
    tool: np.ndarray = field(default_factory=lambda: np.eye(4))
    offsets: np.ndarray | None = None
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    gear_ratios: np.ndarray | None = None
    controller_order: tuple[int, ...] | None = None
    joint_names: tuple[str, ...] | None = None
    joint_types: tuple[str, ...] | None = None
    meta: Mapping = field(default_factory=dict)
    compliance: np.ndarray | None = None
    compliance_nodes: Mapping[str, np.ndarray] | None = None
    allow_negative_compliance: bool = False
    # --- joint couplings (kincal.kinematics.couplings): joint -> {other joint: coefficient, "constant": c}
    couplings: Mapping[str, Mapping[str, float]] | None = None
    # mass model (kincal.kinematics.gravity): one block, validated by _mass_fields
    link_masses: np.ndarray | None = None
    link_coms: np.ndarray | None = None
    payload_mass: float = 0.0
    payload_com: np.ndarray | None = None
    gravity: np.ndarray | None = None
    # lateral compliance (kincal.kinematics.lateral): None, or (n, 2) rad/(N m) about each joint's lateral axes
    lateral: np.ndarray | None = None
    lateral_axes: np.ndarray | None = None

    def __post_init__(self) -> None:
        where = f"arm '{self.name}'"
        screws = as_array(self.screws, f"{where}: screws", (6,))
        if screws.ndim != 2 or screws.shape[0] < 1:
            raise ModelError(f"{where}: screws must have shape (n, 6) with n >= 1, got {screws.shape}")
        n = screws.shape[0]
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731  (frozen dataclass)
        set_("screws", _frozen(screws))
        for key in ("home", "base", "tool"):
            set_(key, _checked_transform(self, key, where))
        for key, default in (("offsets", 0.0), ("lower", -np.inf), ("upper", np.inf), ("gear_ratios", 1.0),
                             ("compliance", 0.0)):
            set_(key, _joint_vector(self, key, default, n, where))
        _check_compliance(self, where)
        if np.any(np.isnan(self.lower)) or np.any(np.isnan(self.upper)) or np.any(self.lower >= self.upper):
            raise ModelError(f"{where}: joint limits need lower < upper, got lower={self.lower.tolist()} upper={self.upper.tolist()}")
        if np.any(self.gear_ratios == 0):
            raise ModelError(f"{where}: gear ratios must be non-zero, got {self.gear_ratios.tolist()}")

        names = tuple(self.joint_names) if self.joint_names is not None else tuple(f"j{i + 1}" for i in range(n))
        if len(names) != n or len(set(names)) != n or not all(isinstance(s, str) and s for s in names):
            raise ModelError(f"{where}: joint_names must be {n} distinct non-empty strings, got {names}")
        set_("joint_names", names)

        w_norm = np.linalg.norm(screws[:, 3:], axis=1)
        inferred = tuple(PRISMATIC if w < 0.5 else REVOLUTE for w in w_norm)
        types = tuple(self.joint_types) if self.joint_types is not None else inferred
        if len(types) != n or any(t not in (REVOLUTE, PRISMATIC) for t in types):
            raise ModelError(f"{where}: joint_types must be {n} of 'revolute'/'prismatic', got {types}")
        set_("joint_types", types)
        _check_joint_screws(screws, types, names, where)

        set_("allow_negative_compliance", bool(self.allow_negative_compliance))
        set_("compliance_nodes", MappingProxyType(_nodes(self, where)))
        for key, value in _mass_fields(self, where).items():
            set_(key, value)
        order = tuple(range(n)) if self.controller_order is None else tuple(int(i) for i in self.controller_order)
        if sorted(order) != list(range(n)):
            raise ModelError(f"{where}: controller_order must be a permutation of 0..{n - 1}, got {order}")
        set_("controller_order", order)
        set_("meta", MappingProxyType(dict(self.meta)))
        set_("couplings", checked_couplings(self.couplings, names, where))
        for key, value in _lateral_fields(self, where).items():
            set_(key, value)

    @property
    def dof(self) -> int:
        return self.screws.shape[0]

    @property
    def has_gravity_load(self) -> bool:
        """Whether gravity acts on some mass of this arm (``kincal.kinematics.gravity``)."""
        return self.gravity is not None and bool(np.any(self.gravity)) and (
            bool(np.any(self.link_masses)) or self.payload_mass > 0)

    def replace(self, **changes) -> "ArmModel":
        """A copy with some fields changed (validated again). Changes of the geometry alone (screws of the same
        joints, offsets, base, home, tool, constant compliances: a calibrated model) validate only those
        fields, with the same checks: the others were validated with this model."""
        if changes.keys() <= _GEOMETRY and not self.compliance_nodes and (
                "screws" not in changes or np.shape(changes["screws"]) == self.screws.shape):
            return self._with_geometry(changes)
        return replace(self, **changes)

    def _with_geometry(self, changes: dict) -> "ArmModel":
        where = f"arm '{self.name}'"
        new = object.__new__(ArmModel)
        fields = new.__dict__  # written directly: a frozen dataclass without slots, as object.__setattr__ would
        fields.update(self.__dict__, **changes)
        if "screws" in changes:
            screws = fields["screws"]
            if not _valid_screws(screws, new.joint_types):  # the checks below decide, and say what fails
                screws = as_array(screws, f"{where}: screws", (6,))
                _check_joint_screws(screws, new.joint_types, new.joint_names, where)
            fields["screws"] = _frozen(screws)
        for key in ("home", "base", "tool"):
            if key in changes:  # a transform bit for bit this model's passed its checks: its frozen copy is kept
                own = getattr(self, key)
                fields[key] = own if same_array_bits(changes[key], own) else _checked_transform(new, key, where)
        for key, default in (("offsets", 0.0), ("compliance", 0.0)):
            if key in changes:
                fields[key] = _joint_vector(new, key, default, new.dof, where)
        if "compliance" in changes:  # else this model's, checked with the same allow_negative_compliance
            _check_compliance(new, where)
        return new

    def home_twist(self) -> np.ndarray:
        """The thesis' xi_st: twist coordinates with exp(xi_st) = home."""
        return se3.log(self.home)

    def within_limits(self, q: np.ndarray, tol: float = 0.0) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        return np.all((q >= self.lower - tol) & (q <= self.upper + tol), axis=-1)

    def __eq__(self, other) -> bool:
        if not isinstance(other, ArmModel):
            return NotImplemented
        arrays = ("screws", "home", "base", "tool", "offsets", "lower", "upper", "gear_ratios", "compliance",
                  "link_masses", "link_coms", "payload_mass", "payload_com")
        return (
            self.name == other.name
            and self.joint_names == other.joint_names
            and self.joint_types == other.joint_types
            and self.controller_order == other.controller_order
            and all(np.array_equal(getattr(self, a), getattr(other, a)) for a in arrays)
            and self.compliance_nodes.keys() == other.compliance_nodes.keys()
            and all(np.array_equal(v, other.compliance_nodes[k]) for k, v in self.compliance_nodes.items())
            and _plain_couplings(self) == _plain_couplings(other)
            and (self.gravity is None) == (other.gravity is None)
            and (self.gravity is None or np.array_equal(self.gravity, other.gravity))
            and (self.lateral is None) == (other.lateral is None)
            and (self.lateral is None or (np.array_equal(self.lateral, other.lateral)
                                          and np.array_equal(self.lateral_axes, other.lateral_axes)))
        )

    __hash__ = None  # type: ignore[assignment]


# The fields ``ArmModel.replace`` validates on their own (``_with_geometry``).
_GEOMETRY = frozenset({"screws", "offsets", "base", "home", "tool", "compliance"})


def same_array_bits(x, frozen: np.ndarray) -> bool:
    """Whether ``x`` is an array equal to ``frozen`` bit for bit (dtype, shape and bytes: -0.0 is not 0.0)."""
    return isinstance(x, np.ndarray) and x.dtype == frozen.dtype and x.shape == frozen.shape and \
        x.tobytes() == frozen.tobytes()


def _checked_transform(arm: ArmModel, key: str, where: str) -> np.ndarray:
    T = getattr(arm, key)
    if type(T) is np.ndarray and T.dtype == np.float64 and T.shape == (4, 4) and _rigid(T.tolist()):
        return _frozen(T)
    return _frozen(check_transform(T, f"{where}: {key}", tol=_RIGID_TOL))


_RIGID_TOL = 1e-6  # an arm's transforms: last row and orthonormality (``check_transform``'s tol)


def _rigid(rows: list) -> bool:
    """Whether one transform (as Python lists) passes ``check_transform`` at ``_RIGID_TOL``, decided on Python
    floats (no numpy calls): True only with a margin (``DET_MARGIN``) inside the tolerance and an exact last row
    (0, 0, 0, 1); False leaves the decision, and its message, to ``check_transform``."""
    (a, b, c, x), (d, e, f, y), (g, h, i, z), last = rows
    if last != [0.0, 0.0, 0.0, 1.0] or not all(map(math.isfinite, (a, b, c, x, d, e, f, y, g, h, i, z))):
        return False
    tol = _RIGID_TOL - DET_MARGIN
    gram = (a * a + d * d + g * g - 1, b * b + e * e + h * h - 1, c * c + f * f + i * i - 1,
            a * b + d * e + g * h, a * c + d * f + g * i, b * c + e * f + h * i)  # R^T R - I, upper triangle
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)  # ``det3``'s, term for term
    return all(abs(v) <= tol for v in gram) and abs(det - 1.0) <= tol


def _joint_vector(arm: ArmModel, key: str, default: float, n: int, where: str) -> np.ndarray:
    """Field ``key`` as n per-joint values (``default`` for None), finite except the limits."""
    val = getattr(arm, key)
    arr = np.full(n, default, dtype=float) if val is None else np.asarray(val, dtype=float)
    if arr.shape != (n,):
        raise ModelError(f"{where}: {key} must have {n} entries (one per joint), got shape {arr.shape}")
    if key != "lower" and key != "upper" and not _all_finite(arr):
        raise ModelError(f"{where}: {key} must be finite, got {arr.tolist()}")
    return _frozen(arr)


def _all_finite(arr: np.ndarray) -> bool:
    """``np.all(np.isfinite(arr))`` of an arm's few per-joint values, on Python floats (no numpy calls)."""
    return all(map(math.isfinite, arr.ravel().tolist()))


def _check_compliance(arm: ArmModel, where: str) -> None:
    if not arm.allow_negative_compliance and any(c < 0 for c in arm.compliance.ravel().tolist()):
        raise ModelError(f"{where}: compliance must be >= 0 (rad/(N m) or m/N), got {arm.compliance.tolist()}"
                         "; a calibration's estimates below 0 need allow_negative_compliance")


def _check_joint_screws(screws: np.ndarray, types, names, where: str) -> None:
    """Revolute joints: a unit axis with zero pitch; prismatic: w = 0 and a unit v (every joint at once; the
    first one that fails is named)."""
    if all(_joint_screw_ok(x, t == REVOLUTE) for x, t in zip(screws.tolist(), types)):
        return
    for i, t in enumerate(types):
        v, w = screws[i, :3], screws[i, 3:]
        if t == REVOLUTE and (abs(np.linalg.norm(w) - 1) > _UNIT_TOL or abs(w @ v) > _UNIT_TOL):
            raise ModelError(
                f"{where}: joint {names[i]} is revolute and needs a unit axis with zero pitch; "
                f"got |w| = {np.linalg.norm(w):.12g}, w.v = {w @ v:.3g} (use kincal.kinematics.conform_twists)"
            )
        if t == PRISMATIC and (np.linalg.norm(w) > _UNIT_TOL or abs(np.linalg.norm(v) - 1) > _UNIT_TOL):
            raise ModelError(
                f"{where}: joint {names[i]} is prismatic and needs w = 0 and a unit v; "
                f"got |w| = {np.linalg.norm(w):.3g}, |v| = {np.linalg.norm(v):.12g}"
            )


def _valid_screws(screws, types) -> bool:
    """Whether ``screws``, a float array (n, 6) (``replace`` checked the shape), is finite and passes
    ``_check_joint_screws``: one pass on Python floats (``_joint_screw_ok`` fails a screw with nan or inf)."""
    return type(screws) is np.ndarray and screws.dtype == np.float64 and \
        all(_joint_screw_ok(x, t == REVOLUTE) for x, t in zip(screws.tolist(), types))


def _joint_screw_ok(x: list, revolute: bool) -> bool:
    """``_check_joint_screws``' test of one screw (v, w) on Python floats (an arm's few joints: no numpy calls).
    Written as "within": a screw with nan or inf fails it (``_valid_screws`` needs no finiteness test)."""
    v0, v1, v2, w0, w1, w2 = x
    nw = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if revolute:
        return abs(nw - 1) <= _UNIT_TOL and abs(w0 * v0 + w1 * v1 + w2 * v2) <= _UNIT_TOL
    return nw <= _UNIT_TOL and abs(math.sqrt(v0 * v0 + v1 * v1 + v2 * v2) - 1) <= _UNIT_TOL


def _lateral_fields(arm: ArmModel, where: str) -> dict:
    """``lateral`` (n, 2) and ``lateral_axes`` (n, 2, 6) checked (None when the arm has no lateral compliance;
    the axes default to ``kincal.kinematics.lateral.lateral_axes`` of the screws)."""
    if arm.lateral is None:
        if arm.lateral_axes is not None:
            raise ModelError(f"{where}: lateral_axes given without lateral compliances")
        return {}
    n = arm.screws.shape[0]
    c = np.asarray(arm.lateral, dtype=float)
    if c.shape != (n, 2) or not np.all(np.isfinite(c)):
        raise ModelError(f"{where}: lateral must be finite with shape ({n}, 2) (x, y per joint), got shape {c.shape}")
    if np.any(c < 0) and not arm.allow_negative_compliance:
        raise ModelError(f"{where}: lateral compliance must be >= 0 (rad/(N m)), got {c.tolist()}"
                         "; a calibration's estimates below 0 need allow_negative_compliance")
    axes = lateral_axes(arm.screws) if arm.lateral_axes is None else np.asarray(arm.lateral_axes, dtype=float)
    if axes.shape != (n, 2, 6) or not np.all(np.isfinite(axes)):
        raise ModelError(f"{where}: lateral_axes must be finite with shape ({n}, 2, 6), got shape {axes.shape}")
    return {"lateral": _frozen(c), "lateral_axes": _frozen(axes)}


def _plain_couplings(arm: ArmModel) -> dict:
    return {j: dict(t) for j, t in arm.couplings.items()}


def _nodes(arm: ArmModel, where: str) -> dict[str, np.ndarray]:
    """``compliance_nodes`` checked: known revolute joints, >= 2 increasing angles within limits, values >= 0
    (unless ``allow_negative_compliance``)."""
    out = {}
    for name, table in dict(arm.compliance_nodes or {}).items():
        at = f"{where}: joint {name}: compliance nodes"
        if name not in arm.joint_names:
            raise ModelError(f"{at}: no such joint; joints: {', '.join(arm.joint_names)}")
        j = arm.joint_names.index(name)
        t = np.array(table, dtype=float)
        if t.ndim != 2 or t.shape[1] != 2 or len(t) < 2 or not np.all(np.isfinite(t)):
            raise ModelError(f"{at}: expected at least 2 finite rows (angle, compliance), got shape {t.shape}")
        if arm.joint_types[j] != REVOLUTE:
            raise ModelError(f"{at}: only a revolute joint's compliance can depend on its angle")
        if arm.compliance[j] != 0:
            raise ModelError(f"{at}: the joint also has a constant compliance {arm.compliance[j]:g}; give one of them")
        if np.any(np.diff(t[:, 0]) <= 0):
            raise ModelError(f"{at}: angles must increase strictly, got {t[:, 0].tolist()}")
        if t[0, 0] < arm.lower[j] or t[-1, 0] > arm.upper[j]:
            raise ModelError(f"{at}: angles {t[:, 0].tolist()} leave the joint limits "
                             f"[{arm.lower[j]:g}, {arm.upper[j]:g}] rad")
        if len(np.unique(np.round(np.degrees(t[:, 0])))) < len(t):
            raise ModelError(f"{at}: angles {np.degrees(t[:, 0]).round(3).tolist()} deg: keep them at least 1 deg "
                             "apart (their parameters are named by the nearest degree)")
        if np.any(t[:, 1] < 0) and not arm.allow_negative_compliance:
            raise ModelError(f"{at}: compliances must be >= 0 (rad/(N m)), got {t[:, 1].tolist()}")
        out[name] = _frozen(t)
    return out


def _mass_fields(arm: ArmModel, where: str) -> dict:
    """The mass model checked: masses >= 0, finite centres of mass, gravity (3,) or None."""
    n = arm.dof

    def finite(key, value, shape, default):
        a = np.full(shape, default, dtype=float) if value is None else np.asarray(value, dtype=float)
        if a.shape != shape or not np.all(np.isfinite(a)):
            raise ModelError(f"{where}: {key} must be finite with shape {shape}, got {np.round(a, 6).tolist()}")
        return _frozen(a)

    out = {"link_masses": finite("link_masses", arm.link_masses, (n,), 0.0),
           "link_coms": finite("link_coms", arm.link_coms, (n, 3), 0.0),
           "payload_mass": float(finite("payload_mass", arm.payload_mass, (), 0.0)),
           "payload_com": finite("payload_com", arm.payload_com, (3,), 0.0),
           "gravity": None if arm.gravity is None else finite("gravity", arm.gravity, (3,), 0.0)}
    if np.any(out["link_masses"] < 0) or out["payload_mass"] < 0:
        raise ModelError(f"{where}: masses must be >= 0 kg, got link masses {out['link_masses'].tolist()}, "
                         f"payload {out['payload_mass']:g}")
    return out


@dataclass(frozen=True, eq=False)
class Robot:
    """One or more arms sharing a world frame (each arm's ``base`` is ``T_world_base``).

    ``mounts`` (child arm -> parent arm): a tree-structured robot. A mounted arm's ``base`` is
    ``T_parenttool_childbase`` (its base in the parent's tool frame), so its world pose follows the parent's
    joints (a torso carrying two arms); the parent's parameters exist once (``kincal.kinematics.tree``).
    """

    name: str
    arms: Mapping[str, ArmModel]
    meta: Mapping = field(default_factory=dict)
    mounts: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.arms:
            raise ModelError(f"robot '{self.name}': needs at least one arm")
        for key, arm in self.arms.items():
            if not isinstance(arm, ArmModel):
                raise ModelError(f"robot '{self.name}': arm '{key}' is {type(arm).__name__}, expected ArmModel")
        object.__setattr__(self, "arms", MappingProxyType(dict(self.arms)))
        object.__setattr__(self, "meta", MappingProxyType(dict(self.meta)))
        object.__setattr__(self, "mounts", MappingProxyType(checked_mounts(self.mounts, self.arms, self.name)))
        object.__setattr__(self, "arms", MappingProxyType(tree_gravity_filled(self.arms, self.mounts)))

    def __getitem__(self, arm: str) -> ArmModel:
        try:
            return self.arms[arm]
        except KeyError:
            raise ModelError(f"robot '{self.name}' has no arm '{arm}'; arms: {', '.join(self.arms)}") from None

    def lineage(self, arm: str) -> tuple[str, ...]:
        """The arms from the root to ``arm`` (``(arm,)`` for an arm mounted on nothing)."""
        self[arm]
        return lineage(self.mounts, arm)

    def replace_arm(self, arm: str, model: ArmModel) -> "Robot":
        self[arm]
        return Robot(self.name, {**self.arms, arm: model}, self.meta, self.mounts)

    def __eq__(self, other) -> bool:
        if not isinstance(other, Robot):
            return NotImplemented
        return self.name == other.name and dict(self.arms) == dict(other.arms) and \
            dict(self.mounts) == dict(other.mounts)

    __hash__ = None  # type: ignore[assignment]


def lineage(mounts: Mapping[str, str], arm: str) -> tuple[str, ...]:
    """The arms from the root to ``arm`` through ``mounts`` (child -> parent), which must be acyclic."""
    out = [arm]
    while out[-1] in mounts:
        out.append(mounts[out[-1]])
    return tuple(reversed(out))


def checked_mounts(mounts, arms: Mapping, robot: str) -> dict[str, str]:
    """``mounts`` (child -> parent) checked: both arms exist, no arm on itself, no cycle; one-line ModelError."""
    out = {}
    for child, parent in dict(mounts or {}).items():
        at = f"robot '{robot}': arm '{child}': mount"
        if child not in arms:
            raise ModelError(f"{at}: no such arm; arms: {', '.join(arms)}")
        if not isinstance(parent, str) or parent not in arms:
            raise ModelError(f"{at}: expected the name of another arm ({', '.join(arms)}), found {parent!r}")
        if parent == child:
            raise ModelError(f"{at}: an arm cannot be mounted on itself")
        out[str(child)] = parent
    for child in out:
        seen = [child]
        while seen[-1] in out:
            nxt = out[seen[-1]]
            if nxt in seen:
                cycle = " -> ".join(seen[seen.index(nxt):] + [nxt])
                raise ModelError(f"robot '{robot}': arm '{child}': mount: the mounts form a cycle ({cycle})")
            seen.append(nxt)
    _check_tree_gravity(out, arms, robot)
    return out


def _check_tree_gravity(mounts: Mapping[str, str], arms: Mapping, robot: str) -> None:
    """The arms of one tree that state a gravity vector state the same one (the robot's; one-line ModelError)."""
    seen: dict[str, tuple[str, np.ndarray]] = {}
    for a in arms:
        if arms[a].gravity is None:
            continue
        root = lineage(mounts, a)[0]
        if root in seen and not np.array_equal(seen[root][1], arms[a].gravity):
            raise ModelError(f"robot '{robot}': arm '{a}': gravity {list(arms[a].gravity)} disagrees with arm "
                             f"'{seen[root][0]}' ({list(seen[root][1])}) of the same tree; one gravity per robot")
        seen.setdefault(root, (a, arms[a].gravity))


def tree_gravity_filled(arms: Mapping, mounts: Mapping[str, str]) -> dict:
    """The arms, each arm of a tree that states gravity (on any of its arms) given that gravity: the weights of
    every arm of the tree then load the joints carrying them (``kincal.kinematics.branches``)."""
    g = {}
    for a, arm in arms.items():
        if arm.gravity is not None:
            g.setdefault(lineage(mounts, a)[0], arm.gravity)
    return {a: arm if arm.gravity is not None or lineage(mounts, a)[0] not in g
            else replace(arm, gravity=g[lineage(mounts, a)[0]]) for a, arm in arms.items()}
