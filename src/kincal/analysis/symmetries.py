"""Exact symmetries of the calibration cost that residuals left can make look determined: the scale of the
robot when no measured length enters, rotations about an arm's first joint axis that carry its world-side
frames along, and every exact gauge of the noise-free problem at the current estimate (``consistent_nulls``:
e.g. turning a last joint together with a clamp's fixture). Each is confirmed structurally before it is held."""

from __future__ import annotations

import hashlib
import math
import weakref
from collections import OrderedDict
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np

from kincal._memo import remember
from kincal.analysis.columns import clear_plans, scatter_columns
from kincal.analysis.covariance import right_svd
from kincal.analysis.linalg import lstsq, norm, norms, svd
from kincal.analysis.linearization import Linearization, unit_columns
from kincal.analysis.naming import clear_block_cache
from kincal.kinematics import REVOLUTE
from kincal.kinematics.model import lineage
from kincal.lie import se3
from kincal.params import Layout, scale_direction
from kincal.schema import WORLD


@dataclass(frozen=True, eq=False)
class Structure:
    """What the symmetry tests read of one problem's structure alone, worked out once per solve (``iterate``
    makes one at its first linearization) instead of at every linearization: the free coordinates' names,
    whether a length is free, the candidate rotations of ``rotation_nulls`` and the start of ``structure_key``'s
    digest. A solve never changes its layout, experiments or free coordinates, and its steps change a state's
    values only, never its arms, mounts or joint types: so these answers hold at every linearization of the
    solve, which ``fits`` checks by identity (the same objects, not equal copies)."""

    layout: Layout
    experiments: tuple
    free: np.ndarray
    rtol: float
    names: tuple[str, ...]
    free_length: bool
    rotations: tuple  # ``_rotation_candidates``
    key_start: object  # ``structure_key``'s digest so far (copied, then completed per linearization)
    # what ``identify`` derives at every linearization from inputs fixed for the solve (the held gauges), by
    # those inputs' values: ``identifiability._held``
    derived: dict = field(default_factory=dict, repr=False)

    @classmethod
    def of(cls, lin: Linearization, layout: Layout, experiments: Sequence, rtol: float) -> "Structure":
        return cls(layout, tuple(experiments), lin.free, rtol,
                   tuple(map(layout.names.__getitem__, lin.free.tolist())), bool(layout.lengths[lin.free].any()),
                   tuple(_rotation_candidates(lin.state, layout, experiments, lin.free)),
                   _key_start(layout, lin.free, rtol))

    def fits(self, lin: Linearization, layout: Layout, experiments: Sequence, rtol: float) -> bool:
        """Whether ``lin`` is a linearization of this structure."""
        return (lin.free is self.free and layout is self.layout and rtol == self.rtol
                and len(experiments) == len(self.experiments)
                and all(a is b for a, b in zip(experiments, self.experiments)))


def scale_null(lin: Linearization, layout: Layout, structure: Structure | None = None,
               solve: Callable[[np.ndarray, np.ndarray], np.ndarray] = lstsq) -> np.ndarray | None:
    """The free direction equivalent to scaling every length, if the data cannot see scale; else None.

    Scale is unidentifiable when (1) no measured length enters the residuals: scaling every length, fixed ones
    included, by ``1 + e`` scales the residual's length part by ``1 + e`` (``J_all s_all = r_len``; zero on
    noise-free data at the truth, but with residuals left the data would prefer to shrink the robot, which
    is no information about its size), and (2) the fixed length coordinates add no rank to the free ones
    (e.g. a fixed base is absorbed by free twists and home). The direction is then ``s_free + u`` with
    ``J u = J_fixed s_fixed`` (free parameters standing in for the fixed lengths). Everything is read off the
    linearization's triangular factor. ``solve(Rf, b)``: a solution u of ``Rf u = b`` (``lstsq``: numpy's
    minimum norm, whose cut at eps keeps null singular values near 1e-13, so round-off adds null directions to u;
    ``identifiability.analyse`` passes one cut at the rank of its own spectrum of ``Rf``).
    """
    p = lin.p
    if not (structure.free_length if structure is not None else layout.lengths[lin.free].any()):
        return None  # no free length, nothing to scale
    gap, tolerance, s, colnorm = _scale_gap(lin, layout, structure)
    if gap > tolerance:
        return None
    fixed, Ra = lin.fixed, lin.Rall
    lengths = np.flatnonzero(layout.lengths[fixed] & (colnorm[p:] > 0))
    if len(lengths):
        # the part of a fixed length's column outside the free columns' range sits below row p of R
        outside = norms(Ra[p:, p + lengths], 0) / colnorm[p + lengths]
        if outside.max() > 1e-6:
            return None
    u = solve(lin.Rf, Ra[:p, p:] @ s[p:])
    d = s[:p] + u
    return d if norm(d) > 0 else None


