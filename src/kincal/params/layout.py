"""The parameter layout: every coordinate's stable name, unit, block and status (free, fixed, prior).

Every coordinate is free, fixed, or free with a Gaussian prior on its displacement from the nominal state.
Selections are names or globs (``right.j*.offset``); a glob that matches a block name selects the whole block
(``clamp``, ``right.home``), and a glob matching a joint's 6 twist coordinates (``left.j2.xi.v_x``) selects that
joint's twist, which is always estimated as a whole in its minimal parametrization.
"""

from __future__ import annotations

import fnmatch
import weakref
from dataclasses import dataclass
from functools import cached_property
from typing import Mapping, Sequence

import numpy as np

from kincal._memo import remember
from kincal.errors import ModelError
from kincal.params import kinds, values
from kincal.params.kinds import (ARM_KINDS, COMPLIANCE, HOME, LATERAL, OFFSETS, PLANE, POINT, POINTS, POSE,
                                 POSE_COORDS, TWISTS, ParamKind)
from kincal.params.values import State

LEVELS = ("offsets", "kinematic", "elastic", "lateral")  # lateral: opt-in, the arms that declare it


@dataclass(frozen=True)
class Prior:
    """Gaussian prior on a coordinate's displacement from nominal: ``(disp - mean) / sigma``."""

    sigma: float
    mean: float = 0.0


@dataclass(frozen=True)
class Block:
    """A contiguous run of coordinates of one kind: an arm's part (``arm`` set) or a frame."""

    name: str
    kind: ParamKind
    start: int
    stop: int
    arm: str | None = None  # arm blocks only

    @property
    def part(self) -> str | None:
        """The arm part's name (offsets, twists, home, base, tool, compliance); None for frames."""
        return self.kind.name if self.arm is not None else None

    @cached_property
    def slice(self) -> slice:  # read at every retraction and stacking: made once
        return slice(self.start, self.stop)

    def value(self, state: State):
        """What the kind acts on: the arm's ``ArmValues`` for arm blocks, else the frame's value."""
        return state.arms[self.arm] if self.arm is not None else state.extras[self.name]


@dataclass(frozen=True)
class Layout:
    """Every coordinate's name, block and status. ``free``, ``prior_mean``, ``prior_sigma`` are (p,) arrays."""

    names: tuple[str, ...]
    units: tuple[str, ...]  # "rad", "m", "rad/Nm", "m/N" per coordinate
    blocks: tuple[Block, ...]
    free: np.ndarray
    prior_mean: np.ndarray
    prior_sigma: np.ndarray  # inf where no prior
    twist_joint: Mapping[str, tuple[int, ...]]  # "right.j3" -> coordinate indices of its tangent coordinates

    @property
    def size(self) -> int:
        return len(self.names)

    @cached_property
    def lengths(self) -> np.ndarray:
        """(size,) bool: the coordinates in metres (read at every linearization by the scale test)."""
        out = np.array(self.units) == "m"
        out.flags.writeable = False
        return out

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

    def block_at(self, i: int) -> Block:
        """The block holding coordinate ``i``."""
        for b in self.blocks:
            if b.start <= i < b.stop:
                return b
        raise IndexError(i)

    @property
    def free_names(self) -> list[str]:
        return [n for n, f in zip(self.names, self.free) if f]

    @property
    def runs(self) -> tuple[tuple[int, ...], np.ndarray]:
        """``block_runs`` of the blocks (``touched``): remembered by the blocks tuple, which every layout of a
        structure shares, so a new layout reads it without computing it."""
        return block_runs(self.blocks)

    def touched(self, mask: np.ndarray) -> list[Block]:
        """The blocks (in order) where the (size,) bool ``mask`` holds a True (``touched``)."""
        return touched(self, mask)

    def holding(self, idx) -> list[Block]:
        """The blocks (in order) holding any of the layout indices ``idx`` (negative ones counted from the end)."""
        mask = np.zeros(self.size, bool)
        mask[np.asarray(idx, dtype=int)] = True
        return touched(self, mask)


def block_runs(blocks: Sequence[Block]) -> tuple[tuple[int, ...], np.ndarray]:
    """The indices of the blocks holding a coordinate and their starts (blocks are contiguous runs in order).
    Remembered by the blocks tuple itself (held with the entry, so its id is not reused meanwhile): every layout
    of a structure shares one (``_remembered_blocks``); blocks are immutable."""
    hit = _RUNS.get(id(blocks))
    if hit is not None and hit[0] is blocks:
        return hit[1]
    held = [k for k, b in enumerate(blocks) if b.stop > b.start]
    starts = np.array([blocks[k].start for k in held], dtype=np.intp)
    starts.flags.writeable = False
    if isinstance(blocks, tuple):
        remember(_RUNS, id(blocks), (blocks, (tuple(held), starts)), _SELECTION_ENTRIES)
    return tuple(held), starts


