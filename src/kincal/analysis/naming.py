"""The identifiability report in words: null directions named by what moves (frame motions matched to joint
axes, offsets against twists, compliance without loads), the experiments they come from, and whether an
experiment is degenerate (its arm columns add no rank)."""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from kincal._memo import remember
from kincal.analysis.covariance import right_svd
from kincal.analysis.linearization import unit_columns
from kincal.kinematics import chain
from kincal.kinematics.model import lineage
from kincal.kinematics.tree import composite
from kincal.lie import se3
from kincal.params import POSE, Block, Layout


def block_of(layout: Layout, i: int) -> Block:
    """The block holding layout coordinate ``i``."""
    for b in layout.blocks:
        if b.start <= i < b.stop:
            return b
    raise IndexError(i)


def blocks_of(layout: Layout, idx) -> list[Block]:
    """The blocks holding the layout coordinates ``idx`` (the blocks are contiguous and in order)."""
    return list(_blocks_and_order(layout, idx)[0])


def pivot_order(layout: Layout, idx) -> list[int]:
    """The positions of the coordinates ``idx`` by their block kind's rank (arm offsets, twists, home, base, tool,
    then experiment frames), stably: the default pivot order of the named null directions."""
    return list(_blocks_and_order(layout, idx)[1])


def _blocks_and_order(layout: Layout, idx) -> tuple[tuple[Block, ...], tuple[int, ...]]:
    """``blocks_of`` and ``pivot_order``, remembered by the blocks tuple itself (held with the entry, so its id is
    not reused meanwhile: every layout of a structure shares one, ``params.layout``; blocks and their kinds are
    immutable) and the values of ``idx``: all they read. A solve asks at its start and its first report."""
    blocks, idx = layout.blocks, np.asarray(idx, dtype=int)
    key = (id(blocks), idx.tobytes())
    hit = _BLOCKS_OF.get(key)
    if hit is not None and hit[0] is blocks:
        return hit[1]
    stops = np.array([b.stop for b in blocks])
    found = tuple(blocks[k] for k in np.searchsorted(stops, idx, side="right").tolist())
    ranks = [b.kind.rank for b in found]
    out = found, tuple(sorted(range(len(found)), key=ranks.__getitem__))
    if isinstance(blocks, tuple):
        remember(_BLOCKS_OF, key, (blocks, out), BLOCKS_OF_ENTRIES)
    return out


BLOCKS_OF_ENTRIES = 256
_BLOCKS_OF: dict = {}


def clear_block_cache() -> None:
    """Forget what ``blocks_of`` and ``pivot_order`` remembered."""
    _BLOCKS_OF.clear()


def degenerate(Rf: np.ndarray, rank: int, rtol: float, layout: Layout, free: np.ndarray,
               spectrum: np.ndarray | None = None) -> bool:
    """No combination of free arm coordinates is identifiable: the arm columns add no rank to the columns of
    the experiment frames (only frames move, or nothing does). Judged on subspaces, not single coordinates,
    so an exact gauge (e.g. the whole arm moving with an unknown tracker) does not make data look useless.
    ``spectrum``: the singular values of ``Rf`` with unit columns, when already known."""
    if rank == 0:
        return True
    arms = [b.arm is not None for b in blocks_of(layout, free)]
    frames = arms.count(False)
    if frames == len(arms) or not frames or frames < rank:
        return False  # (the frames' columns alone, fewer than the rank, cannot reach it)
    arm = np.array(arms, bool)
    Js = unit_columns(Rf)[0]
    s_all = right_svd(Js)[0] if spectrum is None else spectrum
    s_frames = right_svd(Js[:, ~arm])[0]
    tol = rtol * s_all[0]
    return int(np.sum(s_frames > tol)) >= int(np.sum(s_all > tol))


