"""URDF files <-> POE: read a chain base_link -> tip_link as an ArmModel (via yourdfpy), write an ArmModel as URDF.

Import: the joint frames are composed at q = 0 along the chain (fixed joints fold into the next
transform). Joint i with URDF origin ``O_i`` and unit axis ``a_i`` (in its own frame) sits at
``F_i = O_1 ... O_i`` (fixed origins included); its twist is ``(-w x p, w)`` with ``w = R(F_i) a_i``,
``p = t(F_i)`` (revolute, continuous) or ``(w, 0)`` (prismatic); ``home = T_base_link_tip_link`` at q = 0.
Revolute/prismatic limits are kept (missing lower/upper attributes mean unlimited); continuous joints
are unlimited. URDF axes are normalized (URDF
treats ``axis`` as a direction). Floating and planar joints are refused, and so are mimic joints in a chain import
(``tree_from_urdf`` reads them as couplings).
Inertials (``inertials=True``): each link's ``<inertial>`` mass and origin, lumped per moving joint of the chain
(a link belongs to the last chain joint on its path from base_link: links on fixed joints, side branches and
links beyond tip_link included, other joints at zero), centres of mass in base_link's frame at q = 0; the
gravity vector is not in URDF: give ``gravity=`` (``ArmModel``) for the weights to load the joints.

Branched URDFs (``tree_from_urdf``): one base link and several tip links (given, or every leaf link) become a
``Robot`` with mounted arms (``Robot.mounts``), split at the links where the tips' chains part: the chain from
the base to the first such link is an arm of its own (a torso, named after that link), and each arm below it is
mounted on it with ``base`` = identity (its chain starts at the torso's end link, which is the torso's home).
A segment without moving joints is folded into the bases of the segments below it.

Mimic joints (``tree_from_urdf``, or ``from_urdf(mimic=True)``) become joint couplings of their arm.

Export of a tree (``tree_to_urdf``): every arm in one URDF, each mounted arm hung on its carrier's tool link; a
coupling on one joint is written as ``<mimic>``. Export (``to_urdf``): one link per joint (named ``<joint>_link``), every joint frame parallel to the arm base
frame at q = 0,
so axes are generally not along z; joint offsets are folded into the origins
(``exp(xi (q + o)) = F exp(xi_local o) exp(xi_local q) F^-1``). Meant for cross-checks (pinocchio).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from kincal.errors import DataFormatError, ModelError
from kincal.kinematics.couplings import CONSTANT, coupling_map
from kincal.kinematics.model import PRISMATIC, REVOLUTE, ArmModel, Robot
from kincal.lie import se3
from kincal.lie.rotations import matrix_to_rpy

_MOVING = {"revolute": REVOLUTE, "continuous": REVOLUTE, "prismatic": PRISMATIC}


def _yourdfpy():
    try:  # optional extra (kincal[urdf]), imported only when a URDF is read
        import yourdfpy
    except ImportError:
        raise ModelError(
            "URDF import needs the optional package 'yourdfpy': pip install 'kincal[urdf]'"
        ) from None
    return yourdfpy


def _load(source):
    """yourdfpy.URDF from a path or from URDF text (a string starting with '<')."""
    yourdfpy = _yourdfpy()
    text = isinstance(source, str) and source.lstrip().startswith("<")
    label = "<urdf string>" if text else str(source)
    if not text and not Path(source).is_file():
        raise DataFormatError(f"{label}: no such URDF file")
    handle = io.BytesIO(source.encode("utf-8")) if text else str(source)
    try:
        return yourdfpy.URDF.load(handle, build_scene_graph=False, load_meshes=False,
                                  load_collision_meshes=False, build_collision_scene_graph=False), label
    except Exception as exc:  # yourdfpy/lxml raise many kinds; report them as a format error
        raise DataFormatError(f"{label}: cannot parse URDF: {exc}") from None


def _chain(robot, base_link: str, tip_link: str, label: str) -> list:
    """Joints from base_link to tip_link, in order."""
    links = set(robot.link_map)
    for role, link in (("base_link", base_link), ("tip_link", tip_link)):
        if link not in links:
            known = ", ".join(sorted(links))
            raise DataFormatError(f"{label}: {role} {link!r} is not a link of the URDF (links: {known})")
    parent_joint = {j.child: j for j in robot.joint_map.values()}
    chain, link = [], tip_link
    while link != base_link:
        if link not in parent_joint:
            raise DataFormatError(f"{label}: tip_link {tip_link!r} is not below base_link {base_link!r}")
        joint = parent_joint[link]
        chain.append(joint)
        link = joint.parent
    return chain[::-1]


def from_urdf(source, base_link: str, tip_link: str, *, name: str | None = None, inertials: bool = True,
              mimic: bool = False, **model_fields) -> ArmModel:
    """ArmModel of the URDF chain from ``base_link`` to ``tip_link`` (``home = T_base_link_tip_link`` at q = 0).

    ``source`` is a URDF file path or URDF text. ``model_fields`` go to ArmModel (base, tool, gear_ratios,
    gravity, ...). Joint names are the URDF joint names. ``inertials``: read the links' masses and centres of
    mass (module docstring). ``mimic``: read mimic joints as couplings (``ArmModel.couplings``: the joint's
    reading is ``multiplier x`` the mimicked joint's ``+ offset``; both in the chain), else refuse them.
    """
    robot, label = _load(source)
    couplings = {}
    T = np.eye(4)
    screws, names, types, lower, upper = [], [], [], [], []
    for joint in _chain(robot, base_link, tip_link, label):
        origin = np.eye(4) if joint.origin is None else np.asarray(joint.origin, dtype=float)
        T = T @ origin
        if joint.type == "fixed":
            continue
        if joint.type not in _MOVING:
            raise DataFormatError(
                f"{label}: joint {joint.name!r}: type {joint.type!r} is not supported in a serial chain"
            )
        if joint.mimic is not None and not mimic:
            raise DataFormatError(f"{label}: joint {joint.name!r}: mimic joints are not supported in a chain import "
                                  "(tree_from_urdf reads them as joint couplings)")
        if joint.mimic is not None:
            couplings[joint.name] = {joint.mimic.joint: float(1.0 if joint.mimic.multiplier is None
                                                              else joint.mimic.multiplier),
                                     CONSTANT: float(joint.mimic.offset or 0.0)}
        axis = np.asarray(joint.axis, dtype=float)
        norm = np.linalg.norm(axis)
        if not np.isfinite(norm) or norm < 1e-9:
            raise DataFormatError(
                f"{label}: joint {joint.name!r}: axis must be a non-zero vector, found {axis.tolist()}"
            )
        w = T[:3, :3] @ (axis / norm)
        kind = _MOVING[joint.type]
        screws.append(se3.join(-np.cross(w, T[:3, 3]), w) if kind == REVOLUTE else se3.join(w, np.zeros(3)))
        limit = joint.limit
        bounded = (joint.type != "continuous" and limit is not None
                   and limit.lower is not None and limit.upper is not None)
        lower.append(float(limit.lower) if bounded else -np.inf)
        upper.append(float(limit.upper) if bounded else np.inf)
        if not lower[-1] < upper[-1]:
            raise DataFormatError(
                f"{label}: joint {joint.name!r}: limit needs lower < upper, found {lower[-1]}, {upper[-1]}"
            )
        names.append(joint.name)
        types.append(kind)
    if not screws:
        raise DataFormatError(f"{label}: no moving joint between {base_link!r} and {tip_link!r}")
    for joint, terms in couplings.items():
        lead = next(iter(terms))
        if lead not in names:
            raise DataFormatError(f"{label}: joint {joint!r}: mimics joint {lead!r}, which is not a moving joint of "
                                  f"the chain {base_link!r} -> {tip_link!r}")
    if couplings:
        model_fields.setdefault("couplings", couplings)
    model_fields.setdefault("lower", lower)
    model_fields.setdefault("upper", upper)
    if inertials:
        masses, coms = _link_inertials(robot, base_link, names, label)
        if np.any(masses):
            model_fields.setdefault("link_masses", masses)
            model_fields.setdefault("link_coms", coms)
    return ArmModel(name or f"{base_link}->{tip_link}", np.array(screws), T, joint_names=tuple(names),
                    joint_types=tuple(types), **model_fields)


def tree_from_urdf(source, base_link: str, tips: dict[str, str] | None = None, *, name: str | None = None) -> Robot:
    """A tree-structured Robot from a branched URDF: ``tips`` maps arm name -> tip link (default: every leaf link,
    each arm named after its link). Arms are split at the links where the tips' chains part (module docstring);
    joint names are the URDF's."""
    robot, label = _load(source)
    if tips is None:
        parents = {j.parent for j in robot.joint_map.values()}
        tips = {link: link for link in robot.link_map if link not in parents and link != base_link}
    if not tips:
        raise DataFormatError(f"{label}: no tip link below base_link {base_link!r}")
    paths = {arm: [base_link] + [j.child for j in _chain(robot, base_link, tip, label)] for arm, tip in tips.items()}
    splits = {_common(paths[a], paths[b])[-1] for a in paths for b in paths if a < b}
    arms, mounts, carried = {}, {}, {}
    for arm, path in paths.items():
        cuts = [base_link] + [link for link in path[1:-1] if link in splits] + [path[-1]]
        for start, end in zip(cuts[:-1], cuts[1:]):
            key = arm if end == path[-1] else end
            if key in arms or key in carried:
                continue
            base = carried.get(start, np.eye(4))  # a fixed segment above folds into this base
            parent = next((k for k in arms if k == start), None)
            try:
                arms[key] = from_urdf(source, start, end, name=key, base=base, mimic=True)
            except DataFormatError as exc:
                if "no moving joint" not in str(exc):
                    raise
                carried[end] = base @ _fixed(robot, start, end, label)
                continue
            if parent is not None:
                mounts[key] = parent
    return Robot(name or robot.robot.name, arms, {"source": f"{label} (branched URDF from {base_link})"}, mounts)


def _common(a: list, b: list) -> list:
    """The common start of two link paths."""
    n = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
    return a[:n]


def _fixed(robot, start: str, end: str, label: str) -> np.ndarray:
    """``T_start_end`` of a chain of fixed joints."""
    T = np.eye(4)
    for joint in _chain(robot, start, end, label):
        T = T @ (np.eye(4) if joint.origin is None else np.asarray(joint.origin, dtype=float))
    return T


def _link_inertials(robot, base_link: str, joints: list[str], label: str) -> tuple[np.ndarray, np.ndarray]:
    """Per moving chain joint (``joints``, in order) the mass (kg) of the links it carries before the next one,
    and their centre of mass in base_link's frame at q = 0 (zeros without mass)."""
    index = {name: i for i, name in enumerate(joints)}
    children: dict[str, list] = {}
    for j in robot.joint_map.values():
        children.setdefault(j.parent, []).append(j)
    mass, moment = np.zeros(len(joints)), np.zeros((len(joints), 3))
    stack = [(base_link, np.eye(4), None)]
    while stack:  # every link below base_link once (URDF links form a tree)
        link, T, owner = stack.pop()
        inertial = robot.link_map[link].inertial
        if inertial is not None and inertial.mass is not None and not float(inertial.mass) >= 0:
            raise DataFormatError(f"{label}: link {link!r}: inertial mass must be >= 0 kg, found {inertial.mass}")
        if owner is not None and inertial is not None and inertial.mass:
            origin = np.eye(4) if inertial.origin is None else np.asarray(inertial.origin, dtype=float)
            mass[owner] += float(inertial.mass)
            moment[owner] += float(inertial.mass) * (T @ origin)[:3, 3]
        for j in children.get(link, []):
            origin = np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float)
            stack.append((j.child, T @ origin, index.get(j.name, owner)))
    return mass, np.divide(moment, mass[:, None], out=np.zeros_like(moment), where=mass[:, None] > 0)


