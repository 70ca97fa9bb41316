"""The identifiability report in words: null directions named by parameter, frame motions matched to joint
axes, the scale test, and whether an experiment is degenerate (its arm columns add no rank)."""

from __future__ import annotations


import numpy as np

from kincal.analysis import analyse
from kincal.analysis.covariance import right_svd
from kincal.estimation.steps import Linearization
from kincal.kinematics import REVOLUTE, chain
from kincal.lie import se3
from kincal.params import POSE, scale_direction
from kincal.schema import WORLD


def degenerate(problem, J, ana) -> bool:
    """No combination of free arm coordinates is identifiable: the arm columns add no rank to the columns of
    the experiment frames (only frames move, or nothing does). Judged on subspaces, not single coordinates,
    so an exact gauge (e.g. the whole arm moving with an unknown tracker) does not make data look useless."""
    if ana.rank == 0:
        return True
    arm = np.array([block_of(problem, i).arm is not None for i in problem.free_idx])
    if not arm.any():
        return False
    if arm.all():
        return False
    c = np.linalg.norm(J, axis=0)
    Js = J / np.where(c > 0, c, 1.0)
    s_all = right_svd(Js)[0]
    s_frames = right_svd(Js[:, ~arm])[0]
    tol = ana.rtol * s_all[0]
    return int(np.sum(s_frames > tol)) >= int(np.sum(s_all > tol))


def block_of(problem, i):
    for b in problem.layout.blocks:
        if b.start <= i < b.stop:
            return b
    raise IndexError(i)


def context(problem):
    """Which experiments, with their free frames, for the words of identifiability messages."""
    parts = []
    for e in problem.experiments:
        unknown = [n for r, n in e.frames.items()
                   if problem.layout.free[problem.layout.block(n).start]]
        parts.append(f"{e.kind_name} '{e.name}'" + (f" (free: {', '.join(unknown)})" if unknown else ""))
    return "; ".join(parts)


def analyse_named(problem, state, lin, rtol, order, context):
    layout = problem.layout
    axes, frames = {}, {}
    for e in problem.experiments:
        for arm in e.arms:
            a = state.arms[arm]
            kin = chain(a.screws, e.dataset.q[arm][:1] + a.offsets, a.base, a.home, a.tool)
            Ad = se3.adjoint(kin.prefixes[0, :-1])
            for j, jn in enumerate(a.joint_names):
                axes.setdefault(f"{arm}.{jn}", Ad[j] @ a.screws[j])
        for role, G in e.increment_frames(state).items():
            frames[e.frames[role]] = G
    loads = any("wrench_tool" in e.dataset.measured for e in problem.experiments)
    col = {int(i): k for k, i in enumerate(problem.free_idx)}
    blocks = [block_of(problem, i) for i in problem.free_idx]
    pose_blocks = [(b, [col.get(i) for i in range(b.start, b.stop)]) for b in layout.blocks
                   if b.kind is POSE]

    def describe(row):
        words = []
        for b, idx in pose_blocks:
            if any(i is None for i in idx):
                continue
            d = row[idx]
            if np.linalg.norm(d) < 1e-9:
                continue
            tw = se3.adjoint(frames.get(b.name, np.eye(4))) @ d
            v, w = se3.split(tw)
            if np.linalg.norm(w) < 1e-9 * max(np.linalg.norm(v), 1e-300):
                words.append(f"a translation of the {b.name}")
                continue
            t = tw / np.linalg.norm(w)
            match = [jn for jn, ax in axes.items() if min(np.linalg.norm(t - ax), np.linalg.norm(t + ax)) < 1e-6]
            words.append(f"a rotation of the {b.name} about the axis of {match[0]}" if match
                         else f"a screw motion of the {b.name}")
        moved = {blocks[k].part for k in np.flatnonzero(np.abs(row) > 1e-9) if blocks[k].arm is not None}
        if "compliance" in moved and not loads:
            words.append("no data set applies a load (wrench_tool), so joint compliance has no effect")
        if "offsets" in moved and moved & {"twists", "home"}:
            words.append("in a full POE model a joint offset equals rotating the later joint axes and the home pose "
                         "about that joint's axis")
        return "; ".join(words)

    return analyse(lin.Rf, problem.free_names, rtol=rtol, scale=scale_null(problem, state, lin), priority=order,
                   describe=describe, context=context, held=rotation_nulls(problem, state, lin))


