"""Write a calibrated arm back into the URDF its nominal model came from (``kincal export --to urdf``).

Only the chain from ``base_link`` to ``tip_link`` changes, and in it only joint origins: every link name,
visual, collision, inertial, limit, every joint outside the chain and every other element stays as it was.

Each moving joint keeps its axis vector (in its own frame); its frame is turned by the smallest rotation that
takes the axis onto the calibrated one and moved to the point of the calibrated axis closest to where it was,
with the joint offsets folded in (the frames at reading zero: ``E_{i-1} F_i`` with ``E_k = exp(xi_1 o_1) ...
exp(xi_k o_k)``). A change of the base moves the whole chain inside ``base_link``, and the first fixed joint
after the last moving one takes what remains up to ``tip_link`` (with a calibrated tool frame folded into it,
so that the URDF's tip with the nominal tool frame is the calibrated tool). The forward kinematics of the
patched URDF equal the calibrated model's to round-off.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from kincal.errors import DataFormatError, ModelError
from kincal.kinematics.model import PRISMATIC, ArmModel
from kincal.lie import se3, so3
from kincal.lie.rotations import matrix_to_rpy, rpy_to_matrix


def patch_urdf(source, base_link: str, tip_link: str, nominal: ArmModel, calibrated: ArmModel) -> str:
    """The URDF text of ``source`` (a path or URDF text) with the chain ``base_link`` -> ``tip_link`` set to
    ``calibrated``; ``nominal`` is the model ``from_urdf`` read from the same chain."""
    tree, label, prolog = _parse(source)
    root = tree.getroot()
    chain = _chain(root, base_link, tip_link, label)
    moving = [j for j in chain if j.get("type") != "fixed"]
    names = [j.get("name") for j in moving]
    if tuple(names) != tuple(calibrated.joint_names):
        raise ModelError(f"{label}: the chain {base_link} -> {tip_link} has joints {names}; the calibrated model "
                         f"has {list(calibrated.joint_names)}: export needs the URDF the model was imported from")
    after = chain[chain.index(moving[-1]) + 1:]
    if not after:
        raise ModelError(f"{label}: no fixed joint between the last moving joint {names[-1]!r} and {tip_link!r} "
                         "to take the calibrated flange; add one (e.g. a 'flange' link) and import again")
    frames, tip = _targets(chain, moving, nominal, calibrated)
    link = np.eye(4)  # pose of the current parent link in base_link at reading zero
    for j in chain:
        if j in moving:
            new = frames[moving.index(j)]
        elif j is after[0]:
            new = tip @ se3.inverse(_fixed_tail(after[1:]))
        else:  # other fixed joints stay as written
            link = link @ _origin(j)
            continue
        _set_origin(j, se3.inverse(link) @ new)
        link = new
    return prolog + ET.tostring(root, encoding="unicode") + "\n"


def _targets(chain, moving, nominal: ArmModel, cal: ArmModel):
    """New frames (base_link coordinates, reading zero) of the moving joints, and the tip link's."""
    C = se3.inverse(nominal.base) @ cal.base
    nominal_frames, F = [], np.eye(4)
    for j in chain:
        F = F @ _origin(j)
        if j in moving:
            nominal_frames.append(F)
    E = np.eye(4)
    frames = []
    for i, j in enumerate(moving):
        axis = _axis(j)
        v, w = se3.split(cal.screws[i])
        prismatic = cal.joint_types[i] == PRISMATIC
        direction = v / np.linalg.norm(v) if prismatic else w
        Fn = nominal_frames[i]
        R = _align(Fn[:3, :3] @ axis, direction) @ Fn[:3, :3]
        p = Fn[:3, 3] if prismatic else _closest_on_axis(Fn[:3, 3], w, np.cross(w, v))
        frames.append(C @ E @ se3.make(R, p))
        E = E @ se3.exp(cal.screws[i] * cal.offsets[i])
    tip = C @ E @ cal.home @ cal.tool @ se3.inverse(nominal.tool)
    return frames, tip


def _align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a onto unit vector b."""
    c = np.cross(a, b)
    s, cos = np.linalg.norm(c), float(np.dot(a, b))
    if s < 1e-15:
        if cos > 0:
            return np.eye(3)
        raise ModelError("a calibrated joint axis points opposite to the URDF's: not a calibration of this URDF")
    return so3.exp(c / s * np.arctan2(s, cos))


def _closest_on_axis(p: np.ndarray, w: np.ndarray, point: np.ndarray) -> np.ndarray:
    return point + np.dot(p - point, w) * w


def _fixed_tail(joints) -> np.ndarray:
    T = np.eye(4)
    for j in joints:
        T = T @ _origin(j)
    return T


def _parse(source):
    """(tree, label, prolog): the prolog is the text before the root element (declaration, comments), which
    the tree does not keep."""
    text = isinstance(source, str) and source.lstrip().startswith("<")
    label = "<urdf string>" if text else str(source)
    try:
        raw = source if text else Path(source).read_text(encoding="utf-8")
        parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
        tree = ET.ElementTree(ET.fromstring(raw, parser))
    except (ET.ParseError, OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{label}: cannot read URDF: {exc}") from None
    start = raw.find("<" + tree.getroot().tag)
    return tree, label, raw[:start] if start > 0 else ""


def _chain(root, base_link: str, tip_link: str, label: str) -> list:
    by_child = {j.find("child").get("link"): j for j in root.findall("joint") if j.find("child") is not None}
    chain, link = [], tip_link
    while link != base_link:
        if link not in by_child:
            raise DataFormatError(f"{label}: {tip_link!r} is not below {base_link!r}")
        chain.append(by_child[link])
        link = by_child[link].find("parent").get("link")
    return chain[::-1]


def _origin(joint) -> np.ndarray:
    o = joint.find("origin")
    xyz = np.array([float(x) for x in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split()])
    rpy = np.array([float(x) for x in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split()])
    return se3.make(rpy_to_matrix(rpy), xyz)


def _axis(joint) -> np.ndarray:
    a = joint.find("axis")
    v = np.array([float(x) for x in (a.get("xyz") if a is not None else "1 0 0").split()])
    return v / np.linalg.norm(v)


def _set_origin(joint, T: np.ndarray) -> None:
    o = joint.find("origin")
    if o is None:
        o = ET.SubElement(joint, "origin")
    o.set("xyz", " ".join(repr(float(x)) for x in T[:3, 3]))
    o.set("rpy", " ".join(repr(float(x)) for x in matrix_to_rpy(T[:3, :3])))


__all__ = ["patch_urdf"]