def _origin_xml(T: np.ndarray) -> str:
    xyz = " ".join(repr(float(x)) for x in T[:3, 3])
    rpy = " ".join(repr(float(x)) for x in matrix_to_rpy(T[:3, :3]))
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def to_urdf(model: ArmModel, *, root: str = "world", flange: str = "flange", tip: str = "tool") -> str:
    """URDF text of ``model``: links ``root`` -> ``base`` -> ``<joint>_link`` per joint -> ``flange`` -> ``tip``.

    Joint names are the model's joint names. Revolute joints with infinite limits become 'continuous';
    prismatic joints need finite limits (URDF requires them).
    """
    rows = [f'<robot name="{model.name}">', f'  <link name="{root}"/>']
    rows += _arm_rows(model, root, "", "base", flange, tip, {})
    rows.append("</robot>")
    return "\n".join(rows) + "\n"


def tree_to_urdf(robot: Robot, *, root: str = "world") -> tuple[str, list[str]]:
    """One branched URDF of every arm of ``robot`` (text, notes): links ``<arm>_base`` -> ``<arm>_<joint>_link``
    -> ``<arm>_flange`` -> ``<arm>`` (the arm's tool), a mounted arm's base joint hung on its carrier's tool link
    ``<carrier>``, joints named ``<arm>_<joint>`` (shared joints once). A coupling on one joint becomes a
    ``<mimic>`` (readings: joint offsets are folded into the origins); one on several joints cannot be written
    in URDF: the joint is written free and a note says so. ``tree_from_urdf(text, root)`` reads it back with the
    same arms, mounts and forward kinematics."""
    rows, notes = [f'<robot name="{robot.name}">', f'  <link name="{root}"/>'], []
    for arm in sorted(robot.arms, key=lambda a: len(robot.lineage(a))):  # carriers before what they carry
        model, line = robot[arm], robot.lineage(arm)
        mimics, dropped = _mimics(model, f"{arm}_")
        notes += [f"arm '{arm}': joint {j} follows several joints ({', '.join(d)}); URDF's mimic takes one: "
                  f"written as a free joint (give its reading)" for j, d in dropped.items()]
        parent = root if len(line) == 1 else line[-2]
        rows += _arm_rows(model, parent, f"{arm}_", f"{arm}_base", f"{arm}_flange", arm, mimics)
    rows.append("</robot>")
    return "\n".join(rows) + "\n", notes