def context(layout: Layout, experiments: Sequence) -> str:
    """Which experiments, with their free frames, for the words of identifiability messages."""
    parts = []
    for e in experiments:
        unknown = [n for r, n in e.frames.items() if layout.free[layout.block(n).start]]
        parts.append(f"{e.kind_name} '{e.name}'" + (f" (free: {', '.join(unknown)})" if unknown else ""))
    return "; ".join(parts)


def describer(state, free: np.ndarray, layout: Layout, experiments: Sequence) -> Callable[[np.ndarray], str]:
    """Words for a null direction (p,) over the free coordinates ``free`` (layout indices) at ``state``: what the
    frames do (a translation, a rotation about a named joint axis, a screw motion), and the known trade-offs of
    the arm parameters."""
    axes, frames = _joint_axes_and_frames(state, experiments)
    loads = any("wrench_tool" in e.dataset.measured or any(state.arms[a].weights is not None for a in e.arms)
                for e in experiments)  # tool loads, or the arm's own weight (kincal.kinematics.gravity)
    col = {int(i): k for k, i in enumerate(free)}
    part = np.array([b.part if b.arm is not None else "" for b in blocks_of(layout, free)])
    poses = []  # (name, columns, adjoint of its increment frame) of each pose frame with every coordinate free
    for b in layout.blocks:
        idx = [col.get(i) for i in range(b.start, b.stop)]
        if b.kind is POSE and None not in idx:
            poses.append((b.name, idx, se3.adjoint(frames.get(b.name, np.eye(4)))))

    axes = (list(axes), np.array(list(axes.values())).reshape(-1, 6))  # names and screws, matched at once

    def describe(row: np.ndarray) -> str:
        words = [_frame_motion(name, Ad @ row[idx], axes) for name, idx, Ad in poses
                 if np.linalg.norm(row[idx]) >= 1e-9]
        moved = set(part[np.abs(row) > 1e-9].tolist())
        if moved & {"compliance", "lateral"} and not loads:
            words.append("no data set applies a load (wrench_tool) and no arm has a mass model with gravity, so joint "
                         "compliance has no effect")
        if "offsets" in moved and moved & {"twists", "home"}:
            words.append("in a full POE model a joint offset equals rotating the later joint axes and the home pose "
                         "about that joint's axis")
        return "; ".join(words)

    return describe


def _joint_axes_and_frames(state, experiments) -> tuple[dict, dict]:
    """World joint axes at each experiment's first sample (``arm.joint`` -> screw), and the world pose in which
    each pose frame's increment is expressed."""
    axes, frames = {}, {}
    for e in experiments:
        for arm in e.arms:
            line = lineage(state.mounts, arm)  # a mounted arm's axes move with the arms carrying it
            segs = [state.arms[s] for s in line]
            comp = composite(segs)
            theta = np.concatenate([e.dataset.q[s][:1] + a.offsets for s, a in zip(line, segs)], axis=-1)
            kin = chain(comp.screws, theta, comp.base, comp.home, comp.tool)
            Ad = se3.adjoint(kin.prefixes[0, :-1])
            names = [f"{s}.{jn}" for s, a in zip(line, segs) for jn in a.joint_names]
            for j, jn in enumerate(names):
                axes.setdefault(jn, Ad[j] @ comp.screws[j])
        for role, G in e.increment_frames(state).items():
            frames[e.frames[role]] = G
    return axes, frames


def _frame_motion(name: str, tw: np.ndarray, axes: tuple) -> str:
    """A frame's motion (world twist) in words, matched to a joint axis when it is a rotation about one;
    ``axes``: the joint axes' names and their screws (k, 6)."""
    v, w = se3.split(tw)
    if np.linalg.norm(w) < 1e-9 * max(np.linalg.norm(v), 1e-300):
        return f"a translation of the {name}"
    t = tw / np.linalg.norm(w)
    names, A = axes
    near = np.minimum(np.linalg.norm(t - A, axis=1), np.linalg.norm(t + A, axis=1)) < 1e-4
    match = np.flatnonzero(near)
    return (f"a rotation of the {name} about the axis of {names[match[0]]}" if len(match)
            else f"a screw motion of the {name}")
