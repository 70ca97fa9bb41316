"""Calibration parameters: values, named local coordinates, free/fixed/prior status, retraction.

Values live in a ``State`` (raw arrays, twists may be slightly off the joint-screw manifold during an
inner solve); what the solver moves are *local coordinates* around a linearization state:

==============  ==========================================  =====================================================
block           local coordinates (stable names)            retraction ``retract(state, delta)``
==============  ==========================================  =====================================================
joint offsets   ``right.j3.offset``                         ``o + d``
joint twists    ``right.j3.xi.shift_1, shift_2, tilt_1,     ``Ad(exp(G d)) xi``: a rigid motion of the joint axis
                tilt_2`` (prismatic: ``tilt_1, tilt_2``)    (exact: stays unit, zero pitch) with first-order basis
                                                            ``tangent_basis(xi)`` (4 per revolute joint, 2 per
                                                            prismatic); re-linearized between outer iterations.
                                                            Reports and priors use the chart ``B^+ (xi - xi0)``
home/base/tool  ``right.home.v_x .. w_z``                   ``exp(d) T`` (left increment, in the frame T maps to)
pose nuisance   ``fixture.*, plate.*, clamp.*, tracker.*``  ``exp(d) T``
joint compliance ``right.j3.compliance`` (rad/Nm; m/N)     ``c + d`` (meaningful only with loads: ``wrench_tool``)
points          ``markers.m1.x``, ``socket.x``              ``p + d``
plane           ``plane.n_1, plane.n_2, plane.d``           ``n = normalize(n0 + U d_n)``, ``d + d_d``
==============  ==========================================  =====================================================

Every coordinate is free, fixed, or free with a Gaussian prior on its displacement from the nominal state.
Selections are names or globs (``right.j*.offset``); a glob that matches a block name selects the whole block
(``clamp``, ``right.home``), and a glob matching a joint's 6 twist coordinates (``left.j2.xi.v_x``) selects that
joint's twist, which is always estimated as a whole in its minimal parametrization.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

import numpy as np

from kincal.errors import ModelError
from kincal.kinematics import PRISMATIC, REVOLUTE, ArmModel, Robot, conform_twists, tangent_basis, tangent_generators
from kincal.kinematics.identification import TWIST_COORDS
from kincal.lie import se3, so3

LEVELS = ("offsets", "kinematic", "elastic")
POSE_COORDS = TWIST_COORDS
ARM_POSES = ("home", "base", "tool")
COMPLIANCE_UNITS = {REVOLUTE: "rad/Nm", PRISMATIC: "m/N"}


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
    compliance: np.ndarray | None = None  # (n,) rad/(N m) or m/N; None: zeros

    @property
    def dof(self) -> int:
        return self.screws.shape[0]

    @property
    def joint_compliance(self) -> np.ndarray:
        """(n,) compliances (zeros when none are set)."""
        return np.zeros(self.dof) if self.compliance is None else self.compliance

    @property
    def basis(self) -> np.ndarray:
        """Block-diagonal (6n, t) map from all tangent coordinates to the stacked twist coordinates."""
        n = self.dof
        t = sum(b.shape[1] for b in self.bases)
        out = np.zeros((6 * n, t))
        c = 0
        for i, b in enumerate(self.bases):
            out[6 * i: 6 * i + 6, c: c + b.shape[1]] = b
            c += b.shape[1]
        return out

    @staticmethod
    def from_model(model: ArmModel) -> "ArmValues":
        return ArmValues(
            np.array(model.screws), np.array(model.offsets), np.array(model.base), np.array(model.home),
            np.array(model.tool), _bases(model.screws, model.joint_types), model.joint_names, model.joint_types,
            _generators(model.screws, model.joint_types), np.array(model.compliance),
        )


def _bases(screws, types) -> tuple:
    return tuple(tangent_basis(s, t) for s, t in zip(screws, types))


def _generators(screws, types) -> tuple:
    return tuple(tangent_generators(s, t) for s, t in zip(screws, types))


def _retract_twists(a: "ArmValues", d: np.ndarray) -> "ArmValues":
    """Exact retraction of the joint screws: xi_j = Ad(exp(G_j d_j)) xi_j, which stays a valid joint screw,
    with the basis at d: d xi_j = -ad(xi_j) J_l(G_j d_j) G_j dd_j."""
    screws, bases, gens, c = a.screws.copy(), [], [], 0
    for j, G in enumerate(a.generators):
        g = G @ d[c: c + G.shape[1]]
        c += G.shape[1]
        screws[j] = se3.adjoint(se3.exp(g)) @ a.screws[j]
        gens.append(se3.left_jacobian(g) @ G)  # retracting again from here keeps basis == -ad(xi) G
        bases.append(-se3.ad(screws[j]) @ gens[-1])
    return replace(a, screws=screws, bases=tuple(bases), generators=tuple(gens))


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
    """All parameter values: arms by name, and experiment nuisances (4x4 poses, point arrays, planes) by name."""

    arms: Mapping[str, ArmValues]
    extras: Mapping[str, object] = field(default_factory=dict)

    @staticmethod
    def from_robot(robot: Robot, extras: Mapping[str, object] | None = None) -> "State":
        return State({k: ArmValues.from_model(m) for k, m in robot.arms.items()}, dict(extras or {}))

    def to_robot(self, robot: Robot) -> Robot:
        """The calibrated Robot: ``robot`` with this state's (conformed) values."""
        arms = {}
        for key, model in robot.arms.items():
            if key not in self.arms:  # an arm no experiment involves stays as it was
                arms[key] = model
                continue
            a = self.arms[key]
            screws = conform_twists(a.screws, a.joint_types)
            arms[key] = model.replace(  # a compliance estimated below 0 (noise) is held at 0 in the model
                screws=screws, offsets=a.offsets, base=a.base, home=a.home, tool=a.tool,
                compliance=np.maximum(a.joint_compliance, 0.0),
            )
        return Robot(robot.name, arms, dict(robot.meta))


