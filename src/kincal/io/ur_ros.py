"""The kinematics file of the Universal Robots ROS driver (``kincal export --to ur-ros``; docs/deploy.md).

The driver's description (``ur_description``, ROS 1 and ROS 2) builds the arm from a ``kinematics_params_file``
(``kinematics_parameters_file`` in the xacro): per link ``shoulder, upper_arm, forearm, wrist_1, wrist_2,
wrist_3`` a joint origin ``x, y, z, roll, pitch, yaw`` (URDF: ``Trans(x, y, z) Rz(yaw) Ry(pitch) Rx(roll)``)
followed by the joint's rotation about z, starting in ``base_link_inertia`` (``base_link`` turned by pi about
z, the controller's Base frame) and ending in ``wrist_3_link``, which is ``tool0``. ``hash`` is the robot's
calibration checksum, which the driver compares with the connected robot's at start-up (and logs an error when
they differ). ``ur_calibration`` writes the file from the controller's DH table; kincal writes it from a
calibrated model:

- kincal's arm base frame is the controller's Base frame (``base_link_inertia``), as in the built-in ``ur10``;
- each link frame sits on its calibrated joint axis (with the joint offsets folded in: the frames at
  controller reading zero), at the foot of the common normal to the next axis, or for (nearly) parallel axes
  at the axis point closest to the previous frame's origin; its x axis is the previous x axis made
  perpendicular. For the nominal UR this gives the driver's own default file;
- ``tool0`` must lie on joint 6's axis with z along it. A calibrated flange off that axis is moved onto it
  and the difference goes into ``kincal.tool0_to_tool`` (with the model's tool frame), stated in mm and deg;
- the model's base pose becomes ``kincal.world_to_base_link``, where a cell description mounts ``base_link``.

The forward kinematics of ``world_to_base_link @ Rz(pi) @ (origins and joint rotations) @ tool0_to_tool``
equal the model's (checked at 200 configurations and written into the file).
"""

from __future__ import annotations

import hashlib

import numpy as np
import yaml

from kincal.errors import ModelError
from kincal.kinematics import ArmModel, forward_kinematics
from kincal.kinematics.dh import axis_frame
from kincal.kinematics.model import REVOLUTE
from kincal.lie import se3, so3
from kincal.lie.rotations import matrix_to_rpy, rpy_to_matrix

UR_LINKS = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
PARALLEL_SIN = 0.1  # axes closer to parallel than ~5.7 deg: the frame goes to the point nearest the previous one
ON_AXIS_TOL = 1e-9  # m and rad: a flange this close to joint 6's axis is taken as on it
CHECK_CONFIGURATIONS = 200
_RZ_PI = se3.make(rpy_to_matrix([0.0, 0.0, np.pi]), np.zeros(3))


def ur_frames(a: ArmModel) -> tuple[np.ndarray, np.ndarray]:
    """Link frames ``G_1..G_6`` of the description in the arm base frame at reading zero, shape (6, 4, 4), and
    ``T_tool0_flange`` (identity when the calibrated flange lies on joint 6's axis)."""
    if a.dof != 6 or any(t != REVOLUTE for t in a.joint_types):
        prismatic = sum(t != REVOLUTE for t in a.joint_types)
        kinds = f" ({prismatic} prismatic)" if prismatic else ""
        raise ModelError(f"arm '{a.name}' has {a.dof} joints{kinds}: the Universal Robots ROS driver's kinematics "
                         "file needs 6 revolute joints (a UR arm)")
    lines, E = [], np.eye(4)
    for s, o in zip(a.screws, a.offsets):
        v, w = se3.split(se3.adjoint(E) @ s)
        lines.append((np.cross(w, v), w))  # (point, direction) at reading zero
        E = E @ se3.exp(s * o)
    flange = E @ a.home
    frames, origin, x = [], np.zeros(3), np.array([1.0, 0.0, 0.0])
    for i, (p, z) in enumerate(lines[:5]):
        origin = _foot(p, z, *lines[i + 1], origin)
        frames.append(axis_frame(origin, x, z))
        x = frames[-1][:3, 0]
    p, z = lines[5]
    last = axis_frame(p + np.dot(flange[:3, 3] - p, z) * z, flange[:3, 0], z)  # tool0 on the axis
    rest = se3.inverse(last) @ flange
    if np.abs(rest - np.eye(4)).max() < ON_AXIS_TOL:
        last, rest = flange, np.eye(4)
    return np.stack(frames + [last]), rest


def _foot(p, z, p_next, z_next, previous) -> np.ndarray:
    """The point of axis (p, z) where the common normal to the next axis meets it, or, for nearly parallel
    axes, the point of the axis closest to ``previous``."""
    c = np.cross(z, z_next)
    if np.linalg.norm(c) < PARALLEL_SIN:
        return p + np.dot(previous - p, z) * z
    t, _, _ = np.linalg.solve(np.column_stack([z, -z_next, c]), p_next - p)
    return p + t * z


def ur_rpy(R: np.ndarray) -> np.ndarray:
    """URDF roll, pitch, yaw of R with roll in [0, pi] (the range ``ur_calibration``'s files use, so the nominal
    UR gives the driver's default file literally)."""
    r, p, y = matrix_to_rpy(R)
    if r < -1e-12:
        r, p, y = r + np.pi, np.pi - p, y + np.pi
    wrap = lambda t: (t + np.pi) % (2 * np.pi) - np.pi if abs(t) > np.pi else t  # noqa: E731
    return np.array([r, wrap(p), wrap(y)]) + 0.0  # + 0.0: no negative zeros in the file