def scale_null(problem, state, lin: Linearization):
    """The free direction equivalent to scaling every length, if the data cannot see scale; else None.

    Scale is unidentifiable when (1) no measured length enters the residuals: scaling every length, fixed ones
    included, by ``1 + e`` scales the residual's length part by ``1 + e`` (``J_all s_all = r_len``; zero on
    noise-free data at the truth, but with residuals left the data would prefer to shrink the robot, which
    is no information about its size), and (2) the fixed length coordinates add no rank to the free ones
    (e.g. a fixed base is absorbed by free twists and home). The direction is then ``s_free + u`` with
    ``J u = J_fixed s_fixed`` (free parameters standing in for the fixed lengths). Everything is read off the
    linearization's triangular factor.
    """
    layout = problem.layout
    p = lin.p
    if not any(layout.units[i] == "m" for i in problem.free_idx):
        return None  # no free length, nothing to scale
    if not lin.every:
        raise AssertionError("the scale test needs a linearization with every column")
    fixed = lin.fixed  # the fixed coordinates that scale with the robot
    Ra = lin.Rall  # (q, p + len(fixed)): free first
    s_all = scale_direction(state, layout)
    s = np.concatenate([s_all[problem.free_idx], s_all[fixed]])
    colnorm = np.linalg.norm(Ra, axis=0)
    if np.linalg.norm(Ra @ s - lin.Rlen) > 1e-6 * (np.sum(colnorm * np.abs(s)) + np.linalg.norm(lin.Rlen)):
        return None
    units = np.array(layout.units)[fixed]
    lengths = np.flatnonzero((units == "m") & (colnorm[p:] > 0))
    if len(lengths):
        # the part of a fixed length's column outside the free columns' range sits below row p of R
        outside = np.linalg.norm(Ra[p:, p + lengths], axis=0) / colnorm[p + lengths]
        if np.max(outside) > 1e-6:
            return None
    u = np.linalg.lstsq(lin.Rf, Ra[:p, p:] @ s[p:], rcond=None)[0]
    d = s[:p] + u
    return d if np.linalg.norm(d) > 0 else None


def rotation_nulls(problem, state, lin: Linearization) -> list[np.ndarray]:
    """Rotations about an arm's first joint axis that carry every world-side frame of its experiments along
    (``j1.offset + 1`` with the frames turned by the axis screw): exact symmetries of the cost wherever those
    frames are free. Residuals written in a frame that turns along are unchanged (clamp, plate, tracker); a
    socket's world-frame vector ``r`` turns, ``J g = w x r``, which residuals left would mistake for
    information. Returned (natural units, free coordinates) where the linearization confirms the symmetry:
    ``J g`` equals the turned residuals."""
    layout = problem.layout
    col = {int(i): k for k, i in enumerate(problem.free_idx)}
    residuals = None  # evaluated only for an arm that passes the structural checks
    out = []
    for arm, a in state.arms.items():
        exps = [e for e in problem.experiments if arm in e.arms]
        if not exps or any(len(e.arms) > 1 for e in exps):
            continue  # another arm in the loop does not turn along
        i1 = layout.index(f"{arm}.{a.joint_names[0]}.offset")
        if i1 not in col or a.joint_types[0] != REVOLUTE:
            continue
        xi = se3.adjoint(a.base) @ a.screws[0]  # joint 1's screw in world coordinates
        v, w = se3.split(xi)
        g = np.zeros(layout.size)
        g[i1] = 1.0
        ok = True
        for e in exps:
            for role, name in e.frames.items():
                if e.SCHEMA.role(role).side != WORLD:
                    continue
                b = layout.block(name)
                g[b.slice] = b.kind.world_motion(state.extras[name], xi)
                if not layout.free[b.start: b.stop].all():
                    ok = False  # a known frame anchors the rotation
        if not ok or any(g[i] != 0 and i not in col for i in np.flatnonzero(g)):
            continue
        target = []
        residuals = problem._residuals(state) if residuals is None else residuals
        for e, W, res in zip(problem.experiments, lin.W, residuals):
            t = np.zeros_like(res.r)
            if e.WORLD_VECTOR and arm in e.arms:
                t = np.cross(w, res.r)
            target.append((W @ t[:, :, None]).ravel())
        target.append(np.zeros(len(lin.r) - sum(len(x) for x in target)))
        t = np.concatenate(target)
        gf = g[problem.free_idx]
        Jg = lin.J @ gf
        if np.linalg.norm(Jg - t) <= 1e-6 * (np.sum(np.linalg.norm(lin.J, axis=0) * np.abs(gf)) + np.linalg.norm(t)):
            out.append(gf)
    return out

