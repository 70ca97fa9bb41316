"""Operations over a whole layout, each delegated block by block to the block's parameter kind."""

from __future__ import annotations

import numpy as np

from kincal.lie import se3
from kincal.params.kinds import ARM_KINDS, POSE_COORDS, TWISTS, ParamKind, with_arm_poses
from kincal.params.layout import Layout, touched
from kincal.params.values import State, retract_twists, twist_motions


def retract(state: State, layout: Layout, delta: np.ndarray, tangents: bool = True) -> State:
    """Values at local coordinates ``delta`` (p,) around ``state`` (tangent bases kept: see ``recentre``).
    ``tangents=False``: for residuals without Jacobian only (``values.retract_twists``; ``recentre`` restores
    the tangent bases)."""
    arms, extras = dict(state.arms), dict(state.extras)
    # the joint screws' rigid motions and the pose blocks that move: their exponentials in one batch (``exp(d) T``
    # for a pose, as ``kind.retract``; ``values.retract_twists`` for the screws)
    twists, poses = [], []
    for b in _moved_blocks(layout, delta):
        kind = b.kind
        if kind is TWISTS:
            twists.append((b, twist_motions(state.arms[b.arm], delta[b.slice])))
        elif kind.pose_of(b.value(state)) is not None:
            poses.append(b)
        elif b.arm is not None:
            arms[b.arm] = kind.retract(arms[b.arm], delta[b.slice])
        else:
            extras[b.name] = kind.retract(extras[b.name], delta[b.slice])
    if not twists and not poses:
        return state.moved(arms, extras)
    E = se3.exp(np.concatenate([g for _, g in twists] + [delta[b.slice][None] for b in poses]))
    k = 0
    for b, g in twists:
        a = arms[b.arm]  # the twists' fields only: the arm's other blocks changed others
        arms[b.arm] = retract_twists(a, delta[b.slice], tangents, (g, E[k: k + len(g)]))
        k += len(g)
    moved = {}  # arm -> its moved poses, set in one replace
    for b, Ek in zip(poses, E[k:]):
        if b.arm is not None:
            moved.setdefault(b.arm, []).append((b.kind, Ek @ b.kind.pose_of(arms[b.arm])))
        else:
            extras[b.name] = b.kind.with_pose(extras[b.name], Ek @ extras[b.name])
    for arm, ps in moved.items():
        arms[arm] = with_arm_poses(arms[arm], ps)
    return state.moved(arms, extras)


def _moved_blocks(layout: Layout, delta: np.ndarray) -> list:
    """The blocks of ``layout`` (in order) where ``delta`` has a nonzero coordinate."""
    return touched(layout, delta != 0)


def recentre(state: State, conformed: bool = False) -> State:
    """The next linearization point: every kind re-centres its values (twists conformed, planes normalized,
    tangent bases recomputed). ``conformed``: the twists were conformed already (``conform``): their screws are
    kept as they are, the same arrays."""
    arms = {}
    for name, a in state.arms.items():
        for kind in _RECENTRING:
            a = TWISTS.with_tangents(a) if conformed and kind is TWISTS else kind.recentre(a)
        arms[name] = a
    extras = {k: _recentred(state.kinds[k], v) for k, v in state.extras.items()}
    return state.moved(arms, extras)


def _recentred(kind, value):
    """``kind.recentre(value)``, without the call where the kind keeps its values as they are."""
    return value if type(kind).recentre is ParamKind.recentre else kind.recentre(value)


# The arm kinds whose values re-centre (the others keep theirs: ``ParamKind.recentre``), in ``ARM_KINDS``' order.
_RECENTRING = tuple(k for k in ARM_KINDS if type(k).recentre is not ParamKind.recentre)


def conform(state: State) -> State:
    """``state`` with every arm's twists conformed as ``recentre`` conforms them (screws only, no tangent bases):
    a trial point that ``recentre(..., conformed=True)`` makes the next linearization point with the same screws."""
    return state.moved({name: TWISTS.conform(a) for name, a in state.arms.items()}, dict(state.extras))


