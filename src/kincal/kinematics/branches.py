"""Gravity on tree-structured robots: the weights a tip's composite chain carries, its own and other branches'.

A tip's composite chain (``kincal.kinematics.tree``) carries the links of every segment of its lineage (centres
of mass mapped into the composite base frame at q = 0 by the same ``M_k`` as the screws) and the tip's payload.
Every other arm ``o`` of the tree mounted on an arm of the lineage (segment ``k``, after the composite chain's
first ``m`` joints) hangs its links and payload on link ``m - 1``: its mass ``M_o`` and first moment ``S_o``
(world) come from its own composite chain at the unloaded readings (its readings and the shared ones), so the
tip's carrier joints ``i < m`` see ``xi_i . (M_o g, S_o x g)`` on top of their own loads. The robot has one
gravity vector (the arms stating one agree, ``kincal.kinematics.model``).

Derivatives of those torques:

* a parameter of the lineage moves the hung weight with link ``m - 1`` (``gravity._Inserter`` on the folded
  masses), except a rigid transform inserted exactly at ``m`` that still carries the branch (the carrier's home
  and tool, i.e. segment index <= k): then ``gravity._Projected.moved_weight`` adds it;
* a parameter of ``o`` itself (offsets, twists, home, tool, base) or one of its readings moves its own links
  ``>= l`` and its payload by a world twist ``zeta = (v, w)`` of its chain: ``dS_o = M'_l v + w x S'_l`` (mass
  beyond l of ``o``'s own links), hence ``dtau_i = (M'_l u_i, S'_l x u_i) . zeta`` with ``u_i = g x w_i``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np

from kincal.errors import DataFormatError, ModelError
from kincal.kinematics.fk import Kinematics, chain, space_axes
from kincal.kinematics.elastic import chain_coupling, joint_compliance, loaded_chain
from kincal.kinematics.lateral import chain_lateral
from kincal.kinematics.gravity import GravityLoad, gravity_load, mass_beyond, weight_levers
from kincal.kinematics.model import Robot, lineage
from kincal.kinematics.tree import Composite, composite
from kincal.kinematics.twists import padded_bases
from kincal.lie import se3, so3


@dataclass(frozen=True)
class Branch:
    """Another arm ``arm`` hung on segment ``k`` of a lineage after its composite chain's first ``m`` joints:
    its composite chain ``comp`` and unloaded ``kin``, and the mass beyond each joint of its own links and
    payload ``M`` (n_o + 1,) with first moments ``S`` (N, n_o + 1, 3), world."""

    arm: str
    k: int
    m: int
    comp: Composite
    kin: Kinematics
    M: np.ndarray
    S: np.ndarray

    @property
    def hung(self) -> tuple[int, float, np.ndarray]:
        """(m, mass, first moment (N, 3)) as ``gravity.mass_beyond`` takes it."""
        return self.m, float(self.M[self.m]), self.S[:, self.m]


def composite_load(comp: Composite, loads: Sequence[GravityLoad | None], g: np.ndarray, own_from: int = 0
                   ) -> GravityLoad:
    """The composite chain's weights: every segment's links (coms mapped by ``M_k``) and the tip's payload;
    links before joint ``own_from`` weightless (another branch counts only its own links)."""
    masses = np.concatenate([np.zeros(n) if ld is None else ld.masses for ld, n in zip(loads, comp.sizes)])
    masses[:own_from] = 0.0
    coms = np.concatenate([np.zeros((n, 3)) if ld is None else ld.coms @ M[:3, :3].T + M[:3, 3]
                           for ld, n, M in zip(loads, comp.sizes, comp.frames)]).reshape(-1, 3)
    tip = loads[-1]
    return GravityLoad(masses, coms, 0.0 if tip is None else tip.payload_mass,
                       np.zeros(3) if tip is None else tip.payload_com, np.asarray(g, float))


def _weighs(load: GravityLoad | None) -> bool:
    return load is not None and (bool(np.any(load.masses)) or load.payload_mass != 0)


def tree_members(mounts: Mapping[str, str], arms, line: Sequence[str]) -> list[str]:
    """The arms of the tree of ``line`` (same root) not in ``line``."""
    return [a for a in arms if a not in line and lineage(mounts, a)[0] == line[0]]


def loading_branches(mounts: Mapping[str, str], loads: Mapping[str, GravityLoad | None], line: Sequence[str]
                     ) -> list[str]:
    """The other arms whose weight loads the joints of ``line`` (gravity on the tree and mass on the arm)."""
    others = tree_members(mounts, loads, line)
    if not any(loads[a] is not None for a in (*line, *others)):
        return []
    return [a for a in others if _weighs(loads[a])]


def model_loading_branches(robot: Robot, line: Sequence[str]) -> list[str]:
    """``loading_branches`` of a robot model, weighed by its arms' own mass models."""
    if not robot.mounts:
        return []
    return loading_branches(robot.mounts, {a: gravity_load(m) for a, m in robot.arms.items()}, line)