def _mimics(model: ArmModel, prefix: str) -> tuple[dict[str, str], dict[str, list[str]]]:
    """(joint -> ``<mimic>`` element, joint -> its several leading joints) of ``model``'s couplings, resolved
    through chains of couplings (``kincal.kinematics.couplings.coupling_map``)."""
    A, b = coupling_map(model.couplings, model.joint_names)
    out, dropped = {}, {}
    for j in model.couplings:
        i = model.joint_names.index(j)
        lead = np.flatnonzero(A[i])
        if len(lead) == 1:
            out[j] = (f'<mimic joint="{prefix}{model.joint_names[lead[0]]}" multiplier="{float(A[i, lead[0]])!r}" '
                      f'offset="{float(b[i])!r}"/>')
        else:
            dropped[j] = [model.joint_names[k] for k in lead]
    return out, dropped


def _arm_rows(model: ArmModel, parent: str, prefix: str, base: str, flange: str, tip: str, mimics) -> list[str]:
    """The links and joints of ``model`` hung on link ``parent`` (``to_urdf``)."""
    rows = [f'  <link name="{base}"/>']
    rows += _joint_xml(f"{prefix}base_joint", "fixed", parent, base, model.base)
    previous, prev_link = np.eye(4), base
    for i, (jname, kind) in enumerate(zip(model.joint_names, model.joint_types)):
        v, w = se3.split(model.screws[i])
        if kind == REVOLUTE:
            point, axis = np.cross(w, v), w
            local = se3.join(np.zeros(3), w)  # the screw seen from a frame at `point`, parallel to the base
        else:
            point, axis = previous[:3, 3], v
            local = se3.join(v, np.zeros(3))
        frame = se3.make(np.eye(3), point)
        origin = se3.inverse(previous) @ frame @ se3.exp(local * model.offsets[i])
        link = f"{prefix}{jname}_link"
        rows.append(f'  <link name="{link}"/>')
        lo, up = model.lower[i], model.upper[i]
        if kind == REVOLUTE and not (np.isfinite(lo) and np.isfinite(up)):
            jtype, limit = "continuous", ""
        else:
            if not (np.isfinite(lo) and np.isfinite(up)):
                raise ModelError(
                    f"arm '{model.name}': joint {jname} is prismatic without finite limits; URDF needs them"
                )
            jtype = "revolute" if kind == REVOLUTE else "prismatic"
            limit = f'<limit lower="{float(lo)!r}" upper="{float(up)!r}" effort="0" velocity="0"/>'
        axis_xml = f'<axis xyz="{" ".join(repr(float(a)) for a in axis)}"/>'
        rows += _joint_xml(f"{prefix}{jname}", jtype, prev_link, link, origin, axis_xml + limit + mimics.get(jname, ""))
        previous, prev_link = frame, link
    rows += [f'  <link name="{flange}"/>', f'  <link name="{tip}"/>']
    rows += _joint_xml(f"{prefix}flange_joint", "fixed", prev_link, flange, se3.inverse(previous) @ model.home)
    rows += _joint_xml(f"{prefix}tool_joint", "fixed", flange, tip, model.tool)
    return rows


def _joint_xml(name: str, jtype: str, parent: str, child: str, origin: np.ndarray, extra: str = "") -> list[str]:
    return [
        f'  <joint name="{name}" type="{jtype}">',
        f'    <parent link="{parent}"/><child link="{child}"/>',
        f"    {_origin_xml(origin)}{extra}",
        "  </joint>",
    ]