# Data that see the robot's scale by this factor over the scale test's tolerance at a solve's first
# linearization are not tested again at its later ones (``scale_visible``).
SCALE_VISIBLE_MARGIN = 1e4


def _scale_gap(lin: Linearization, layout: Layout, structure: Structure | None = None):
    """The scale test's terms: (|J_all s_all - r_len|, the tolerance it is compared with, s, R's column norms),
    all whitened, read off the linearization's triangular factor. ``structure``: the solve's, which keeps the
    terms of its last linearization (``scale_null`` and ``scale_visible`` both ask at a solve's first)."""
    if not lin.every:
        raise AssertionError("the scale test needs a linearization with every column")
    last = structure.derived.get("scale gap") if structure is not None else None
    if last is not None and last[0]() is lin and last[1] is layout:
        return last[2]
    terms = _scale_terms(lin, layout)
    if structure is not None:  # the linearization held weakly: a solve's Structure outlives each of them
        structure.derived["scale gap"] = (weakref.ref(lin), layout, terms)
    return terms


def _scale_terms(lin: Linearization, layout: Layout):
    Ra = lin.Rall  # (q, p + len(fixed)): free first
    s_all = scale_direction(lin.state, layout) if lin.scale is None else lin.scale
    s = np.concatenate([s_all[lin.free], s_all[lin.fixed]])
    colnorm = norms(Ra, 0)
    return norm(Ra @ s - lin.Rlen), 1e-6 * (np.add.reduce(colnorm * np.abs(s)) + norm(lin.Rlen)), s, colnorm


def scale_visible(lin: Linearization, layout: Layout, structure: Structure | None = None) -> bool:
    """Whether the data see the robot's scale by a wide margin at ``lin`` (a linearization with every column):
    the scale test's gap is ``SCALE_VISIBLE_MARGIN`` times its tolerance. A solve then skips the test's fixed
    columns at its later linearizations. The gap is what a measured length adds (markers, poses, distances:
    ``W y_measured``, the same at every state) or the pull of a known length (smooth in the state); the
    tolerance is 1e-6 of the whitened columns' size. Closing a margin of 1e4 would take a change of the robot's
    size by that factor between linearizations of one solve, which is no calibration. ``structure``: the
    solve's (the test's terms of ``scale_null`` at ``lin``)."""
    if not layout.lengths[lin.free].any():
        return False
    gap, tolerance, _, _ = _scale_gap(lin, layout, structure)
    return bool(gap > SCALE_VISIBLE_MARGIN * tolerance)


