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

from kincal.kinematics import REVOLUTE, chain
from kincal.lie import se3, so3
from kincal.params import Layout, State, retract

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
    points nan for prismatic joints) and the tool pose."""

    points: np.ndarray  # (n, 3)
    dirs: np.ndarray  # (n, 3)
    tool: np.ndarray  # (4, 4) T_world_tool


@dataclass(frozen=True)
class _Term:
    name: str
    unit: str
    words: str
    fn: Callable[[_Geometry], float]


def geometry(state: State, arm: str) -> _Geometry:
    """The world joint axes and the tool pose of ``arm`` at joint readings 0."""
    a = state.arms[arm]
    kin = chain(a.screws, a.offsets, a.base, a.home, a.tool)
    S = np.einsum("kij,kj->ki", se3.adjoint(kin.prefixes[:-1]), a.screws)
    v, w = S[:, :3], S[:, 3:]
    rev = np.array([t == REVOLUTE for t in a.joint_types])
    nw = np.where(rev, np.linalg.norm(w, axis=1), 1.0)[:, None]
    nv = np.where(rev, 1.0, np.linalg.norm(v, axis=1))[:, None]
    dirs = np.where(rev[:, None], w / nw, v / nv)
    points = np.where(rev[:, None], np.cross(w, v) / nw**2, np.nan)
    return _Geometry(points, dirs, kin.tool)


def _closest_on(p1, u1, p2, u2) -> np.ndarray:
    """The point of line (p1, u1) closest to line (p2, u2) (not parallel)."""
    w0 = p1 - p2
    b, d, e = u1 @ u2, u1 @ w0, u2 @ w0
    return p1 + (b * e - d) / (1.0 - b * b) * u1


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x)


def _skew_terms(prefix: str, words: str, j: int, k: int, revolute: bool) -> list[_Term]:
    def distance(g):
        return float((g.points[k] - g.points[j]) @ _unit(np.cross(g.dirs[j], g.dirs[k])))

    def angle(g):
        return float(np.arctan2(np.linalg.norm(np.cross(g.dirs[j], g.dirs[k])), g.dirs[j] @ g.dirs[k]))

    out = [_Term(f"{prefix}.angle", "rad", f"angle between the axes of {words}", angle)]
    if revolute:
        out.insert(0, _Term(f"{prefix}.distance", "m", f"common-normal length between the axes of {words} "
                                                        "(signed along the cross product of their directions)", distance))
    return out


def _parallel_terms(prefix: str, words: str, j: int, k: int, anchor: int | None, sign: float) -> list[_Term]:
    """Nearly parallel axes j, k: their distance measured at the point of axis j closest to the nearest axis not
    parallel to it (``anchor``; a common normal is undefined there), and the tilt of axis k in and out of their
    common plane (signed, so smooth through parallel)."""

    def frame(g):
        p1, u1 = g.points[j], g.dirs[j]
        if anchor is not None:
            p1 = _closest_on(p1, u1, g.points[anchor], g.dirs[anchor])
        u2 = sign * g.dirs[k]
        q2 = g.points[k] + ((p1 - g.points[k]) @ u2) * u2
        d = q2 - p1
        d = d - (d @ u1) * u1
        e1 = _unit(d)
        return d, u1, u2, e1, np.cross(u1, e1)

    def distance(g):
        return float(np.linalg.norm(frame(g)[0]))

    def tilt(which):
        def fn(g):
            _, u1, u2, e1, e2 = frame(g)
            return float(np.arctan2(u2 @ (e1 if which == 0 else e2), u2 @ u1))
        return fn

    at = "" if anchor is None else f", at the point of the first axis closest to axis {anchor + 1}"
    return [_Term(f"{prefix}.distance", "m", f"distance between the (nearly parallel) axes of {words}{at}", distance),
            _Term(f"{prefix}.tilt_in", "rad", f"tilt of the second axis towards the first in their common plane, {words}",
                  tilt(0)),
            _Term(f"{prefix}.tilt_out", "rad", f"tilt of the second axis out of their common plane, {words}", tilt(1))]


def _pair_terms(arm: str, names, types, g0: _Geometry) -> list[_Term]:
    n, out = len(names), []
    sines = [np.linalg.norm(np.cross(g0.dirs[j], g0.dirs[j + 1])) for j in range(n - 1)]
    for j in range(n - 1):
        prefix, words = f"{arm}.{names[j]}-{names[j + 1]}", f"{names[j]} and {names[j + 1]} at the nominal zero"
        revolute = types[j] == REVOLUTE and types[j + 1] == REVOLUTE
        if sines[j] >= PARALLEL_SIN:
            out += _skew_terms(prefix, words, j, j + 1, revolute)
        elif revolute:
            out += _parallel_terms(prefix, words, j, j + 1, _anchor(g0, j, types),
                                   float(np.sign(g0.dirs[j] @ g0.dirs[j + 1])))
    return out


def _anchor(g0: _Geometry, j: int, types) -> int | None:
    """The revolute axis nearest to j (by index, earlier first) not parallel to it, or None."""
    for k in sorted(range(len(types)), key=lambda k: (abs(k - j), k)):
        if k != j and types[k] == REVOLUTE and np.linalg.norm(np.cross(g0.dirs[j], g0.dirs[k])) >= PARALLEL_SIN:
            return k
    return None


def _base_frame(g: _Geometry) -> np.ndarray:
    """The frame of the first two axes: origin on axis 1 at their common normal, z along axis 1, x along the
    common normal (axis 1 x axis 2)."""
    o = _closest_on(g.points[0], g.dirs[0], g.points[1], g.dirs[1])
    z = g.dirs[0]
    x = _unit(np.cross(g.dirs[0], g.dirs[1]))
    return se3.make(np.stack([x, np.cross(z, x), z], axis=1), o)


def _tool_terms(arm: str, names, types, g0: _Geometry) -> list[_Term]:
    """The tool pose at the nominal zero in the world frame and, when the first two axes are revolute and not
    parallel, in their frame: position, and rotation from the nominal tool orientation (about the frame's axes)."""
    frames = [("world", "the world frame", lambda g: np.eye(4))]
    if len(names) > 1 and types[0] == REVOLUTE == types[1] and \
            np.linalg.norm(np.cross(g0.dirs[0], g0.dirs[1])) >= PARALLEL_SIN:
        frames.insert(0, ("axes12", f"the frame of the axes of {names[0]} and {names[1]} (origin on the first at "
                                    "their common normal, z along it, x along the common normal)", _base_frame))
    out = []
    for key, where, F in frames:
        R0 = (se3.inverse(F(g0)) @ g0.tool)[:3, :3]

        def pose(g, F=F):
            return se3.inverse(F(g)) @ g.tool

        for i, c in enumerate("xyz"):
            out.append(_Term(f"{arm}.tool_at_zero.{key}.{c}", "m", f"tool position at the nominal zero, {c} in {where}",
                             lambda g, i=i, pose=pose: float(pose(g)[i, 3])))
        for i, c in enumerate("xyz"):
            out.append(_Term(f"{arm}.tool_at_zero.{key}.rot_{c}", "rad",
                             f"tool rotation from its nominal orientation at the nominal zero, about {c} of {where}",
                             lambda g, i=i, pose=pose, R0=R0: float(so3.log(pose(g)[:3, :3] @ R0.T)[i])))
    return out


def terms(nominal: State, arm: str) -> list[_Term]:
    """The derived quantities of ``arm``, their formulas chosen on the ``nominal`` state."""
    a, g0 = nominal.arms[arm], geometry(nominal, arm)
    return _pair_terms(arm, a.joint_names, a.joint_types, g0) + _tool_terms(arm, a.joint_names, a.joint_types, g0)


def evaluate(state: State, arms_terms: dict) -> np.ndarray:
    """The values of ``{arm: terms}`` at ``state``."""
    out = []
    for arm, ts in arms_terms.items():
        g = geometry(state, arm)
        out += [t.fn(g) for t in ts]
    return np.array(out)


def jacobian(state: State, layout: Layout, free: np.ndarray, arms_terms: dict, step: float = STEP) -> np.ndarray:
    """d values / d free local coordinates (m, p) by central differences through ``retract``."""
    cols = []
    for i in free:
        d = np.zeros(layout.size)
        d[i] = step
        cols.append((evaluate(retract(state, layout, d), arms_terms)
                     - evaluate(retract(state, layout, -d), arms_terms)) / (2 * step))
    return np.stack(cols, axis=1) if cols else np.zeros((0, 0))


def derived(state: State, nominal: State, layout: Layout, free: np.ndarray, covariance: np.ndarray,
            null: np.ndarray) -> tuple[Derived, ...]:
    """The derived quantities of every arm with free coordinates that the free coordinates move, standard
    deviations from ``covariance`` (free local coordinates, the result's gauge), invariance judged against the
    null basis ``null`` (p, k)."""
    arms = [b.arm for b in layout.blocks if b.arm is not None and layout.free[b.start: b.stop].any()]
    arms_terms = {arm: terms(nominal, arm) for arm in dict.fromkeys(arms)}
    if not arms_terms:
        return ()
    values, nominals = evaluate(state, arms_terms), evaluate(nominal, arms_terms)
    G = jacobian(state, layout, free, arms_terms)
    std = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", G, covariance, G), 0, None))
    size = np.linalg.norm(G, axis=1)
    moved = np.linalg.norm(G @ null, axis=1) if null.shape[1] else np.zeros(len(G))
    invariant = moved <= INVARIANT_RTOL * size
    flat = [t for ts in arms_terms.values() for t in ts]
    return tuple(Derived(t.name, float(v), float(v0), float(s), t.unit, bool(ok), t.words)
                 for t, v, v0, s, ok, g in zip(flat, values, nominals, std, invariant, size) if g > UNMOVED)