def touched(layout, mask: np.ndarray) -> list[Block]:
    """The blocks of ``layout`` (in order) where the (size,) bool ``mask`` holds a True: one reduction over the
    blocks' runs instead of a test per block or per coordinate. ``layout``: a ``Layout`` or anything with its
    ``blocks``."""
    held, starts = layout.runs if isinstance(layout, Layout) else block_runs(layout.blocks)
    if not held:
        return []
    hit = np.logical_or.reduceat(mask, starts)
    return [layout.blocks[k] for k, h in zip(held, hit.tolist()) if h]


def level_patterns(level: str, arms: Sequence[str]) -> list[str]:
    """The patterns a one-word level stands for."""
    if level == "offsets":
        return [f"{a}.*.offset" for a in arms]
    if level == "kinematic":
        return [f"{a}.{k.name}" for a in arms for k in (OFFSETS, TWISTS, HOME)]
    if level == "elastic":
        return [f"{a}.{COMPLIANCE.name}" for a in arms]
    if level == "lateral":
        return ["*.lateral_[xy]"]
    raise ModelError(f"unknown level {level!r}; levels: {', '.join(LEVELS)} (or a list of names/globs)")


def _blocks(state: State, arms: Sequence[str]):
    """Blocks with their coordinate names and units: every arm kind of each arm, then every frame."""
    names: list[str] = []
    units: list[str] = []
    blocks: list[Block] = []
    twist_joint: dict[str, tuple[int, ...]] = {}
    items = [(f"{arm}.{k.name}", k, arm, state.arms[arm]) for arm in arms for k in ARM_KINDS]
    items += [(name, state.kinds[name], None, value) for name, value in state.extras.items()]
    for bname, kind, arm, value in items:
        cn, cu = kind.coordinates(arm if arm is not None else bname, value)
        if kind is LATERAL and not cn:  # only arms that declare lateral compliance have the block
            continue
        if kind is TWISTS:
            for j in value.joint_names:
                twist_joint[f"{arm}.{j}"] = tuple(len(names) + k for k, c in enumerate(cn)
                                                  if c.startswith(f"{arm}.{j}.xi."))
        blocks.append(Block(bname, kind, len(names), len(names) + len(cn), arm))
        names += cn
        units += cu
    return names, units, blocks, twist_joint


def _remembered_blocks(state: State, arms: Sequence[str]):
    """``_blocks``, remembered per structure: the arms' values objects (immutable; a problem's nominal arms are
    ``ArmValues.from_model``'s, the same object per model) and each frame's name, kind and value shape, which
    are all a frame kind's coordinates read (``FRAME_KINDS``: a pose or plane its name, points their count)."""
    frames = tuple((n, state.kinds[n], np.shape(v) if state.kinds[n] in _SHAPED else None)
                   for n, v in state.extras.items())
    if any(k not in _SHAPED and k not in _NAMED for _, k, _ in frames):
        return _blocks(state, arms)
    values = [state.arms[a] for a in arms]
    key = (tuple(arms), tuple(id(v) for v in values), frames)
    hit = _BLOCKS.get(key)
    if hit is not None and all(r() is v for r, v in zip(hit[0], values)):
        names, units, blocks, twist_joint = hit[1]
        return names, units, blocks, dict(twist_joint)
    names, units, blocks, twist_joint = _blocks(state, arms)
    remember(_BLOCKS, key, (tuple(weakref.ref(v) for v in values), (tuple(names), tuple(units), tuple(blocks),
                                                                   twist_joint)), _SELECTION_ENTRIES)
    return names, units, blocks, dict(twist_joint)


def build_layout(
    state: State,
    free: str | Sequence[str] = "offsets",
    *,
    fixed: Sequence[str] = (),
    priors: Mapping[str, Prior] | None = None,
    free_extras: Sequence[str] | None = None,
    arms: Sequence[str] | None = None,
) -> Layout:
    """Coordinates of every arm in ``arms`` (default: all) and every frame in the state.

    ``free``: a level word or names/globs. Frames listed in ``free_extras`` (default: all frames, i.e. the
    unknowns of the experiments) are free too. ``fixed`` globs are removed afterwards. A coordinate with a
    prior is free. Every pattern must match at least one coordinate.
    """
    arms = list(state.arms) if arms is None else list(arms)
    names, units, blocks, twist_joint = _remembered_blocks(state, arms)
    extras = list(state.extras) if free_extras is None else list(free_extras)
    key = _selection_key(names, blocks, free, fixed, priors, extras)
    hit = _SELECTIONS.get(key) if key is not None else None
    if hit is None:
        hit = _selection(names, blocks, twist_joint, _patterns(free, arms), extras, fixed, priors)
        if key is not None:
            remember(_SELECTIONS, key, hit, _SELECTION_ENTRIES)
    mask, mean, sigma = (a.copy() for a in hit)
    return Layout(tuple(names), tuple(units), tuple(blocks), mask, mean, sigma, twist_joint)