def rotation_nulls(lin: Linearization, layout: Layout, experiments: Sequence,
                   structure: Structure | None = None) -> list[np.ndarray]:
    """Rotations about an arm's first joint axis that carry every world-side frame of its experiments along
    (``j1.offset + 1`` with the frames turned by the axis screw): exact symmetries of the cost wherever those
    frames are free. Residuals written in a frame that turns along are unchanged (clamp, plate, tracker); a
    socket's world-frame vector ``r`` turns, ``J g = w x r``, which residuals left would mistake for
    information. Returned (natural units, free coordinates) where the linearization confirms the symmetry:
    ``J g`` equals the turned residuals. ``structure``: the candidates remembered for the solve."""
    if structure is None:
        candidates = _rotation_candidates(lin.state, layout, experiments, lin.free)
    else:
        candidates = structure.rotations
    out = []
    for arm, i1, frames, outside, turns in candidates:
        a = lin.state.arms[arm]
        xi = se3.remembered(se3.adjoint, a.base) @ a.screws[0]  # joint 1's screw in world coordinates
        g = np.zeros(layout.size)
        g[i1] = 1.0
        for name, b in frames:
            g[b.slice] = b.kind.world_motion(lin.state.extras[name], xi)
        if len(outside) and (g[outside] != 0).any():
            continue
        gf = g[lin.free]
        Jg = lin.J @ gf
        size = np.add.reduce(lin.colnorm * np.abs(gf))  # J's column norms (R is J's triangular factor)
        if turns:
            t = _turned_residuals(lin, experiments, arm, se3.split(xi)[1])
            confirmed = norm(Jg - t) <= 1e-6 * (size + norm(t))
        else:  # no residual turns: the target is zero (``Jg - 0`` is ``Jg``, ``size + 0`` is ``size``)
            confirmed = norm(Jg) <= 1e-6 * size
        if confirmed:
            out.append(gf)
    return out


def _rotation_candidates(state, layout: Layout, experiments: Sequence, free_idx: np.ndarray) -> list:
    """The arms whose first-joint rotation ``rotation_nulls`` tests, from the structure alone: (arm, index of
    its joint 1 offset, its experiments' world-side frames as (name, block), the coordinates the rotation moves
    that are not free (layout indices), whether a residual turns with it: a world-frame vector of an experiment
    it carries, ``_turned_residuals``). Not one mounted on
    another arm (its first axis moves with the carrying arm: the root's turns the world), nor one whose
    experiments have another arm in the loop (which does not turn along), nor one whose joint 1 is fixed or
    prismatic, nor one with a known world-side frame (it anchors the rotation)."""
    free = np.zeros(layout.size, bool)
    free[free_idx] = True
    out = []
    for arm, a in state.arms.items():
        if arm in state.mounts:
            continue
        exps = [e for e in experiments if _carries(state, arm, e)]
        if not exps or any(len(e.arms) > 1 for e in exps):
            continue
        i1 = layout.index(f"{arm}.{a.joint_names[0]}.offset")
        if not free[i1] or a.joint_types[0] != REVOLUTE:
            continue
        frames = _world_frames(layout, exps)
        if frames is not None:
            turns = any(e.WORLD_VECTOR and _carries(state, arm, e) for e in experiments)
            out.append((arm, i1, frames, _outside(frames, free), turns))
    return out


def _outside(frames, free: np.ndarray) -> np.ndarray:
    """The layout indices of the frames' coordinates that are not free (none, as a rule)."""
    if all(free[b.start: b.stop].all() for _, b in frames):
        return np.zeros(0, int)
    moved = np.concatenate([np.arange(b.start, b.stop) for _, b in frames])
    return moved[~free[moved]]


def _carries(state, arm: str, e) -> bool:
    """Whether ``arm`` is one of the experiment's arms or carries one (``Robot.mounts``)."""
    return any(arm in lineage(state.mounts, b) for b in e.arms)


def _world_frames(layout: Layout, exps) -> list | None:
    """The world-side frames of ``exps`` as (name, block), which turn with the rotation, or None when one is
    known (it anchors the rotation)."""
    frames = []
    for e in exps:
        for role, name in e.frames.items():
            if e.SCHEMA.role(role).side != WORLD:
                continue  # frames on the tool side or between arms do not turn with the world
            b = layout.block(name)
            if not layout.free[b.start: b.stop].all():
                return None
            frames.append((name, b))
    return frames


