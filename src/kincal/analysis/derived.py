"""Derived quantities a calibration engineer can read, with standard deviations: the geometry of consecutive
joint axes (common-normal length and angle; for nearly parallel axes their distance and two tilts) and the
tool pose, all at the nominal zero (every joint reading 0).

They are functions of the forward kinematics alone (the world axes at given readings are its derivatives), so
the arm-internal gauges of a full POE model (a joint offset against the later axes and home, tool against
home, base against the axes) leave them unchanged. The relative axis geometry and the tool pose in the frame
of the first two axes are also unchanged by a rigid motion of the world (an unknown tracker or plate); the
tool pose in the world frame is not, then. Lengths move with the scale where no measured length enters; the
tool pose moves with a tool frame the data do not tie down (markers at unknown offsets). Which quantity is
gauge invariant is read off the Jacobian: no unidentifiable direction moves it (``Derived.identifiable``).

The formula of each quantity (parallel or not, which axis anchors a parallel pair) is chosen on the nominal
model, so it is the same smooth function of every estimate. Jacobians are central differences through the
parameter retraction (a few dozen evaluations of one configuration), checked in tests/test_gauge.py.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from kincal.analysis.naming import block_of
from kincal.kinematics import REVOLUTE, chain
from kincal.kinematics.model import lineage
from kincal.lie import se3, so3
from kincal.params import COMPLIANCE, Layout, State, retract

PARALLEL_SIN = 1e-2  # consecutive nominal axes closer to parallel than this (sin of the angle) use the parallel form
INVARIANT_RTOL = 1e-4  # a quantity moved less than this (relative to its gradient) by a null direction is invariant
STEP = 1e-6  # central-difference step in natural units (m, rad)
# Gradient norm (per natural unit) below which no free coordinate moves a quantity (differences of round-off):
# it is not estimated (e.g. consecutive axis geometry when only offsets are free) and not reported.
UNMOVED = 1e-7


@dataclass(frozen=True)
class Derived:
    """One derived quantity: value and nominal (SI ``unit``), standard deviation (in the result's gauge), whether
    it is ``identifiable`` (gauge invariant: no unidentifiable direction moves it, so its value and standard
    deviation are the same in every gauge), and what it is in words."""

    name: str
    value: float
    nominal: float
    std: float
    unit: str
    identifiable: bool
    words: str


@dataclass(frozen=True)
class _Geometry:
    """An arm at the nominal zero: joint axes in the world (points closest to the origin, unit directions;
    points nan for prismatic joints), the tool pose, and the frame the arm is mounted in (a mounted arm's
    carrier's tool at its zero readings; the world for an arm mounted on nothing)."""

    points: np.ndarray  # (n, 3)
    dirs: np.ndarray  # (n, 3)
    tool: np.ndarray  # (4, 4) T_world_tool
    mount: np.ndarray  # (4, 4) T_world_mount


@dataclass(frozen=True)
class _Group:
    """Quantities computed together (one axis pair, the tool pose in one frame): names, units, words, and the
    function of an arm's geometry giving their values."""

    names: tuple[str, ...]
    units: tuple[str, ...]
    words: tuple[str, ...]
    fn: Callable[[_Geometry], np.ndarray]


def carriers(state: State, arm: str) -> tuple[str, ...]:
    """The arms carrying ``arm`` (root first; none for an arm mounted on nothing)."""
    return lineage(state.mounts, arm)[:-1]


def geometry(state: State, arm: str) -> _Geometry:
    """The world joint axes and the tool pose of ``arm`` at joint readings 0 (a mounted arm's carriers too)."""
    mount = np.eye(4)
    for c in carriers(state, arm):
        v = state.arms[c]
        mount = mount @ chain(v.screws, v.offsets, v.base, v.home, v.tool).tool
    a = state.arms[arm]
    kin = chain(a.screws, a.offsets, mount @ a.base, a.home, a.tool)
    S = np.einsum("kij,kj->ki", se3.adjoint(kin.prefixes[:-1]), a.screws)
    v, w = S[:, :3], S[:, 3:]
    rev = np.array([t == REVOLUTE for t in a.joint_types])
    nw = np.where(rev, np.linalg.norm(w, axis=1), 1.0)[:, None]
    nv = np.where(rev, 1.0, np.linalg.norm(v, axis=1))[:, None]
    dirs = np.where(rev[:, None], w / nw, v / nv)
    points = np.where(rev[:, None], np.cross(w, v) / nw**2, np.nan)
    return _Geometry(points, dirs, kin.tool, mount)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors (np.cross is slow on single vectors, and Jacobians evaluate many)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _closest_on(p1, u1, p2, u2) -> np.ndarray:
    """The point of line (p1, u1) closest to line (p2, u2) (not parallel)."""
    w0 = p1 - p2
    b, d, e = u1 @ u2, u1 @ w0, u2 @ w0
    return p1 + (b * e - d) / (1.0 - b * b) * u1


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.sqrt(x @ x)


def _skew_pair(prefix: str, words: str, j: int, k: int, revolute: bool) -> _Group:
    """Axes j, k not parallel: the signed common-normal length (revolute pairs) and the angle between them."""

    def fn(g):
        c = _cross(g.dirs[j], g.dirs[k])
        angle = np.arctan2(np.sqrt(c @ c), g.dirs[j] @ g.dirs[k])
        return np.array([(g.points[k] - g.points[j]) @ _unit(c), angle] if revolute else [angle])

    names, units = (f"{prefix}.distance", f"{prefix}.angle"), ("m", "rad")
    texts = (f"common-normal length between the axes of {words} (signed along the cross product of their "
             "directions)", f"angle between the axes of {words}")
    return _Group(names, units, texts, fn) if revolute else _Group(names[1:], units[1:], texts[1:], fn)


def _parallel_pair(prefix: str, words: str, j: int, k: int, anchor: int | None, sign: float) -> _Group:
    """Nearly parallel axes j, k: their distance measured at the point of axis j closest to the nearest axis not
    parallel to it (``anchor``; a common normal is undefined there), and the tilt of axis k in and out of their
    common plane (signed, so smooth through parallel)."""

    def fn(g):
        p1, u1 = g.points[j], g.dirs[j]
        if anchor is not None:
            p1 = _closest_on(p1, u1, g.points[anchor], g.dirs[anchor])
        u2 = sign * g.dirs[k]
        d = g.points[k] + ((p1 - g.points[k]) @ u2) * u2 - p1
        d = d - (d @ u1) * u1
        e1 = _unit(d)
        e2 = _cross(u1, e1)
        return np.array([np.sqrt(d @ d), np.arctan2(u2 @ e1, u2 @ u1), np.arctan2(u2 @ e2, u2 @ u1)])

    at = "" if anchor is None else f", at the point of the first axis closest to axis {anchor + 1}"
    return _Group((f"{prefix}.distance", f"{prefix}.tilt_in", f"{prefix}.tilt_out"), ("m", "rad", "rad"),
                  (f"distance between the (nearly parallel) axes of {words}{at}",
                   f"tilt of the second axis towards the first in their common plane, {words}",
                   f"tilt of the second axis out of their common plane, {words}"), fn)


def _pair_groups(arm: str, names, types, g0: _Geometry) -> list[_Group]:
    out = []
    for j in range(len(names) - 1):
        prefix, words = f"{arm}.{names[j]}-{names[j + 1]}", f"{names[j]} and {names[j + 1]} at the nominal zero"
        revolute = types[j] == REVOLUTE and types[j + 1] == REVOLUTE
        if np.linalg.norm(_cross(g0.dirs[j], g0.dirs[j + 1])) >= PARALLEL_SIN:
            out.append(_skew_pair(prefix, words, j, j + 1, revolute))
        elif revolute:
            out.append(_parallel_pair(prefix, words, j, j + 1, _anchor(g0, j, types),
                                      float(np.sign(g0.dirs[j] @ g0.dirs[j + 1]))))
    return out


def _anchor(g0: _Geometry, j: int, types) -> int | None:
    """The revolute axis nearest to j (by index, earlier first) not parallel to it, or None."""
    for k in sorted(range(len(types)), key=lambda k: (abs(k - j), k)):
        if k != j and types[k] == REVOLUTE and np.linalg.norm(_cross(g0.dirs[j], g0.dirs[k])) >= PARALLEL_SIN:
            return k
    return None


def _base_frame(g: _Geometry) -> np.ndarray:
    """The frame of the first two axes: origin on axis 1 at their common normal, z along axis 1, x along the
    common normal (axis 1 x axis 2)."""
    o = _closest_on(g.points[0], g.dirs[0], g.points[1], g.dirs[1])
    z = g.dirs[0]
    x = _unit(_cross(g.dirs[0], g.dirs[1]))
    return se3.make(np.stack([x, _cross(z, x), z], axis=1), o)


def _world_frame(g: _Geometry) -> np.ndarray:
    return np.eye(4)


def _mount_frame(g: _Geometry) -> np.ndarray:
    return g.mount


def _tool_groups(arm: str, names, types, g0: _Geometry, carrier: str | None = None) -> list[_Group]:
    """The tool pose at the nominal zero in the world frame (for an arm mounted on ``carrier``: through its
    carriers at their zero readings, and in the carrier's tool frame, ``mount``) and, when the first two axes are
    revolute and not parallel, in their frame: position, and rotation from the nominal tool orientation (about
    the frame's axes)."""
    frames = [("world", "the world frame" if carrier is None else
               "the world frame, its carriers at their zero readings", _world_frame)]
    if carrier is not None:
        frames.insert(0, ("mount", f"the tool frame of {carrier}, which carries the arm", _mount_frame))
    if len(names) > 1 and types[0] == REVOLUTE == types[1] and \
            np.linalg.norm(_cross(g0.dirs[0], g0.dirs[1])) >= PARALLEL_SIN:
        frames.insert(0, ("axes12", f"the frame of the axes of {names[0]} and {names[1]} (origin on the first at "
                                    "their common normal, z along it, x along the common normal)", _base_frame))
    out = []
    for key, where, F in frames:
        R0 = (se3.inverse(F(g0)) @ g0.tool)[:3, :3]

        def fn(g, F=F, R0=R0):
            T = se3.inverse(F(g)) @ g.tool
            return np.concatenate([T[:3, 3], so3.log(T[:3, :3] @ R0.T)])

        out.append(_Group(
            tuple(f"{arm}.tool_at_zero.{key}.{c}" for c in ("x", "y", "z", "rot_x", "rot_y", "rot_z")),
            ("m",) * 3 + ("rad",) * 3,
            tuple(f"tool position at the nominal zero, {c} in {where}" for c in "xyz")
            + tuple(f"tool rotation from its nominal orientation at the nominal zero, about {c} of {where}"
                    for c in "xyz"), fn))
    return out


def groups(nominal: State, arm: str) -> list[_Group]:
    """The derived quantities of ``arm``, their formulas chosen on the ``nominal`` state."""
    a, g0 = nominal.arms[arm], geometry(nominal, arm)
    return _pair_groups(arm, a.joint_names, a.joint_types, g0) + \
        _tool_groups(arm, a.joint_names, a.joint_types, g0, nominal.mounts.get(arm))


def names(arms_groups: dict) -> list[str]:
    """The quantities' names, in the order of ``evaluate``."""
    return [n for gs in arms_groups.values() for grp in gs for n in grp.names]


def evaluate(state: State, arms_groups: dict) -> np.ndarray:
    """The values of ``{arm: groups}`` at ``state``."""
    out = []
    for arm, gs in arms_groups.items():
        g = geometry(state, arm)
        out += [grp.fn(g) for grp in gs]
    return np.concatenate(out) if out else np.zeros(0)


def jacobian(state: State, layout: Layout, free: np.ndarray, arms_groups: dict, step: float = STEP) -> np.ndarray:
    """d values / d free local coordinates (m, p) by central differences through ``retract``; zero for the
    coordinates the geometry at zero does not depend on (experiment frames, arms other than these and their
    carriers, compliances: no load)."""
    G = np.zeros((len(names(arms_groups)), len(free)))
    moving = {*arms_groups, *(c for arm in arms_groups for c in carriers(state, arm))}
    for k, i in enumerate(free):
        b = block_of(layout, int(i))
        if b.arm not in moving or b.kind is COMPLIANCE:
            continue
        d = np.zeros(layout.size)
        d[i] = step
        G[:, k] = (evaluate(retract(state, layout, d), arms_groups)
                   - evaluate(retract(state, layout, -d), arms_groups)) / (2 * step)
    return G


def derived(state: State, nominal: State, layout: Layout, free: np.ndarray, covariance: np.ndarray,
            null: np.ndarray) -> tuple[Derived, ...]:
    """The derived quantities of every arm with free coordinates that the free coordinates move, standard
    deviations from ``covariance`` (free local coordinates, the result's gauge), invariance judged against the
    null basis ``null`` (p, k)."""
    arms = [b.arm for b in layout.blocks if b.arm is not None and layout.free[b.start: b.stop].any()]
    arms_groups = {arm: groups(nominal, arm) for arm in dict.fromkeys(arms)}
    if not arms_groups:
        return ()
    values, nominals = evaluate(state, arms_groups), evaluate(nominal, arms_groups)
    G = jacobian(state, layout, free, arms_groups)
    std = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", G, covariance, G), 0, None))
    size = np.linalg.norm(G, axis=1)
    moved = np.linalg.norm(G @ null, axis=1) if null.shape[1] else np.zeros(len(G))
    invariant = moved <= INVARIANT_RTOL * size
    flat = [(n, u, w) for gs in arms_groups.values() for grp in gs for n, u, w in zip(grp.names, grp.units, grp.words)]
    return tuple(Derived(n, float(v), float(v0), float(s), u, bool(ok), w)
                 for (n, u, w), v, v0, s, ok, g in zip(flat, values, nominals, std, invariant, size) if g > UNMOVED)