def tree_gravity(arms: Mapping, loads: Mapping[str, GravityLoad | None], mounts: Mapping[str, str],
                 line: Sequence[str], q: Mapping[str, np.ndarray], offsets: Mapping[str, np.ndarray]
                 ) -> tuple[GravityLoad | None, tuple[Branch, ...]]:
    """The weights of the composite chain of ``line`` and the other branches hung on it, at readings ``q``
    (arm -> (N, n)); (None, ()) when gravity loads nothing. ``arms``: name -> segment (screws, base, home,
    tool); ``offsets``: name -> joint offsets."""
    members = [*line, *tree_members(mounts, arms, line)]
    g = next((loads[a].g for a in members if loads[a] is not None), None)
    if g is None:
        return None, ()
    comp = composite([arms[s] for s in line])
    load = composite_load(comp, [loads[s] for s in line], g)
    branches = tuple(_branch(arms, loads, mounts, line, o, q, offsets, g)
                     for o in loading_branches(mounts, loads, line))
    if not branches and not _weighs(load):
        return None, ()
    return load, branches


def _branch(arms, loads, mounts, line, o, q, offsets, g) -> Branch:
    lin = lineage(mounts, o)
    if tuple(lin[:-1]) != tuple(line[: len(lin) - 1]):
        raise ModelError(f"arm '{o}': gravity on a tree: an arm off the lineage of '{line[-1]}' must be mounted on "
                         f"one of its arms ({', '.join(line)}), found on '{lin[-2]}'")
    if o not in q:
        raise DataFormatError(f"field q[{o}]: no readings of arm '{o}', whose weight loads the joints carrying "
                              f"arm '{line[-1]}'; expected its joint readings in the data set")
    comp = composite([arms[s] for s in lin])
    m = int(comp.starts[-2])
    theta0 = np.concatenate([np.asarray(q[s], float) + offsets[s] for s in lin], axis=-1)
    kin = chain(comp.screws, theta0, comp.base, comp.home, comp.tool)
    M, S = mass_beyond(composite_load(comp, [loads[s] for s in lin], g, own_from=m), kin.prefixes, kin.tool)
    return Branch(o, len(lin) - 2, m, comp, kin, M, S)