def _turned_residuals(lin: Linearization, experiments, arm: str, w: np.ndarray) -> np.ndarray:
    """The whitened change of the stacked residual under the rotation: world-frame vectors turn, the rest not."""
    target = []
    for e, W, r in zip(experiments, lin.W, lin.residuals):
        t = np.zeros_like(r)
        if e.WORLD_VECTOR and _carries(lin.state, arm, e):
            t = np.cross(w, r)
        target.append((W @ t[:, :, None]).ravel())
    target.append(np.zeros(len(lin.r) - sum(len(x) for x in target)))
    return np.concatenate(target)


# Configurations per experiment in the consistent linearization: exact gauges are structural, an evenly spread
# subset of a large data set has the same ones (and keeps the test cheap).
CONSISTENT_SAMPLES = 120
_PROJECTIONS = 4  # Gauss-Newton steps of the joint readings onto the model (quadratic: misfit 1e-2 -> 1e-16)


def consistent_nulls(lin: Linearization, layout: Layout, experiments: Sequence, rtol: float,
                     plain: int | None = None, structure: Structure | None = None) -> np.ndarray | None:
    """A basis (p, k) of the exact null directions (natural units, free coordinates) of the noise-free problem
    at ``lin.state``, or None when the residuals are too small to lift any.

    Residuals left (noise, misfit) lift an exact symmetry of the noise-free cost off the null space by their
    own size: turning a last joint and a clamp's fixture together about the joint's axis conjugates the
    fixture-frame gap, which changes it unless it is zero. So the Jacobian is taken again at joint readings
    moved onto the model (``consistent_readings``: every residual zero where the readings can explain it),
    with the same whitening and the same prior and constraint rows: its null space (relative singular value
    below ``rtol`` after scaling columns to unit norm) is the noise-free problem's, whatever the noise.
    Residuals below a tenth of ``rtol`` of the largest column lift nothing visibly: the test is skipped there,
    and the readings are moved only until their residual is that small.

    ``plain``: the dimension of ``lin``'s own null space (at ``rtol``), when known. Residuals only lift exact
    gauges out of it, so where it has as many dimensions as this structure's noise-free null space had, at a
    state where the residuals lifted none (the structure cache, below), it is that space: an empty basis is
    returned (nothing to add) without the consistent linearization. ``structure``: the solve's (``Structure``),
    for the start of the key."""
    enough = 0.1 * rtol * (lin.colnorm.max() if lin.colnorm.size else 0.0)  # column norms are not negative
    if math.sqrt(lin.cost2) <= enough:  # ``norm(lin.r)``: the same sum of squares
        return None
    key = structure_key(lin, layout, experiments, rtol, structure)
    known = 0 if key in _FULL_RANK else _NULLITY.get(key)
    if known == 0 or (known == plain and plain):
        _remember(key, known)
        return np.zeros((len(lin.free), 0))
    null, reached = _consistent_nulls(lin, layout, experiments, rtol, enough)
    if null is not None and null.shape[1] == 0:
        _remember(key, 0)
    elif null is not None and reached and plain is not None:
        _remember(key, null.shape[1] if plain == null.shape[1] else LIFTS)  # a lifting structure stays uncached
    return null


# Structures whose noise-free problem had no exact null direction (``consistent_nulls``). Full rank is an open
# condition: the same free coordinates, experiments and joint readings with other measurements (the
# next outer iteration, another repeat of a Monte Carlo study) have none either, so the consistent linearization
# (a third of a small calibration's cost) is skipped for them. A structure with exact gauges is remembered apart
# (``_NULLITY``), by their number only, never their basis (it moves with the state), and only from a state where
# the readings reached the model and the residuals lifted none of them out of the plain null space: lifting
# residuals (a clamp's fixture-frame gap) lift them at other states too, and such a structure is marked
# ``LIFTS`` for good. ``clear_structure_cache`` forgets everything.
FULL_RANK_ENTRIES = 256
_FULL_RANK: OrderedDict[bytes, None] = OrderedDict()
NULLITY_ENTRIES = 256
_NULLITY: OrderedDict[bytes, int] = OrderedDict()
LIFTS = -1


