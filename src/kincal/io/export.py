"""Export a (calibrated) model to the formats controllers and ROS take (``kincal export``; docs/deploy.md).

- ``urdf``: an arm imported from a URDF (``kincal import``, which records the file and chain in the arm's
  ``meta.urdf``) is written back into that URDF with only the chain's joint origins changed
  (``kincal.io.urdf_patch``); a native arm becomes a clean URDF whose links are named after the joints.
- ``dh``, ``mdh``: the DH table (``kincal.kinematics.dh.to_dh``) with the base, flange and tool transforms
  that close it, and the largest forward-kinematics difference to the model at 200 random configurations.
  Nearly parallel consecutive axes (a calibrated model) are refused as ill-conditioned.
- ``controller``: the joint offsets per controller channel in motor units via the gear ratios.
- ``json``: the model file's content as JSON.
- ``ur-ros``: the kinematics file the Universal Robots ROS driver loads (``kincal.io.ur_ros``).

Tree-structured robots (``Robot.mounts``, docs/trees.md "Deploying"): ``export_tree`` writes the whole tree as
one branched URDF (``kincal.io.urdf.tree_to_urdf``: one base link, a tip per arm, shared joints once, single-joint
couplings as ``<mimic>``) or one controller document listing every arm's channels once (a torso's offsets are not
repeated per arm); ``export_text`` of one mounted arm writes its composite chain (carriers included, in the
world) for urdf, dh and mdh, and its own channels for controller.

Every file is written under a temporary name beside the target and renamed at the end; an existing target is
never overwritten unless asked.
"""

from __future__ import annotations

import json
from pathlib import Path

import yaml

from kincal.errors import DataFormatError
from kincal.io.atomic import output_file
from kincal.io.dh_table import dh_document, dh_text  # noqa: F401  (dh_document: part of this API)
from kincal.io.models import robot_to_dict
from kincal.io.ur_ros import ur_ros_text
from kincal.io.urdf import from_urdf, to_urdf, tree_to_urdf
from kincal.io.urdf_patch import patch_urdf
from kincal.kinematics import ArmModel, Robot
from kincal.kinematics.tree import tip_model

FORMATS = ("urdf", "dh", "mdh", "controller", "json", "ur-ros")
SIGN_CONVENTION = ("joint angle = controller reading + offset (theta = q + o); a controller that adds a "
                   "calibration offset to its reading takes these values as they are, one that subtracts takes "
                   "their negatives")


def export_text(robot: Robot, arm: str, fmt: str, model_file: Path | None = None, ur_hash: str | None = None) -> str:
    """The text of ``arm`` of ``robot`` in format ``fmt`` (``model_file``: where the model was read from, to
    resolve a recorded URDF path; ``ur_hash``: the robot's calibration checksum for ``ur-ros``)."""
    if fmt not in FORMATS:
        raise DataFormatError(f"--to {fmt!r}: expected one of {', '.join(FORMATS)}")
    a = robot[arm]
    if fmt == "urdf":
        return _urdf(a, model_file) if len(robot.lineage(arm)) == 1 else to_urdf(tip_model(robot, arm))
    if fmt in ("dh", "mdh"):
        return dh_text(tip_model(robot, arm), modified=fmt == "mdh")
    if fmt == "controller":
        return yaml.safe_dump(controller_document(a), sort_keys=False)
    if fmt == "ur-ros":
        return ur_ros_text(a, str(model_file or robot.name), ur_hash)[0]
    return json.dumps(robot_to_dict(robot), indent=2) + "\n"


TREE_FORMATS = ("urdf", "controller")
OFFSET_UNITS = {"offset_joint": "rad (m for prismatic joints)", "offset_motor": "motor rad (motor m) = offset x gear ratio"}


def export_tree(robot: Robot, fmt: str) -> tuple[str, list[str]]:
    """(text, notes) of every arm of a tree-structured ``robot`` in one file: a branched URDF or the controller
    offsets of every arm once (module docstring)."""
    if fmt not in TREE_FORMATS:
        raise DataFormatError(f"--to {fmt}: a tree-structured robot ({', '.join(robot.arms)}) is exported whole "
                              f"as {' or '.join(TREE_FORMATS)}; name an arm (--arm) for {fmt} of its chain")
    if fmt == "urdf":
        arms = [a for a in robot.arms if robot[a].meta and robot[a].meta.get("urdf")]
        if arms:
            raise DataFormatError(f"arm '{arms[0]}' was imported from a URDF chain (meta.urdf): patching a tree into "
                                  "its URDF is not supported; export that arm alone (--arm) or remove meta.urdf")
        return tree_to_urdf(robot)
    arms = [{"arm": arm, **({"mounted_on": robot.mounts[arm]} if arm in robot.mounts else {}),
             "channels": controller_document(robot[arm])["channels"]} for arm in robot.arms]
    doc = {"format": "kincal-controller-offsets", "robot": robot.name, "units": dict(OFFSET_UNITS),
           "sign_convention": SIGN_CONVENTION, "arms": arms}
    return yaml.safe_dump(doc, sort_keys=False), []


def write_text(path, text: str, overwrite: bool = False) -> Path:
    """Write ``text`` to ``path`` all or nothing (``kincal.io.atomic.output_file``)."""
    p = Path(path)
    with output_file(p, overwrite=overwrite) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return p


def _urdf(a: ArmModel, model_file: Path | None) -> str:
    src = a.meta.get("urdf") if a.meta else None
    if not src:
        return to_urdf(a)
    file = Path(str(src["file"]))
    if not file.is_absolute() and model_file is not None:
        file = model_file.parent / file
    if not file.is_file():
        raise DataFormatError(f"arm '{a.name}' was imported from {file}, which is not there any more: export needs "
                              "that URDF to patch (or remove meta.urdf to write a new one)")
    nominal = from_urdf(file, src["base_link"], src["tip_link"])
    return patch_urdf(file, src["base_link"], src["tip_link"], nominal, a)


def controller_document(a: ArmModel) -> dict:
    """Joint offsets per controller channel: rad at the joint and motor rad (offset x gear ratio)."""
    channels = []
    for c, j in enumerate(a.controller_order):
        o, g = float(a.offsets[j]), float(a.gear_ratios[j])
        channels.append({"channel": c + 1, "joint": a.joint_names[j], "offset_joint": o, "gear_ratio": g,
                         "offset_motor": o * g})
        if a.joint_names[j] in a.couplings:  # its reading follows others; its offset is its own
            channels[-1]["coupled"] = {k: float(v) for k, v in a.couplings[a.joint_names[j]].items()}
    return {"format": "kincal-controller-offsets", "arm": a.name, "units": dict(OFFSET_UNITS),
            "sign_convention": SIGN_CONVENTION, "channels": channels}


def import_urdf(path, base_link: str, tip_link: str, *, arm: str = "arm", name: str | None = None) -> Robot:
    """A one-arm Robot of the URDF chain, recording the file (absolute: a calibration's model.yaml is written
    elsewhere and carries it along) and the chain in the arm's ``meta.urdf`` so ``export --to urdf`` can patch
    it later."""
    p = Path(path)
    model = from_urdf(p, base_link, tip_link, name=arm)
    meta = {"urdf": {"file": str(p.resolve()), "base_link": base_link, "tip_link": tip_link}}
    return Robot(name or p.stem, {arm: model.replace(meta=meta)})