@dataclass(frozen=True)
class Prior:
    """Gaussian prior on a coordinate's displacement from nominal: ``(disp - mean) / sigma``."""

    sigma: float
    mean: float = 0.0


@dataclass(frozen=True)
class Block:
    """A contiguous run of coordinates: ``kind`` in offsets, twists, pose, points, plane."""

    name: str
    kind: str
    start: int
    stop: int
    arm: str | None = None  # arm blocks only
    part: str | None = None  # offsets, twists, home, base, tool (arm blocks)


@dataclass(frozen=True)
class Layout:
    """Every coordinate's name, block and status. ``free``, ``prior_mean``, ``prior_sigma`` are (p,) arrays."""

    names: tuple[str, ...]
    units: tuple[str, ...]  # "rad" or "m" per coordinate
    blocks: tuple[Block, ...]
    free: np.ndarray
    prior_mean: np.ndarray
    prior_sigma: np.ndarray  # inf where no prior
    twist_joint: Mapping[str, tuple[int, ...]]  # "right.j3" -> coordinate indices of its tangent coordinates

    @property
    def size(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ModelError(f"no parameter named {name!r}") from None

    def block(self, name: str) -> Block:
        for b in self.blocks:
            if b.name == name:
                return b
        raise ModelError(f"no parameter block named {name!r}")

    @property
    def free_names(self) -> list[str]:
        return [n for n, f in zip(self.names, self.free) if f]


def _arm_blocks(arm: str, a: ArmValues):
    """(block name, kind, part, coordinate names, units) for one arm."""
    revolute = [t == REVOLUTE for t in a.joint_types]
    yield (f"{arm}.offsets", "offsets", "offsets", [f"{arm}.{j}.offset" for j in a.joint_names],
           ["rad" if r else "m" for r in revolute])
    names, units = [], []
    for j, r in zip(a.joint_names, revolute):
        locs = ("shift_1", "shift_2", "tilt_1", "tilt_2") if r else ("tilt_1", "tilt_2")
        names += [f"{arm}.{j}.xi.{c}" for c in locs]
        units += ["m" if c.startswith("shift") else "rad" for c in locs]
    yield f"{arm}.twists", "twists", "twists", names, units
    for part in ARM_POSES:
        yield (f"{arm}.{part}", "pose", part, [f"{arm}.{part}.{c}" for c in POSE_COORDS], _pose_units())
    yield (f"{arm}.compliance", "compliance", "compliance", [f"{arm}.{j}.compliance" for j in a.joint_names],
           [COMPLIANCE_UNITS[t] for t in a.joint_types])


def _pose_units():
    return ["m", "m", "m", "rad", "rad", "rad"]


def extra_coordinates(name: str, value) -> tuple[str, list[str], list[str]]:
    """(kind, coordinate names, units) of a nuisance block from its value."""
    if isinstance(value, Plane):
        return "plane", [f"{name}.n_1", f"{name}.n_2", f"{name}.d"], ["rad", "rad", "m"]
    value = np.asarray(value)
    if value.shape == (4, 4):
        return "pose", [f"{name}.{c}" for c in POSE_COORDS], _pose_units()
    if value.shape == (3,):
        return "points", [f"{name}.{c}" for c in "xyz"], ["m"] * 3
    if value.ndim == 2 and value.shape[1] == 3:
        return "points", [f"{name}.m{i + 1}.{c}" for i in range(value.shape[0]) for c in "xyz"], ["m"] * value.size
    raise ModelError(f"parameter block {name!r}: cannot parametrize a value of shape {value.shape}")


def level_patterns(level: str, arms: Sequence[str]) -> list[str]:
    """The patterns a one-word level stands for."""
    if level == "offsets":
        return [f"{a}.*.offset" for a in arms]
    if level == "kinematic":
        return [p for a in arms for p in (f"{a}.*.offset", f"{a}.twists", f"{a}.home")]
    if level == "elastic":
        return [f"{a}.compliance" for a in arms]
    raise ModelError(f"unknown level {level!r}; levels: {', '.join(LEVELS)} (or a list of names/globs)")


def build_layout(
    state: State,
    free: str | Sequence[str] = "offsets",
    *,
    fixed: Sequence[str] = (),
    priors: Mapping[str, Prior] | None = None,
    free_extras: Sequence[str] | None = None,
    arms: Sequence[str] | None = None,
) -> Layout:
    """Coordinates of every arm in ``arms`` (default: all) and every extra in the state.

    ``free``: a level word or names/globs. Extras listed in ``free_extras`` (default: all extras, i.e. the
    unknowns of the experiments) are free too. ``fixed`` globs are removed afterwards. A coordinate with a
    prior is free. Every pattern must match at least one coordinate.
    """
    arms = list(state.arms) if arms is None else list(arms)
    names: list[str] = []
    units: list[str] = []
    blocks: list[Block] = []
    twist_joint: dict[str, tuple[int, ...]] = {}
    for arm in arms:
        a = state.arms[arm]
        for bname, kind, part, cn, cu in _arm_blocks(arm, a):
            blocks.append(Block(bname, kind, len(names), len(names) + len(cn), arm, part))
            if kind == "twists":
                for j in a.joint_names:
                    twist_joint[f"{arm}.{j}"] = tuple(
                        len(names) + k for k, c in enumerate(cn) if c.startswith(f"{arm}.{j}.xi.")
                    )
            names += cn
            units += cu
    for ename, value in state.extras.items():
        kind, cn, cu = extra_coordinates(ename, value)
        blocks.append(Block(ename, kind, len(names), len(names) + len(cn)))
        names += cn
        units += cu

    p = len(names)
    if isinstance(free, str) and free not in LEVELS:
        level_patterns(free, arms)  # raises: a bare string must be a level word
    items = [free] if isinstance(free, str) else list(free)
    patterns = [p for it in items for p in (level_patterns(it, arms) if it in LEVELS else [it])]
    mask = np.zeros(p, bool)
    for pat in patterns:
        hit = _match(pat, names, blocks, twist_joint)
        if not hit.any():
            raise ModelError(f"free parameter pattern {pat!r} matches no parameter (e.g. {', '.join(names[:3])}, ...)")
        mask |= hit
    extras_free = list(state.extras) if free_extras is None else list(free_extras)
    for ename in extras_free:
        b = next(b for b in blocks if b.name == ename)
        mask[b.start: b.stop] = True
    for pat in fixed:
        hit = _match(pat, names, blocks, twist_joint)
        if not hit.any():
            raise ModelError(f"fixed parameter pattern {pat!r} matches no parameter")
        mask &= ~hit
    mean = np.zeros(p)
    sigma = np.full(p, np.inf)
    for pat, prior in (priors or {}).items():
        hit = _match(pat, names, blocks, twist_joint)
        if not hit.any():
            raise ModelError(f"prior pattern {pat!r} matches no parameter")
        if not (prior.sigma > 0 and np.isfinite(prior.sigma)):
            raise ModelError(f"prior {pat!r}: sigma must be positive and finite, got {prior.sigma}")
        mean[hit], sigma[hit] = prior.mean, prior.sigma
        mask |= hit
    return Layout(tuple(names), tuple(units), tuple(blocks), mask, mean, sigma, twist_joint)


def _match(pattern: str, names, blocks, twist_joint) -> np.ndarray:
    hit = np.array([fnmatch.fnmatchcase(n, pattern) for n in names], bool)
    for b in blocks:
        if fnmatch.fnmatchcase(b.name, pattern):
            hit[b.start: b.stop] = True
    for joint, idx in twist_joint.items():
        aliases = [f"{joint}.xi"] + [f"{joint}.xi.{c}" for c in TWIST_COORDS]
        if any(fnmatch.fnmatchcase(a, pattern) for a in aliases):
            hit[list(idx)] = True
    return hit


def retract(state: State, layout: Layout, delta: np.ndarray) -> State:
    """Values at local coordinates ``delta`` (p,) around ``state`` (tangent bases kept: see ``recentre``)."""
    arms = dict(state.arms)
    extras = dict(state.extras)
    for b in layout.blocks:
        d = delta[b.start: b.stop]
        if not np.any(d):
            continue
        if b.arm is not None:
            a = arms[b.arm]
            if b.part == "offsets":
                arms[b.arm] = replace(a, offsets=a.offsets + d)
            elif b.part == "twists":
                arms[b.arm] = _retract_twists(a, d)
            elif b.part == "compliance":
                arms[b.arm] = replace(a, compliance=a.joint_compliance + d)
            else:
                arms[b.arm] = replace(a, **{b.part: se3.exp(d) @ getattr(a, b.part)})
        elif b.kind == "pose":
            extras[b.name] = se3.exp(d) @ extras[b.name]
        elif b.kind == "points":
            extras[b.name] = extras[b.name] + d.reshape(np.shape(extras[b.name]))
        elif b.kind == "plane":
            pl = extras[b.name]
            extras[b.name] = replace(pl, normal=pl.normal + pl.U @ d[:2], d=pl.d + d[2])
    return State(arms, extras)


def recentre(state: State) -> State:
    """Conform twists, renormalize planes, and recompute tangent bases: the next linearization point."""
    arms = {}
    for k, a in state.arms.items():
        screws = conform_twists(a.screws, a.joint_types)  # removes round-off only: the retraction is exact
        arms[k] = replace(a, screws=screws, bases=_bases(screws, a.joint_types),
                          generators=_generators(screws, a.joint_types))
    extras = {k: (Plane.from_array(v.as_array()) if isinstance(v, Plane) else v) for k, v in state.extras.items()}
    return State(arms, extras)


def pose_retraction_jacobians(layout: Layout, delta: np.ndarray) -> dict[str, np.ndarray]:
    """For pose blocks: ``J_l(d)`` mapping d(delta) to the left increment at ``exp(d) T`` (exact, not first order)."""
    return {b.name: se3.left_jacobian(delta[b.start: b.stop]) for b in layout.blocks
            if b.kind == "pose" and np.any(delta[b.start: b.stop])}


def displacement(state: State, nominal: State, layout: Layout) -> tuple[np.ndarray, np.ndarray]:
    """Local displacement of ``state`` from ``nominal`` (p,) and its derivative w.r.t. ``state``'s own local
    coordinates (diagonal blocks, returned as a dense (p, p) matrix). Used for priors and reports."""
    p = layout.size
    disp = np.zeros(p)
    D = np.zeros((p, p))
    for b in layout.blocks:
        s = slice(b.start, b.stop)
        if b.arm is not None:
            a, a0 = state.arms[b.arm], nominal.arms[b.arm]
            if b.part == "offsets":
                disp[s], D[s, s] = a.offsets - a0.offsets, np.eye(b.stop - b.start)
            elif b.part == "compliance":
                disp[s], D[s, s] = a.joint_compliance - a0.joint_compliance, np.eye(b.stop - b.start)
            elif b.part == "twists":
                B0p = np.linalg.pinv(a0.basis)
                disp[s] = B0p @ (a.screws - a0.screws).ravel()
                D[s, s] = B0p @ a.basis
            else:
                disp[s], D[s, s] = _pose_disp(getattr(a, b.part), getattr(a0, b.part))
        elif b.kind == "pose":
            disp[s], D[s, s] = _pose_disp(state.extras[b.name], nominal.extras[b.name])
        elif b.kind == "points":
            disp[s] = (np.asarray(state.extras[b.name]) - np.asarray(nominal.extras[b.name])).ravel()
            D[s, s] = np.eye(b.stop - b.start)
        elif b.kind == "plane":
            pl, pl0 = state.extras[b.name], nominal.extras[b.name]
            n, d = pl.unit()
            m = np.linalg.norm(pl.normal)
            disp[s] = np.append(pl0.U.T @ (n - pl0.normal), d - pl0.d)
            D[b.start: b.start + 2, b.start: b.start + 2] = pl0.U.T @ ((np.eye(3) - np.outer(n, n)) / m) @ pl.U
            D[b.start + 2, b.start + 2] = 1.0
    return disp, D


def _pose_disp(T, T0):
    x = se3.log(T @ se3.inverse(T0))
    return x, se3.left_jacobian_inv(x)


def scale_direction(state: State, layout: Layout) -> np.ndarray:
    """Local direction (p,) that scales every length (translations, twist moments, points, plane offsets)."""
    s = np.zeros(layout.size)
    for b in layout.blocks:
        sl = slice(b.start, b.stop)
        if b.arm is not None:
            a = state.arms[b.arm]
            if b.part == "offsets":
                s[sl] = np.where(np.array(a.joint_types) == PRISMATIC, a.offsets, 0.0)
            elif b.part == "compliance":  # same deflection under a pure force: torques scale with length
                s[sl] = np.where(np.array(a.joint_types) == PRISMATIC, a.joint_compliance, -a.joint_compliance)
            elif b.part == "twists":
                v = np.zeros_like(a.screws)
                rev = np.array(a.joint_types) == REVOLUTE
                v[rev, :3] = a.screws[rev, :3]
                s[sl] = np.linalg.pinv(a.basis) @ v.ravel()
            else:
                s[sl] = se3.join(getattr(a, b.part)[:3, 3], np.zeros(3))
        elif b.kind == "pose":
            s[sl] = se3.join(state.extras[b.name][:3, 3], np.zeros(3))
        elif b.kind == "points":
            s[sl] = np.asarray(state.extras[b.name]).ravel()
        elif b.kind == "plane":
            s[b.stop - 1] = state.extras[b.name].d
    return s


def twist_coordinates(state: State, layout: Layout, cov: np.ndarray | None = None):
    """Derived 6 twist coordinates per joint: (names, values, covariance or None), propagated through the bases."""
    names, values, rows = [], [], []
    for b in layout.blocks:
        if b.part != "twists":
            continue
        a = state.arms[b.arm]
        for j, name in enumerate(a.joint_names):
            names += [f"{b.arm}.{name}.xi.{c}" for c in TWIST_COORDS]
            values.append(a.screws[j])
        rows.append((b, a.basis))
    if cov is None:
        return names, np.concatenate(values) if values else np.zeros(0), None
    Bfull = np.zeros((len(names), layout.size))
    r = 0
    for b, B in rows:
        Bfull[r: r + B.shape[0], b.start: b.stop] = B
        r += B.shape[0]
    return names, np.concatenate(values), Bfull @ cov @ Bfull.T

