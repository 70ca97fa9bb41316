"""The identifiability report in words: null directions named by what moves (frame motions matched to joint
axes, offsets against twists, compliance without loads), the experiments they come from, and whether an
experiment is degenerate (its arm columns add no rank)."""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from kincal.analysis.covariance import right_svd
from kincal.analysis.linearization import Linearization, unit_columns
from kincal.kinematics import chain
from kincal.lie import se3
from kincal.params import POSE, Block, Layout


def block_of(layout: Layout, i: int) -> Block:
    """The block holding layout coordinate ``i``."""
    for b in layout.blocks:
        if b.start <= i < b.stop:
            return b
    raise IndexError(i)


def degenerate(Rf: np.ndarray, rank: int, rtol: float, layout: Layout, free: np.ndarray) -> bool:
    """No combination of free arm coordinates is identifiable: the arm columns add no rank to the columns of
    the experiment frames (only frames move, or nothing does). Judged on subspaces, not single coordinates,
    so an exact gauge (e.g. the whole arm moving with an unknown tracker) does not make data look useless."""
    if rank == 0:
        return True
    arm = np.array([block_of(layout, i).arm is not None for i in free])
    if not arm.any() or arm.all():
        return False
    Js = unit_columns(Rf)[0]
    s_all = right_svd(Js)[0]
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


def describer(lin: Linearization, layout: Layout, experiments: Sequence) -> Callable[[np.ndarray], str]:
    """Words for a null direction (p,) over the free coordinates of ``lin``: what the frames do (a translation,
    a rotation about a named joint axis, a screw motion), and the known trade-offs of the arm parameters."""
    axes, frames = _joint_axes_and_frames(lin.state, experiments)
    loads = any("wrench_tool" in e.dataset.measured or any(lin.state.arms[a].weights is not None for a in e.arms)
                for e in experiments)  # tool loads, or the arm's own weight (kincal.kinematics.gravity)
    col = {int(i): k for k, i in enumerate(lin.free)}
    blocks = [block_of(layout, i) for i in lin.free]
    pose_blocks = [(b, [col.get(i) for i in range(b.start, b.stop)]) for b in layout.blocks
                   if b.kind is POSE]

    def describe(row: np.ndarray) -> str:
        words = []
        for b, idx in pose_blocks:
            if any(i is None for i in idx) or np.linalg.norm(row[idx]) < 1e-9:
                continue
            words.append(_frame_motion(b.name, se3.adjoint(frames.get(b.name, np.eye(4))) @ row[idx], axes))
        moved = {blocks[k].part for k in np.flatnonzero(np.abs(row) > 1e-9) if blocks[k].arm is not None}
        if "compliance" in moved and not loads:
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
            a = state.arms[arm]
            kin = chain(a.screws, e.dataset.q[arm][:1] + a.offsets, a.base, a.home, a.tool)
            Ad = se3.adjoint(kin.prefixes[0, :-1])
            for j, jn in enumerate(a.joint_names):
                axes.setdefault(f"{arm}.{jn}", Ad[j] @ a.screws[j])
        for role, G in e.increment_frames(state).items():
            frames[e.frames[role]] = G
    return axes, frames


def _frame_motion(name: str, tw: np.ndarray, axes: dict) -> str:
    """A frame's motion (world twist) in words, matched to a joint axis when it is a rotation about one."""
    v, w = se3.split(tw)
    if np.linalg.norm(w) < 1e-9 * max(np.linalg.norm(v), 1e-300):
        return f"a translation of the {name}"
    t = tw / np.linalg.norm(w)
    match = [jn for jn, ax in axes.items() if min(np.linalg.norm(t - ax), np.linalg.norm(t + ax)) < 1e-4]
    return f"a rotation of the {name} about the axis of {match[0]}" if match else f"a screw motion of the {name}"
