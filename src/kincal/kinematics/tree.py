"""Tree-structured robots: a tip arm carried by its ancestors is one serial POE chain (the composite chain).

A mounted arm's world pose is ``FK(parent at its readings) @ FK(child)``, with the child's ``base`` being
``T_parenttool_childbase``. For the segments ``s_0 (root) .. s_K (tip)`` write ``C_k = home_{k-1} tool_{k-1}
base_k`` and ``M_k = C_1 .. C_k`` (``M_0 = I``). Moving every ``C_k`` to the right of the later joints gives one
chain with

* screws ``[xi_0; Ad(M_1) xi_1; ..; Ad(M_K) xi_K]`` (generators ``Ad(M_k) G_j``: a twist retraction commutes
  with the constant ``Ad(M_k)``), base ``base_0``, home ``M_K home_K``, tool ``tool_K``;

so forward kinematics, loads (a tool wrench loads the ancestors' joints too), compliance and
``tool_jacobians`` work unchanged on it. The segments' own blocks follow by constant maps: offsets, twists and
compliance are column slices, the tip's home is the composite home times ``Ad(M_K)``, and an ancestor's home and
tool and the next segment's base are rigid transforms inserted after the ancestor's last joint
(``kincal.kinematics.jacobians.insertion_jacobians``), at ``P_m X`` with ``P_m`` the composite prefix and
``X = M_k``, ``M_k home_k`` and ``M_k home_k tool_k`` respectively.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from kincal.kinematics.couplings import CONSTANT
from kincal.kinematics.fk import Kinematics, chain
from kincal.kinematics.lateral import chain_lateral
from kincal.kinematics.model import ArmModel, Robot
from kincal.lie import se3


@dataclass(frozen=True)
class Composite:
    """The composite chain of segments (root first): ``screws`` (n, 6), ``base``, ``home``, ``tool`` (4, 4),
    ``frames`` (K + 1, 4, 4) the ``M_k``, ``sizes`` joints per segment, ``starts`` their first joint index."""

    screws: np.ndarray
    base: np.ndarray
    home: np.ndarray
    tool: np.ndarray
    frames: np.ndarray
    sizes: tuple[int, ...]

    @property
    def starts(self) -> np.ndarray:
        return np.concatenate([[0], np.cumsum(self.sizes)])

    def split(self, a: np.ndarray, widths: Sequence[int] | None = None) -> list[np.ndarray]:
        """The last axis of ``a`` cut per segment (by joints, or by ``widths`` per segment)."""
        cut = np.cumsum(self.sizes if widths is None else widths)[:-1]
        return np.split(a, cut, axis=-1)

    def generators(self, per_segment: Sequence[Sequence[np.ndarray]]) -> tuple:
        """The composite joints' generators ``Ad(M_k) G_j`` from each segment's own."""
        return tuple(se3.adjoint(M) @ G for M, gens in zip(self.frames, per_segment) for G in gens)


def composite(segments: Sequence) -> Composite:
    """The composite chain of ``segments`` (root first; anything with screws, base, home, tool: ``ArmModel`` or
    ``kincal.params.ArmValues``)."""
    frames = [np.eye(4)]
    for prev, seg in zip(segments[:-1], segments[1:]):
        frames.append(frames[-1] @ prev.home @ prev.tool @ seg.base)
    screws = np.concatenate([s.screws @ se3.adjoint(M).T for s, M in zip(segments, frames)])
    return Composite(screws, np.asarray(segments[0].base, float), frames[-1] @ segments[-1].home,
                     np.asarray(segments[-1].tool, float), np.stack(frames), tuple(s.screws.shape[0] for s in segments))


def insertion_points(comp: Composite, segments: Sequence) -> list[tuple[int, str, int, np.ndarray]]:
    """(segment index, part, m, X) for each segment's home and tool below the tip and each mounted segment's
    base: the rigid transform sits at ``P_m X`` of the composite chain (``P_m`` its prefix after m joints)."""
    out = []
    starts = comp.starts
    for k, seg in enumerate(segments[:-1]):
        m, M = int(starts[k + 1]), comp.frames[k]
        out.append((k, "home", m, M))
        out.append((k, "tool", m, M @ seg.home))
        out.append((k + 1, "base", m, M @ seg.home @ seg.tool))
    return out


def joined(readings: Mapping[str, np.ndarray], names: Sequence[str]) -> np.ndarray:
    """The readings of the arms ``names`` side by side (..., n_total)."""
    return np.concatenate([np.asarray(readings[a], dtype=float) for a in names], axis=-1)


def tip_model(robot: Robot, arm: str) -> ArmModel:
    """``arm`` with its ancestors as one ArmModel (joints named ``<segment>.<joint>``, readings side by side in
    ``Robot.lineage`` order): its forward kinematics is the tip's world pose; the arm itself when not mounted.
    It carries every segment's link masses (centres of mass mapped by ``M_k``), the tip's payload and the
    tree's gravity; not the other branches' weights (``kincal.kinematics.branches``)."""
    line = robot.lineage(arm)
    if len(line) == 1:
        return robot[arm]
    segs = [robot[a] for a in line]
    comp = composite(segs)
    names = tuple(f"{a}.{j}" for a, s in zip(line, segs) for j in s.joint_names)
    cat = lambda key: np.concatenate([getattr(s, key) for s in segs])  # noqa: E731
    nodes = {f"{a}.{j}": t for a, s in zip(line, segs) for j, t in s.compliance_nodes.items()}
    couplings = {f"{a}.{j}": {(k if k == CONSTANT else f"{a}.{k}"): v for k, v in terms.items()}
                 for a, s in zip(line, segs) for j, terms in s.couplings.items()}
    return ArmModel(f"{arm} (on {', '.join(line[:-1])})", comp.screws, comp.home, base=comp.base, tool=comp.tool,
                    offsets=cat("offsets"), lower=cat("lower"), upper=cat("upper"), gear_ratios=cat("gear_ratios"),
                    joint_names=names, joint_types=sum((s.joint_types for s in segs), ()),
                    compliance=cat("compliance"), compliance_nodes=nodes, couplings=couplings,
                    link_masses=cat("link_masses"),
                    link_coms=np.concatenate([s.link_coms @ M[:3, :3].T + M[:3, 3] for s, M in zip(segs, comp.frames)]),
                    payload_mass=segs[-1].payload_mass, payload_com=segs[-1].payload_com,
                    gravity=next((s.gravity for s in segs if s.gravity is not None), None),
                    **_tip_lateral(segs, comp))


def _tip_lateral(segs, comp: Composite) -> dict:
    """The composite's lateral compliance (``kincal.kinematics.lateral.chain_lateral``), when a segment has it."""
    lat = chain_lateral(segs, comp.frames)
    if lat is None:
        return {}
    negative = any(s.allow_negative_compliance for s in segs)
    return {"lateral": lat[1], "lateral_axes": lat[0], "allow_negative_compliance": negative}


def tip_kinematics(robot: Robot, arm: str, readings: Mapping[str, np.ndarray]) -> Kinematics:
    """Kinematics of the tip ``arm`` at ``readings`` (arm -> (..., n_arm), its ancestors' included)."""
    line = robot.lineage(arm)
    segs = [robot[a] for a in line]
    comp = composite(segs)
    theta = np.concatenate([np.asarray(readings[a], float) + s.offsets for a, s in zip(line, segs)], axis=-1)
    return chain(comp.screws, theta, comp.base, comp.home, comp.tool)


def tip_pose(robot: Robot, arm: str, readings: Mapping[str, np.ndarray]) -> np.ndarray:
    """``T_world_tool`` of ``arm`` at ``readings`` (arm -> (..., n_arm), ancestors included): (..., 4, 4)."""
    return tip_kinematics(robot, arm, readings).tool