# build_layout's memory: the free mask and priors per selection over the same coordinates (a Monte Carlo study
# or a batch lays out the same structure again and again), oldest first
_SELECTIONS: dict[tuple, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
_SELECTION_ENTRIES = 256


# _remembered_blocks' memory: (arm names, ids of their values, frames) -> (weak references to the values, blocks)
_BLOCKS: dict[tuple, tuple] = {}
# block_runs' memory: id(blocks tuple) -> (the tuple, its runs)
_RUNS: dict[int, tuple] = {}
# Frame kinds whose coordinates follow from the frame's name alone, and from its name and value shape.
_NAMED = frozenset((POSE, PLANE))  # sets: kinds hash by identity, so a test calls no ``__eq__``
_SHAPED = frozenset((POINT, POINTS))


def clear_caches() -> None:
    """Forget what ``build_layout``, ``block_runs``, ``ArmValues.from_model`` and ``TWISTS.scale`` remembered, and
    the memories of the layers above registered with ``on_clear`` (tests, cold-start timings)."""
    _SELECTIONS.clear()
    _BLOCKS.clear()
    _RUNS.clear()
    kinds._TWIST_SCALES.clear()
    values._FROM_MODEL.clear()
    for clear in tuple(_CLEARS):
        clear()


# The clear functions of memories kept above this layer (which it may not import): ``clear_caches`` runs them.
_CLEARS: list = []


def on_clear(clear):
    """Have ``clear_caches`` run ``clear`` too; returns it (a decorator)."""
    if clear not in _CLEARS:
        _CLEARS.append(clear)
    return clear


def _selection_key(names, blocks, free, fixed, priors, extras) -> tuple | None:
    """What the selection depends on, hashable; None when some argument is not (no memory then)."""
    key = (tuple(names), tuple((b.name, b.start, b.stop) for b in blocks),
           free if isinstance(free, str) else tuple(free), tuple(fixed), tuple((priors or {}).items()), tuple(extras))
    try:
        hash(key)
    except TypeError:
        return None
    return key


def _selection(names, blocks, twist_joint, patterns, extras, fixed, priors):
    """(free mask, prior means, prior sigmas) of the coordinates ``names`` (``build_layout``'s rules)."""
    match = _Matcher(names, blocks, twist_joint)
    mask = np.zeros(len(names), bool)
    for pat in patterns:
        mask |= match(pat, "free parameter", f" (e.g. {', '.join(names[:3])}, ...)")
    for name in extras:
        mask[next(b for b in blocks if b.name == name).slice] = True
    for pat in fixed:
        mask &= ~match(pat, "fixed parameter")
    mean, sigma = np.zeros(len(names)), np.full(len(names), np.inf)
    for pat, prior in (priors or {}).items():
        hit = match(pat, "prior")
        if not (prior.sigma > 0 and np.isfinite(prior.sigma)):
            raise ModelError(f"prior {pat!r}: sigma must be positive and finite, got {prior.sigma}")
        mean[hit], sigma[hit] = prior.mean, prior.sigma
        mask |= hit
    return mask, mean, sigma


def _patterns(free, arms) -> list[str]:
    if isinstance(free, str) and free not in LEVELS:
        level_patterns(free, arms)  # raises: a bare string must be a level word
    items = [free] if isinstance(free, str) else list(free)
    return [p for it in items for p in (level_patterns(it, arms) if it in LEVELS else [it])]


@dataclass(frozen=True)
class _Matcher:
    """Coordinates matched by a glob: by name, by block name, or by a joint's twist aliases."""

    names: Sequence[str]
    blocks: Sequence[Block]
    twist_joint: Mapping[str, tuple[int, ...]]

    def __call__(self, pattern: str, what: str, hint: str = "") -> np.ndarray:
        hit = np.array([fnmatch.fnmatchcase(n, pattern) for n in self.names], bool)
        for b in self.blocks:
            if fnmatch.fnmatchcase(b.name, pattern):
                hit[b.slice] = True
        for joint, idx in self.twist_joint.items():
            aliases = [f"{joint}.xi"] + [f"{joint}.xi.{c}" for c in POSE_COORDS]
            if any(fnmatch.fnmatchcase(a, pattern) for a in aliases):
                hit[list(idx)] = True
        if not hit.any():
            raise ModelError(f"{what} pattern {pattern!r} matches no parameter{hint}")
        return hit