def _pose(T: np.ndarray) -> dict:
    return {"xyz": [float(v) + 0.0 for v in T[:3, 3]], "rpy": [float(v) + 0.0 for v in matrix_to_rpy(T[:3, :3])]}


def ur_ros_document(a: ArmModel, ur_hash: str | None = None) -> dict:
    """The driver's kinematics file for arm ``a`` as plain data (``kinematics:`` as ur_calibration writes it,
    and a ``kincal:`` block with the base mount, the tool remainder and the check)."""
    frames, rest = ur_frames(a)
    origins = [se3.inverse(prev) @ G for prev, G in zip([np.eye(4)] + list(frames[:-1]), frames)]
    kin = {}
    for link, O in zip(UR_LINKS, origins):
        r, p, y = ur_rpy(O[:3, :3])
        kin[link] = {"x": float(O[0, 3]) + 0.0, "y": float(O[1, 3]) + 0.0, "z": float(O[2, 3]) + 0.0,
                     "roll": float(r), "pitch": float(p), "yaw": float(y)}
    kin["hash"] = ur_hash or "kincal_" + hashlib.sha256(repr(sorted(kin.items())).encode()).hexdigest()[:16]
    world_base_link, tool0_tool = a.base @ _RZ_PI, rest @ a.tool
    doc = {"kinematics": kin}
    q = np.random.default_rng(0).uniform(np.maximum(a.lower, -np.pi), np.minimum(a.upper, np.pi),
                                         (CHECK_CONFIGURATIONS, 6))
    diff = ur_chain_fk(doc, q, world_base_link, tool0_tool) - forward_kinematics(a, q)
    doc["kincal"] = {
        "arm": a.name, "world_to_base_link": _pose(world_base_link), "tool0_to_tool": _pose(tool0_tool),
        "flange_off_joint6_axis": {"position_mm": float(np.linalg.norm(rest[:3, 3]) * 1e3),
                                   "rotation_deg": float(np.degrees(np.linalg.norm(so3.log(rest[:3, :3]))))},
        "check": {"configurations": CHECK_CONFIGURATIONS,
                  "max_position_difference_m": float(np.abs(diff[:, :3, 3]).max()),
                  "max_rotation_difference": float(np.abs(diff[:, :3, :3]).max())}}
    return doc


def ur_chain_fk(doc: dict, q, world_base_link=np.eye(4), tool0_tool=np.eye(4)) -> np.ndarray:
    """Tool poses (n, 4, 4) of a kinematics file composed as the ur_description xacro does:
    ``world_base_link @ Rz(pi) @ prod_i(Trans(x, y, z) Rz(yaw) Ry(pitch) Rx(roll) Rz(q_i)) @ tool0_tool``."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    T = np.broadcast_to(world_base_link @ _RZ_PI, (q.shape[0], 4, 4))
    for i, link in enumerate(UR_LINKS):
        k = doc["kinematics"][link]
        O = se3.make(rpy_to_matrix([k["roll"], k["pitch"], k["yaw"]]), np.array([k["x"], k["y"], k["z"]]))
        Rz = se3.make(rpy_to_matrix(np.stack([0 * q[:, i], 0 * q[:, i], q[:, i]], axis=-1)), np.zeros((len(q), 3)))
        T = T @ O @ Rz
    return T @ tool0_tool


def ur_ros_text(a: ArmModel, source: str, ur_hash: str | None = None) -> tuple[str, list[str]]:
    """The file's text (YAML with a header saying what it is) and the notes a user must read."""
    doc = ur_ros_document(a, ur_hash)
    info = doc["kincal"]
    notes = []
    off = info["flange_off_joint6_axis"]
    if off["position_mm"] > 0 or off["rotation_deg"] > 0:
        notes.append(f"the calibrated flange is {off['position_mm']:.4g} mm and {off['rotation_deg']:.4g} deg off "
                     "joint 6's axis, where the driver's tool0 must lie: tool0 is put on the axis and the rest is "
                     "in kincal.tool0_to_tool (attach the tool there)")
    if np.any(a.compliance > 0):
        notes.append("joint compliance is not in the file (the driver's description is rigid)")
    if ur_hash is None:
        notes.append("hash: not this robot's calibration checksum, so the driver logs a mismatch at start-up; "
                     "pass --ur-hash with the hash ur_calibration writes for this robot")
    header = (f"# Universal Robots ROS driver kinematics file (kinematics_params_file), written by kincal\n"
              f"# from {source}, arm '{a.name}'. Link origins x, y, z (m), roll, pitch, yaw (rad, URDF\n"
              "# convention), composed as ur_description does. The kincal: block (the driver ignores it): where\n"
              "# to mount base_link, the tool on tool0, the largest difference to the model (docs/deploy.md).\n")
    kin = yaml.safe_dump({"kinematics": doc["kinematics"]}, sort_keys=False)
    return header + kin + yaml.safe_dump({"kincal": info}, sort_keys=False, default_flow_style=None), notes


__all__ = ["UR_LINKS", "ur_chain_fk", "ur_frames", "ur_ros_document", "ur_ros_text", "ur_rpy"]