def _remember(key: bytes, nullity: int) -> None:
    """Note (most recent last) that structure ``key`` has ``nullity`` exact gauges (0: full rank)."""
    if nullity > 0 and _NULLITY.get(key) == LIFTS:
        return
    cache, limit = (_FULL_RANK, FULL_RANK_ENTRIES) if nullity == 0 else (_NULLITY, NULLITY_ENTRIES)
    cache[key] = None if nullity == 0 else nullity
    cache.move_to_end(key)
    while len(cache) > limit:
        cache.popitem(last=False)


def clear_structure_cache() -> None:
    """Forget every structure remembered here, the column plans of ``columns.scatter_columns`` and the blocks of
    ``naming.blocks_of``."""
    _FULL_RANK.clear()
    _NULLITY.clear()
    _KEY_STARTS.clear()
    clear_plans()
    clear_block_cache()


def structure_key(lin: Linearization, layout: Layout, experiments: Sequence, rtol: float,
                  structure: Structure | None = None) -> bytes:
    """A digest of what the noise-free problem's null space depends on besides the measured values: the layout
    and free coordinates, each experiment's kind, frames, known values and joint readings, the prior and
    constraint rows. Not the whitening's values: an invertible W leaves the null space of ``W J`` that of J.
    ``structure``: the solve's, whose digest of the layout and free coordinates is copied (the same bytes)."""
    if structure is not None:
        h = structure.key_start.copy()
    else:
        h = _key_start(layout, lin.free, rtol)
    m = 0
    for e, W, r in zip(experiments, lin.W, lin.residuals):
        m += r.size
        h.update(experiment_digest(e))
        h.update(repr(np.shape(W)).encode())  # W is invertible: it moves no exact null direction
    h.update(np.ascontiguousarray(lin.J[m:]).tobytes())
    return h.digest()


def _key_start(layout: Layout, free: np.ndarray, rtol: float):
    """``structure_key``'s digest of the layout's names, the free coordinates and ``rtol`` so far. Not whether
    the linearization has the scale test's columns: the null space is the free columns' (``lin.J``) either way."""
    key = (layout.names, free.dtype.str, free.tobytes(), type(rtol), rtol)  # all that the repr reads
    h = _KEY_STARTS.get(key)
    if h is None:
        h = hashlib.blake2b(digest_size=20)
        h.update(repr((layout.names, free.tolist(), rtol)).encode())
        remember(_KEY_STARTS, key, h, KEY_START_ENTRIES)
    return h.copy()  # the caller completes its own


# ``_key_start``'s digests by what they digest (the names, the free coordinates' values, ``rtol`` and its type):
# a new solve of a structure seen before (a Monte Carlo repeat) has a new layout with the same names. Emptied with
# the others (``clear_structure_cache``).
KEY_START_ENTRIES = 64
_KEY_STARTS: dict = {}


# Each experiment's part of ``structure_key``, computed once per experiment object (a solve asks at every
# linearization; experiments and their data sets are immutable). Weak keys: forgotten with the experiment.
_DIGESTS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def experiment_digest(e) -> bytes:
    """A digest of experiment ``e``'s kind, arms, frames, joint readings and known frames (remembered)."""
    digest = _DIGESTS.get(e)
    if digest is None:
        h = hashlib.blake2b(digest_size=20)
        h.update(repr((type(e).__name__, e.kind, e.arms, sorted(dict(e.frames).items()))).encode())
        for a in sorted(e.dataset.q):  # the data set's arms and those carrying them
            h.update(np.ascontiguousarray(e.dataset.q[a], dtype=float).tobytes())
        for name, value in sorted(e.dataset.known.items()):  # known frames enter the Jacobian
            h.update(name.encode() + np.ascontiguousarray(value, dtype=float).tobytes())
        digest = _DIGESTS[e] = h.digest()
    return digest