def pose_retraction_jacobians(layout: Layout, delta: np.ndarray) -> dict[str, np.ndarray]:
    """Per block stepped away from its linearization point whose retraction is not additive (poses of arms and
    frames): the map from d(delta) to the kind's own increment there (``J_l(d)``: exact, not first order)."""
    out = {}
    for b in _moved_blocks(layout, delta):
        J = b.kind.retraction_jacobian(delta[b.slice])
        if J is not None:
            out[b.name] = J
    return out


def displacement(state: State, nominal: State, layout: Layout, only: np.ndarray | None = None,
                 jacobian: bool = True, blocks: list | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Local displacement of ``state`` from ``nominal`` (p,) and its derivative w.r.t. ``state``'s own local
    coordinates (diagonal blocks, returned as a dense (p, p) matrix; None with ``jacobian=False``). Used for
    priors and reports. ``only``: the layout indices wanted; blocks holding none of them are left zero (e.g.
    fixed frames). ``blocks``: the blocks holding ``only`` (``Layout.holding``), where the caller knows them."""
    disp = np.zeros(layout.size)
    D = np.zeros((layout.size, layout.size)) if jacobian else None
    diagonal = D.reshape(-1)[:: layout.size + 1] if jacobian else None  # a view: D's diagonal, written in place
    poses = []  # (block, pose, nominal pose) of the pose kinds: their logarithms in one batch
    if blocks is None:
        blocks = layout.blocks if only is None else layout.holding(only)
    for b in blocks:
        value, value0 = b.value(state), b.value(nominal)
        T = b.kind.pose_of(value)
        if T is not None:
            poses.append((b, T, b.kind.pose_of(value0)))
        elif jacobian and not b.kind.additive:
            disp[b.slice], D[b.slice, b.slice] = b.kind.displacement(value, value0)
        else:  # an additive kind's derivative is the identity: ones on D's diagonal, as its np.eye would give
            disp[b.slice] = b.kind.offset(value, value0)
            if jacobian:
                diagonal[b.slice] = 1.0
    if poses:
        # ``T @ inverse(T0)`` pose by pose (the same products as in a batch), the nominal poses' inverses remembered:
        # the model's own, or the frames the solve's first evaluation met (``se3.remembered``)
        D_T = np.array([T @ se3.remembered(se3.inverse, T0) for _, T, T0 in poses])  # ``np.stack``'s array, sooner
        x, Jinv = se3.log_with_jacobian_inv(D_T) if jacobian else (se3.log(D_T), None)
        for k, (b, _, _) in enumerate(poses):
            disp[b.slice] = x[k]
            if jacobian:
                D[b.slice, b.slice] = Jinv[k]
    return disp, D


def scale_direction(state: State, layout: Layout) -> np.ndarray:
    """Local direction (p,) that scales every length (translations, twist moments, points, plane offsets)."""
    s = np.zeros(layout.size)
    for b in layout.blocks:
        s[b.slice] = b.kind.scale(b.value(state))
    return s


def twist_coordinates(state: State, layout: Layout, cov: np.ndarray | None = None):
    """Derived 6 twist coordinates per joint: (names, values, covariance or None), propagated through the bases."""
    names, values, rows = [], [], []
    for b in layout.blocks:
        if b.kind is not TWISTS:
            continue
        a = state.arms[b.arm]
        for j, name in enumerate(a.joint_names):
            names += [f"{b.arm}.{name}.xi.{c}" for c in POSE_COORDS]
            values.append(a.screws[j])
        rows.append((b, a.basis))
    if cov is None:
        return names, np.concatenate(values) if values else np.zeros(0), None
    Bfull = np.zeros((len(names), layout.size))
    r = 0
    for b, B in rows:
        Bfull[r: r + B.shape[0], b.slice] = B
        r += B.shape[0]
    return names, np.concatenate(values), Bfull @ cov @ Bfull.T