def branch_torque_derivatives(axes: np.ndarray, g: np.ndarray, b: Branch, generators: Sequence[np.ndarray],
                              base: np.ndarray, parts, C: np.ndarray) -> dict[str, np.ndarray]:
    """``C @ dtau/dp`` (N, k, d) for ``C`` (N, k, m) and the tip chain's joints before the branch (``axes`` (N, m, 6)
    their space axes at the unloaded readings; m = b.m, or 3 b.m on a chain expanded for lateral compliance) for
    the branch arm's own parts (offsets, twists, home, tool, base; ``readings`` too: as offsets); ``generators``
    and ``base``: the branch segment's own (its composite chain's are ``Ad(M_K) G``). A twist z moving the
    branch's weight beyond its joint l changes joint i's torque by ``(g x w_i) . (M'_l z_v + z_w x S'_l)``."""
    Cu = C @ so3.cross(g, axes[..., 3:])  # (N, k, 3)
    n, m, kin, MK = len(b.M) - 1, b.m, b.kin, b.comp.frames[-1]
    at = lambda l, Z: Cu @ weight_levers(b.M[l], b.S[:, l], Z)  # noqa: E731  (l (c,), Z (N, 6, c))
    out = {}
    if "offsets" in parts or "readings" in parts:
        j = np.arange(m, n)
        out["offsets"] = out["readings"] = at(j, np.swapaxes(space_axes(kin.prefixes[:, m:], b.comp.screws[m:]), -1, -2))
    if "twists" in parts:
        Ad = se3.adjoint(kin.prefixes[:, m:])
        Gen, keep = padded_bases([se3.adjoint(MK) @ Gj for Gj in generators])  # (n - m, 6, d)
        Z = np.moveaxis((Ad[:, :-1] - Ad[:, 1:]) @ Gen, 1, -1)  # (N, 6, d, n - m)
        Z = np.swapaxes(Z, -1, -2).reshape(Z.shape[:2] + (-1,))[..., keep]
        out["twists"] = at(m + keep // Gen.shape[-1], Z)
    one = lambda l, Z: at(np.full(Z.shape[-1], l), Z)  # noqa: E731
    if "home" in parts:
        out["home"] = one(n, se3.adjoint(kin.prefixes[:, n] @ MK))
    if "tool" in parts:
        out["tool"] = one(n, se3.adjoint(kin.flange))
    if "base" in parts:  # inserted left of its base: at P_m M_K base^-1
        out["base"] = one(m, se3.adjoint(kin.prefixes[:, m] @ MK @ se3.inverse(base)))
    return out


def loaded_tree(arms: Mapping, loads: Mapping[str, GravityLoad | None], compliances: Mapping[str, np.ndarray],
                mounts: Mapping[str, str], line: Sequence[str], q: Mapping[str, np.ndarray], wrench_tool=None
                ) -> Kinematics:
    """Kinematics of the composite chain of ``line`` (root first) at readings ``q`` (arm -> (N, n): the lineage's
    and, when the tree has gravity, the other loading arms'), deflected by the tool loads and by the weights of
    the tree (the branches hung on it ride along: ``LoadedKinematics.branches``). ``arms``: segments with screws,
    offsets, base, home and tool (``ArmModel`` or ``ArmValues``); ``compliances``: per arm of ``line`` its joint compliances at its readings, (n,) or (N, n)."""
    load, branches = tree_gravity(arms, loads, mounts, line, q, {a: m.offsets for a, m in arms.items()})
    comp = composite([arms[s] for s in line])
    theta0 = np.concatenate([q[s] + arms[s].offsets for s in line], axis=-1)
    if load is None and wrench_tool is None:
        return chain(comp.screws, theta0, comp.base, comp.home, comp.tool)
    cs = [np.asarray(compliances[s], dtype=float) for s in line]
    if any(x.ndim == 2 for x in cs):  # a joint's compliance depends on its angle: every segment per sample
        cs = [np.broadcast_to(x, theta0.shape[:-1] + x.shape[-1:]) for x in cs]
    c = np.concatenate(cs, axis=-1)
    segs = [arms[s] for s in line]
    kin = loaded_chain(comp.screws, theta0, comp.base, comp.home, comp.tool, c, wrench_tool, load,
                       [b.hung for b in branches], chain_lateral(segs, comp.frames), chain_coupling(segs))
    return replace(kin, branches=branches)


def tree_loaded_kinematics(robot: Robot, arm: str, readings: Mapping[str, np.ndarray], wrench_tool=None
                           ) -> Kinematics:
    """Kinematics of ``arm`` through its carriers at ``readings`` (``loaded_tree``) for a robot model: what a tip
    of a sagging tree measures."""
    line = robot.lineage(arm)
    q = {a: np.asarray(v, float) for a, v in readings.items()}
    return loaded_tree(robot.arms, {a: gravity_load(m) for a, m in robot.arms.items()},
                       {s: joint_compliance(robot[s], q[s]) for s in line}, robot.mounts, line, q, wrench_tool)