def _consistent_nulls(lin: Linearization, layout: Layout, experiments: Sequence, rtol: float,
                      enough: float) -> tuple[np.ndarray | None, bool]:
    """(the null basis, whether every experiment's readings reached a residual below ``enough``: the noise-free
    problem's own null space, not one the residuals that no reading explains still lift)."""
    want = {b.name for b in layout.blocks if np.any((lin.free >= b.start) & (lin.free < b.stop))}
    rows, m, reached = [], 0, True
    for e, W, r in zip(experiments, lin.W, lin.residuals):
        m += r.size
        idx = np.unique(np.linspace(0, e.size - 1, min(e.size, CONSISTENT_SAMPLES)).astype(int))
        sub = type(e)(e.dataset.subset(idx), e.frames) if len(idx) < e.size else e
        Wi = W[idx]
        sub = consistent_readings(sub, lin.state, Wi, enough)
        res = sub.residual(lin.state, want=want, jq=False)
        reached = reached and float(np.linalg.norm(Wi @ res.r[:, :, None])) <= enough
        J = scatter_columns(res.jac, layout, lin.free, res.r.shape)
        rows.append((Wi @ J).reshape(-1, len(lin.free)))
    rows.append(lin.J[m:])  # priors and known distances do not depend on the readings
    J = np.concatenate(rows, axis=0)
    if not np.all(np.isfinite(J)) or J.shape[1] == 0:
        return None, False
    Js, c = unit_columns(J)
    S, Vt = right_svd(Js) if Js.shape[0] >= Js.shape[1] else svd(Js)[1:]
    S = np.concatenate([S, np.zeros(Js.shape[1] - len(S))])
    null = Vt[S <= rtol * S[0]] if S[0] > 0 else Vt
    return null.T / c[:, None], reached


def consistent_readings(e, state, W, enough: float = 0.0):
    """``e`` with its joint readings moved onto the model at ``state``: Gauss-Newton steps of minimum length
    (whitened by ``W``) that zero the residual where the readings can (a clamp's 6 residuals with 7 joints), else
    leave only what no reading explains. Stops when the whitened residual is below ``enough`` or a step no
    longer shrinks it tenfold."""
    before, last = np.inf, e
    for _ in range(_PROJECTIONS):
        res = e.residual(state, want=set(), jq=True)
        wr = W @ res.r[:, :, None]
        size = float(np.linalg.norm(wr))
        if size > before:
            return last  # the step did not help (nothing left that the readings explain)
        if size <= enough or size > 0.1 * before or not res.jq:
            break
        before, last = size, e
        arms = list(res.jq)  # the data set's arms and any arm carrying them (a torso)
        A = np.concatenate([W @ res.jq[a] for a in arms], axis=-1)
        dq = -_min_norm_solve(A, wr)[:, :, 0]
        if not np.all(np.isfinite(dq)):
            break
        cuts = np.cumsum([0] + [res.jq[a].shape[-1] for a in arms])
        q = {**e.dataset.q, **{a: e.dataset.q[a] + dq[:, cuts[k]: cuts[k + 1]] for k, a in enumerate(arms)}}
        e = type(e)(replace(e.dataset, q=q), e.frames)
    return e


def _min_norm_solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per sample, the minimum-norm least-squares ``x`` of ``A x = b`` (A (N, k, n), b (N, k, 1)) by the normal
    equations of the smaller side, damped at round-off so a singular configuration stays finite."""
    At = np.swapaxes(A, -1, -2)
    small = A @ At if A.shape[1] <= A.shape[2] else At @ A
    damp = 1e-12 * np.trace(small, axis1=-2, axis2=-1)[:, None, None] * np.eye(small.shape[-1]) + 1e-300
    if A.shape[1] <= A.shape[2]:
        return At @ np.linalg.solve(small + damp, b)
    return np.linalg.solve(small + damp, At @ b)
