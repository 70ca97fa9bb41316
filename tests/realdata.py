"""Loaders for the public real data sets next to the checkout (``../shared/datasets``): files -> kincal objects.

Test helpers, not package code: the data sets are never shipped (licences in each folder's SOURCE.md), and
these loaders know the quirks of each public format. Every loader takes the data set's folder and returns
kincal ``Dataset`` objects in SI units (and, where the nominal model is not a URDF, the nominal ``Robot``
built from the numbers in SOURCE.md). ``folder(name)`` raises ``DataMissing`` when the data are absent, so
tests can skip and scripts can say what is missing.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.io import loadmat

from kincal.data import Dataset
from kincal.estimation.problem import Noise
from kincal.kinematics import ArmModel, Robot
from kincal.kinematics.couplings import derive_readings
from kincal.kinematics.dh import from_dh
from kincal.io.urdf import from_urdf
from kincal.lie import se3, so3

DATASETS = Path(__file__).resolve().parents[2] / "shared" / "datasets"

# Stated noise per data set (position m, orientation rad per axis; encoders exact). None of the sources publishes
# one: each was chosen from kincal's full fit so that the residual variance factor is near 1 (docs/real-data.md).
NOISE = {
    "wu": Noise(0.15e-3, np.radians(0.07), 0.0),  # device points and probed frames
    "ur10": Noise(1.5e-3, np.radians(0.3), 0.0),  # RealSense camera on a checkerboard
    "mocap": Noise(0.3e-3, 1.0, 0.0),  # TALOS / TIAGo markers (TIAGo fits only to about 2.5 mm)
    "mukca": Noise(0.3e-3, 1.0, 0.0),  # ball centre in its socket
    "motoman": Noise(1.0e-3, 1.0, 0.0),  # self-contact distance, plane contact
}


class DataMissing(FileNotFoundError):
    """A real data set (or a file of it) is not available next to the checkout."""


def folder(name: str) -> Path:
    """``../shared/datasets/<name>`` or ``DataMissing``."""
    path = DATASETS / name
    if not path.is_dir():
        raise DataMissing(f"real data set not available: {path}")
    return path


def _file(path: Path) -> Path:
    if not path.is_file():
        raise DataMissing(f"real data file not available: {path}")
    return path


def _csv(path: Path, **kw) -> np.ndarray:
    return np.loadtxt(_file(path), delimiter=",", ndmin=2, **kw)


def _frames(origin, z, x_point) -> np.ndarray:
    """Frames (N, 4, 4) from an origin, a z direction and a point on the x axis (x orthogonalised against z)."""
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    y = np.cross(z, x_point - origin)
    y /= np.linalg.norm(y, axis=-1, keepdims=True)
    T = np.tile(np.eye(4), (len(origin), 1, 1))
    T[:, :3, 0], T[:, :3, 1], T[:, :3, 2], T[:, :3, 3] = np.cross(y, z), y, z, origin
    return T


# ------------------------------------------------------------------ Wu et al. 2015, ABB IRB 120 (wu2015-irb120-poe)

WU = "wu2015-irb120-poe"
# Nominal POE model (SOURCE.md; the authors' Experiment.m): unit axes and a point on each axis, mm, ABB zero.
_WU_AXES = np.array([[0, 0, 1], [0, 1, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0]], float)
_WU_POINTS = np.array([[0, 0, 0], [0, 0, 290], [0, 0, 560], [0, 0, 630], [302, 0, 630], [0, 0, 630]]) * 1e-3
# The base frame as the authors measured it in the device frame (SOURCE.md "Constants"), mm.
_WU_BASE_Z = np.array([-0.000289, -0.002459, 0.999997])
_WU_BASE_X = np.array([0.140895, -0.990024, 0.00132])
_WU_BASE_PLANE_POINT = np.array([-126.930293, 871.797701, 11.929126]) * 1e-3


def _circle_centre(p: np.ndarray) -> np.ndarray:
    """Centre of the circle through points p (K, 3): algebraic fit |p|^2 = 2 c.p + k within their plane."""
    mean = p.mean(axis=0)
    normal = np.linalg.svd(p - mean)[2][-1]
    A = np.vstack([np.column_stack([2 * p, np.ones(len(p))]), np.append(normal, 0.0)])
    b = np.append(np.sum(p**2, axis=1), normal @ mean)
    return np.linalg.lstsq(A, b, rcond=None)[0][:3]


def wu_device_base(path: Path) -> np.ndarray:
    """``T_device_base`` as the authors build it: the base z and x directions and z-plane point they measured,
    origin = centre of the circle a tool point drew about joint 1 (``BaseCirclePoints``), projected onto that
    plane."""
    z = _WU_BASE_Z / np.linalg.norm(_WU_BASE_Z)
    y = np.cross(z, _WU_BASE_X)
    y /= np.linalg.norm(y)
    c = _circle_centre(_csv(path / "BaseCirclePoints.csv") * 1e-3)
    return se3.make(np.column_stack([np.cross(y, z), y, z]), c + z * ((_WU_BASE_PLANE_POINT - c) @ z))


def wu_probed_frames(path: Path) -> np.ndarray:
    """The 37 end-effector frames (device frame, m) probed in ``CaliFullPose``: 36 calibration configurations,
    then the robot at its zero configuration. Per 12-row block, row 8 holds the origin and the z direction,
    row 9 a point on the x axis (the authors' construction)."""
    raw = _csv(path / "CaliFullPose.csv").reshape(37, 12, 6)
    return _frames(raw[:, 7, :3] * 1e-3, raw[:, 7, 3:], raw[:, 8, :3] * 1e-3)


def wu_robot(path: Path) -> Robot:
    """The nominal IRB 120 of SOURCE.md (POE, base frame = space frame, ABB zero). ``home`` is the probed
    end-effector frame at the zero configuration in the base frame, as the authors initialise their tool twist:
    the flange frame would start the tool orientation 139 deg away from the probed frames' (see
    docs/real-data.md)."""
    screws = np.hstack([-np.cross(_WU_AXES, _WU_POINTS), _WU_AXES])
    home = se3.inverse(wu_device_base(path)) @ wu_probed_frames(path)[36]
    arm = ArmModel("arm", screws, home, joint_names=tuple(f"j{i}" for i in range(1, 7)),
                   meta={"source": f"{WU}/SOURCE.md"})
    return Robot("irb120", {"arm": arm})


def wu_joints(path: Path) -> np.ndarray:
    return np.radians(_csv(path / "CaliJointAngles.csv"))


def wu_markers(path: Path) -> Dataset:
    """3 tool points per configuration (device frame), tracker and marker positions unknown."""
    p = _csv(path / "CaliPosition.csv").reshape(36, 3, 3) * 1e-3  # rows: point 1..3 of configuration 1, ...
    return Dataset("markers", "irb120", ("arm",), {"arm": wu_joints(path)}, {"p_tracker_marker": p},
                   name="wu-markers", meta={"source": WU})


def wu_pose(path: Path) -> Dataset:
    """The 36 probed end-effector frames (device frame), tracker unknown."""
    return Dataset("pose", "irb120", ("arm",), {"arm": wu_joints(path)},
                   {"T_tracker_tool": wu_probed_frames(path)[:36]}, name="wu-pose", meta={"source": WU})


# ------------------------------------------------------------------------- FIGAROH UR10e camera poses (figaroh-geometric/ur10)

FIGAROH = "figaroh-geometric"


def rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) for rows (roll, pitch, yaw), rad (pinocchio ``rpyToMatrix``)."""
    (cr, cp, cy), (sr, sp, sy) = np.cos(rpy).T, np.sin(rpy).T
    return np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], axis=-1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], axis=-1),
        np.stack([-sp, cp * sr, cp * cr], axis=-1),
    ], axis=-2)


def figaroh_ur10(path: Path) -> tuple[Robot, Dataset]:
    """Nominal UR10e (URDF chain ``base_link_inertia`` -> ``wrist_3_link``) and the 23 camera poses of the
    target (m, roll-pitch-yaw rad) as a pose data set with the camera frame unknown."""
    arm = from_urdf(_file(path / "ur10_robot.urdf"), "base_link_inertia", "wrist_3_link", name="arm")
    data = _csv(path / "calibration.csv", skiprows=1)  # x, y, z, roll, pitch, yaw, 6 joints
    T = np.tile(np.eye(4), (len(data), 1, 1))
    T[:, :3, :3], T[:, :3, 3] = rpy_matrix(data[:, 3:6]), data[:, :3]
    ds = Dataset("pose", "ur10e", ("arm",), {"arm": data[:, 6:12]}, {"T_tracker_tool": T}, name="ur10-camera",
                 meta={"source": f"{FIGAROH}/ur10"})
    return Robot("ur10e", {"arm": arm}), ds


def figaroh_talos(path: Path) -> tuple[Robot, Dataset]:
    """Nominal TALOS left arm with torso (URDF chain ``base_link`` -> ``gripper_left_base_link``, 9 joints) and
    the 61 mocap positions of one marker (m, robot-base frame; tracker and marker offset unknown)."""
    arm = from_urdf(_file(path / "talos_full_v2.urdf"), "base_link", "gripper_left_base_link", name="arm")
    data = _csv(path / "talos_left_arm_02_10_contact.csv", skiprows=1)  # t, x, y, z, 2 torso + 7 arm joints
    ds = Dataset("markers", "talos", ("arm",), {"arm": data[:, 4:13]}, {"p_tracker_marker": data[:, None, 1:4]},
                 name="talos-left-marker", meta={"source": f"{FIGAROH}/talos", "t": data[:, 0]})
    return Robot("talos", {"arm": arm}), ds


def figaroh_tiago(path: Path) -> tuple[Robot, Dataset]:
    """Nominal TIAGo arm with its prismatic torso (URDF ``base_footprint`` -> ``arm_7_link``, 8 joints) and
    the 34 mocap positions of the 3 distinct hand markers (columns x4..z4 repeat x3..z3 and are dropped)."""
    arm = from_urdf(_file(path / "tiago_hey5.urdf"), "base_footprint", "arm_7_link", name="arm")
    data = _csv(path / "qualysis_base_hand_calibration.csv", skiprows=1)  # 4 markers x xyz, torso, 7 arm joints
    ds = Dataset("markers", "tiago", ("arm",), {"arm": data[:, 12:20]},
                 {"p_tracker_marker": data[:, :9].reshape(-1, 3, 3)}, name="tiago-hand-markers",
                 meta={"source": f"{FIGAROH}/tiago"})
    return Robot("tiago", {"arm": arm}), ds


# ------------------------------------------------------------------------ MUKCa, ball held in sockets (mukca-fixed-point)

MUKCA = "mukca-fixed-point"
MUKCA_HOLE_DISTANCE = 0.050  # m between the centres of hole 0 and hole 1 (SOURCE.md)
MUKCA_TRAIN = ("front_center", "back_left", "high")  # panda_2 placements calibrated on; the other six are held out


def mukca_robot(path: Path, urdf: str = "urdf/panda.urdf") -> Robot:
    """A Panda from one of the folder's URDFs (nominal or ``calibrated_urdf/panda_k/panda.urdf``), chain
    ``panda_link0`` -> ``ball_link`` (the ball centre is the tool point)."""
    return Robot("panda", {"arm": from_urdf(_file(path / urdf), "panda_link0", "ball_link", name="arm")})


def mukca_placements(path: Path, robot_dir: str) -> list[str]:
    """Plate placements recorded for one robot (sub-folders with hole files), sorted."""
    base = path / "data" / robot_dir
    if not base.is_dir():
        raise DataMissing(f"real data folder not available: {base}")
    return sorted(p.name for p in base.iterdir() if (p / "hole_0.csv").is_file())


def mukca_sockets(path: Path, robot_dir: str, placement: str) -> list[Dataset]:
    """The two sockets of one plate placement as socket data sets (socket positions unknown), named
    ``<placement>.hole0`` and ``<placement>.hole1``; joint angles in rad, no header."""
    return [Dataset("socket", "panda", ("arm",), {"arm": _csv(path / "data" / robot_dir / placement / f"hole_{k}.csv")},
                    name=f"{placement}.hole{k}", meta={"source": f"{MUKCA}/data/{robot_dir}/{placement}"})
            for k in (0, 1)]


# ------------------------------------------------------------- CTU Motoman MA1400 dual arm (ctu-motoman-dual-arm)

MOTOMAN = "ctu-motoman-dual-arm"
MOTOMAN_JOINTS = ("E", "S", "L", "U", "R", "B", "T")
MOTOMAN_CONTACT_DISTANCE = 0.116  # m between the two end-effector centres in self-contact (the authors' value)
# Close to the authors' free set (L, U, R, B joint offsets and the end-effector length), in POE terms: the right
# arm's offsets of L, U, R, B and its tool frame; torso E and shoulder S stay nominal, the left arm is fixed.
MOTOMAN_FREE = ["right.L.offset", "right.U.offset", "right.R.offset", "right.B.offset", "right.home"]
# Columns (0-based) of each arm's joints: E (the shared torso axis, col 7 1-based) then S, L, U, R, B, T.
_MOTOMAN_COLUMNS = {"right": [6, 7, 8, 9, 10, 11, 12], "left": [6, 13, 14, 15, 16, 17, 18]}


# Standard DH rows E, S, L, U, R, B, T of the toolbox's loadMotoman.m (SOURCE.md); E's twist is +15 deg (right arm)
# or -15 deg (left arm).
_MOTOMAN_DH = dict(a=[0, 0.150, 0.614, 0.200, 0, 0.030, 0], alpha=[0, -np.pi / 2, np.pi, -np.pi / 2, np.pi / 2, np.pi / 2, 0],
                   d=[-0.263, 1.4159, 0, 0, -0.640, 0, 0.200], theta=[-np.pi / 2, 0, -np.pi / 2, 0, 0, -np.pi / 2, 0])


def _motoman_arm(name: str, torso_alpha: float, flange: np.ndarray) -> ArmModel:
    """One arm of the toolbox's loadMotoman.m through its own copy of E."""
    return from_dh(a=_MOTOMAN_DH["a"], alpha=[torso_alpha] + _MOTOMAN_DH["alpha"][1:], d=_MOTOMAN_DH["d"],
                   theta=_MOTOMAN_DH["theta"], flange=flange, name=name, joint_names=MOTOMAN_JOINTS)


def _motoman_flanges(tool: str) -> dict[str, np.ndarray]:
    """The right and left flange transforms: end-effector centres (DH row EE: d = 0.354 m), or for ``leica`` the
    right arm's laser-tracker reflector (row LR1: a 0.045, d 0.245, theta -0.38)."""
    ee = se3.make(np.eye(3), np.array([0.0, 0.0, 0.354]))
    if tool != "leica":
        return {"right": ee, "left": ee}
    c, s = np.cos(-0.38), np.sin(-0.38)
    return {"right": se3.make(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]), np.array([0.045 * c, 0.045 * s, 0.245])),
            "left": ee}


def motoman_robot(tool: str = "contact") -> Robot:
    """Both arms from the base frame, each with its own copy of the shared torso joint E (the data repeat the E
    reading for both arms; ``motoman_tree`` has E once). ``tool``: ``contact`` (end-effector centre) or ``leica``
    (the right arm's laser-tracker reflector), ``_motoman_flanges``."""
    flanges = _motoman_flanges(tool)
    return Robot("motoman", {"right": _motoman_arm("right", np.radians(15), flanges["right"]),
                             "left": _motoman_arm("left", np.radians(-15), flanges["left"])})


def motoman_tree(tool: str = "contact") -> Robot:
    """The same robot as a tree: the torso joint E once (``torso``), both 6-joint arms mounted on it, each with its
    +-15 deg twist of the E row as its base; FK equal to ``motoman_robot``'s (tests/test_real_data.py)."""
    torso = from_dh(a=[0.0], alpha=[0.0], d=[-0.263], theta=[-np.pi / 2], name="torso", joint_names=("E",))
    arms = {side: from_dh(a=_MOTOMAN_DH["a"][1:], alpha=_MOTOMAN_DH["alpha"][1:], d=_MOTOMAN_DH["d"][1:],
                          theta=_MOTOMAN_DH["theta"][1:], flange=flange, name=side, joint_names=MOTOMAN_JOINTS[1:],
                          base=se3.make(so3.exp(np.array([alpha, 0.0, 0.0])), np.zeros(3)))
            for (side, flange), alpha in zip(_motoman_flanges(tool).items(), np.radians([15, -15]))}
    return Robot("motoman", {"torso": torso, **arms}, mounts={"right": "torso", "left": "torso"})


def _motoman_poses(path: Path, name: str) -> np.ndarray:
    """One row per pose (the files repeat a pose once per observed ArUco marker): columns as SOURCE.md."""
    rows = loadmat(_file(path / "leica_dataset" / f"{name}_dataset.mat"))["dataset"]
    return rows[np.unique(rows[:, 0], return_index=True)[1]]


MOTOMAN_SELF_TOUCH = tuple(f"{p}self_{s}_4x4" for p in ("leica_", "no_leica_")
                           for s in ("upper1", "upper2", "lower1", "lower2"))


def motoman_self_touch(path: Path, names=MOTOMAN_SELF_TOUCH) -> Dataset:
    """Self-contact poses of the given files: both end-effector centres ``MOTOMAN_CONTACT_DISTANCE`` apart."""
    rows = np.vstack([_motoman_poses(path, n) for n in names])
    return Dataset("distance", "motoman", ("right", "left"), {a: rows[:, c] for a, c in _MOTOMAN_COLUMNS.items()},
                   known={"distance": MOTOMAN_CONTACT_DISTANCE}, name="self-touch", meta={"source": MOTOMAN})


def motoman_plane(path: Path, surface: str) -> Dataset:
    """Right end effector touching one surface (e.g. ``higher_table1``), poses with and without the tracker;
    the plane is unknown."""
    rows = np.vstack([_motoman_poses(path, f"{p}{surface}_5x5") for p in ("leica_", "no_leica_")])
    return Dataset("plane", "motoman", ("right",), {"right": rows[:, _MOTOMAN_COLUMNS["right"]]}, name=surface,
                   meta={"source": MOTOMAN})


def motoman_leica(path: Path, name: str = "leica_right_hand_6x6x6") -> Dataset:
    """Reflector positions on the right arm (tracker frame, m) with the tracker frame unknown; poses without a
    tracker reading dropped."""
    rows = _motoman_poses(path, name)
    rows = rows[np.isfinite(rows[:, 19:22]).all(axis=1)]
    return Dataset("markers", "motoman", ("right",), {"right": rows[:, _MOTOMAN_COLUMNS["right"]]},
                   {"p_tracker_marker": rows[:, None, 19:22]}, name=name, meta={"source": MOTOMAN})


# ------------------------------------------------------------- DLR Agile Justin (dlr-agile-justin-elastic)

JUSTIN = "dlr-agile-justin-elastic"
JUSTIN_TORSO_COUPLING = {"t4": {"t2": -1.0, "t3": -1.0}}  # the passive 4th torso joint keeps the upper body level


def _justin_model(path: Path) -> dict:
    import json

    return json.loads(_file(path / "justin19_nominal_model.json").read_text())


def _nearest_pose(T) -> np.ndarray:
    """The published fixed frames are rounded (0.866 for cos 30 deg): the nearest rigid transform, as a model file's
    ``orthonormalize: true`` would give (``so3.project``)."""
    T = np.array(T, dtype=float)
    return se3.make(so3.project(T[:3, :3]), T[:3, 3])


def _justin_dh(rows, name: str, names, **fields) -> ArmModel:
    """Rows ``[d, theta, a, alpha]`` in Craig's (modified) convention, as SOURCE.md's JSON gives them."""
    r = np.asarray(rows, dtype=float)
    return from_dh(a=r[:, 2], alpha=r[:, 3], d=r[:, 0], theta=r[:, 1], modified=True, name=name,
                   joint_names=tuple(names), **fields)


def justin_robot(path: Path, masses: bool = False) -> Robot:
    """Agile Justin's torso (pan, two tilts and the coupled passive tilt) carrying both arms: a tree, so the torso's
    parameters exist once (``Robot.mounts``), with the coupling declared (``ArmModel.couplings``). Each arm's base
    is its pose in the torso's last DH frame, its tool the TCP frame. ``masses``: the JSON's mass model (links,
    hands as payloads, the head on the torso's last link; gravity -z in the torso base frame), so the robot's own
    weight loads every joint compliance (``kincal.kinematics.gravity``)."""
    m = _justin_model(path)
    tcp = _nearest_pose(m["F_TCP_right_and_left"])
    torso_fields, arm_fields = {}, {"right": {}, "left": {}}
    if masses:
        torso_fields, arm_fields = _justin_masses(m)
    torso = _justin_dh(m["DH_TORSO"], "torso", ("t1", "t2", "t3", "t4"), base=_nearest_pose(m["F_TORSO_BASE"]),
                       couplings=JUSTIN_TORSO_COUPLING, **torso_fields)
    arms = {side: _justin_dh(m[f"DH_{side.upper()}"], side, [f"j{i}" for i in range(1, 8)], flange=tcp,
                             base=_nearest_pose(m[f"F_{side.upper()}_BASE"]), **arm_fields[side])
            for side in ("right", "left")}
    return Robot("justin", {"torso": torso, **arms}, {"source": JUSTIN}, mounts={"right": "torso", "left": "torso"})


def justin_lateral(robot: Robot, path: Path) -> Robot:
    """Every joint of the torso and the arms with lateral compliance (``kincal.kinematics.lateral``, starting at
    0) about the x and y axes of its DH frame (normal to its axis, through the frame's origin, turning with it),
    stated as the arm's ``lateral_axes``: the paper's kappa_alpha, kappa_beta. Each bends, first order, by its
    compliance times the moment of the weight beyond the joint about that axis."""
    m = _justin_model(path)
    arms = {}
    for a, arm in robot.arms.items():
        F = _dh_frames(m[f"DH_{a.upper()}"])
        n = F[:, :3, :2].transpose(0, 2, 1)  # (n, 2, 3): each frame's x and y axes
        axes = np.concatenate([np.cross(F[:, None, :3, 3], n), n], axis=-1)
        arms[a] = arm.replace(lateral=np.zeros((arm.dof, 2)), lateral_axes=axes)
    return Robot(robot.name, arms, dict(robot.meta), robot.mounts)


def _dh_frames(rows) -> np.ndarray:
    """The DH frames {1}..{n} at q = 0 in the segment's first frame (Craig: RotX(alpha) TransX(a) RotZ(theta)
    TransZ(d) per row ``[d, theta, a, alpha]``), (n, 4, 4)."""
    T, out = np.eye(4), []
    for d, theta, a, alpha in np.asarray(rows, dtype=float):
        c, s, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
        T = T @ np.array([[c, -s, 0, a], [ca * s, ca * c, -sa, -d * sa], [sa * s, sa * c, ca, d * ca], [0, 0, 0, 1]])
        out.append(T)
    return np.array(out)


def _justin_masses(m: dict) -> tuple[dict, dict]:
    """ArmModel mass fields from the JSON: each DH frame's mass at its centre of gravity (frame coordinates) moved
    to the segment's base frame at q = 0; the head (its joints always 0) joins the torso's last link."""
    mk, cog = m["masses_kg"], m["mass_cog_in_frame_m"]
    g = np.array([0.0, 0.0, -9.81])
    torso_frames = _dh_frames(m["DH_TORSO"])
    tm = np.array(mk["torso_frames_1_to_4"], float)
    tc = np.einsum("nij,nj->ni", torso_frames[:, :3, :3], np.array(cog["torso"])) + torso_frames[:, :3, 3]
    head = torso_frames[-1] @ np.asarray(m["F_HEAD_BASE"], float) @ _dh_frames(m["DH_HEAD"])[-1]
    head_c = head[:3, :3] @ np.array(cog["head"]) + head[:3, 3]
    tc[-1] = (tm[-1] * tc[-1] + mk["head"] * head_c) / (tm[-1] + mk["head"])
    tm[-1] += mk["head"]
    torso = {"link_masses": tm, "link_coms": tc, "gravity": g}
    arms = {}
    for side in ("right", "left"):
        frames = _dh_frames(m[f"DH_{side.upper()}"])
        c = np.einsum("nij,nj->ni", frames[:, :3, :3], np.array(cog[f"{side}_arm"])) + frames[:, :3, 3]
        arms[side] = {"link_masses": np.array(mk["arm_frames_each_arm_7_links"], float), "link_coms": c,
                      "payload_mass": float(mk["hand_each"]), "payload_com": np.array(cog["hand_each"], float)}
    return torso, arms


def justin_markers(path: Path, both_arms: bool = False) -> tuple[Dataset, Dataset]:
    """The hand markers of the 500 poses (Vicon frame, m; commanded joints, rad): one markers data set per hand,
    sharing the camera frame (``camera``), each marker position in its TCP frame unknown. The torso readings are
    q0..q2; the coupled t4 is derived. ``both_arms``: each data set also carries the other arm's readings (what a
    robot with a mass model needs: both arms load the torso)."""
    x = _csv(path / "measurements_flat.csv", skiprows=1)
    names = ("t1", "t2", "t3", "t4")
    torso = derive_readings(JUSTIN_TORSO_COUPLING, names, np.column_stack([x[:, 0:3], np.zeros(len(x))]))
    out = []
    for side, joints, cols in (("right", slice(3, 10), slice(19, 22)), ("left", slice(10, 17), slice(22, 25))):
        q = {side: x[:, joints], "torso": torso}
        if both_arms:  # the other arm's weight loads the torso: its readings are needed (gravity on trees)
            q = {"right": x[:, 3:10], "left": x[:, 10:17], "torso": torso}
        out.append(Dataset("markers", "justin", (side,), q,
                           {"p_tracker_marker": x[:, None, cols]}, name=f"{side} hand",
                           frames={"tracker": "camera", "markers": f"{side}_marker"}, meta={"source": JUSTIN}))
    return out[0], out[1]


# The calibration levels of the paper's table, kincal's free sets, and the published fit errors on all 500 poses
# (mean, std, max mm).
JUSTIN_FRAMES = ["camera", "right_marker", "left_marker"]
JUSTIN_LEVELS = {
    "frames only": (JUSTIN_FRAMES, (21.33, 9.71, 63.41)),
    "offsets": ("offsets", (18.18, 7.8, 45.9)),
    "geometric": ("kinematic", (10.5, 5.74, 36.37)),
}
# Motion capture as for TALOS/TIAGo (0.3 mm): every level leaves millimetres unexplained, which reads as a misfit.
JUSTIN_NOISE = NOISE["mocap"]
# The compliant levels, loaded by the robot's own weight (the JSON's mass model): published fit on all 500 poses.
JUSTIN_ELASTIC = {"joint compliances": (5.64, 2.57, 12.83), "lateral compliances": (3.12, 1.71, 8.23)}


def justin_elastic_case(path: Path, level: str) -> tuple[Robot, list[Dataset], dict]:
    """Robot (masses; lateral compliance for ``lateral compliances``, ``justin_lateral``), both hands' data sets
    (with the other arm's readings) and ``calibrate`` options (``free`` among them) of a compliant level: the
    geometry and the compliances in one solve, as the paper estimates them, from the nominal model with every
    compliance at 0. The rigid model's gauges, which only the weight lifts, are held
    (``estimation.gauge.rigid_gauges``); the coupled t4's torque is held by the t2 and t3 drives
    (``kinematics.elastic.deflection``). The pan joint's compliance is fixed at 0: its axis is vertical, so the
    weight does not load it."""
    robot, sets = justin_robot(path, masses=True), list(justin_markers(path, both_arms=True))
    free = ["kinematic", "elastic"]
    if level == "lateral compliances":
        robot, free = justin_lateral(robot, path), free + ["lateral"]
    elif level != "joint compliances":
        raise ValueError(f"unknown compliant level {level!r}; levels: {', '.join(JUSTIN_ELASTIC)}")
    return robot, sets, {"free": free, "fixed": ["torso.t1.compliance"], "noise": JUSTIN_NOISE, "outliers": "keep"}


def motoman_tree_data(path: Path) -> tuple[Dataset, Dataset]:
    """For ``motoman_tree``: the self-contact poses (``distance``, both arms) and the right arm's reflector positions
    (``markers``: tracker frame and the reflector's position in the end-effector frame unknown), with the E reading
    once, as the torso's."""
    def readings(rows, sides):
        return {"torso": rows[:, 6:7], **{s: rows[:, _MOTOMAN_COLUMNS[s][1:]] for s in sides}}

    touch = np.vstack([_motoman_poses(path, n) for n in MOTOMAN_SELF_TOUCH])
    leica = _motoman_poses(path, "leica_right_hand_6x6x6")
    leica = leica[np.isfinite(leica[:, 19:22]).all(axis=1)]
    return (Dataset("distance", "motoman", ("right", "left"), readings(touch, ("right", "left")),
                    known={"distance": MOTOMAN_CONTACT_DISTANCE}, name="self-touch", meta={"source": MOTOMAN}),
            Dataset("markers", "motoman", ("right",), readings(leica, ("right",)),
                    {"p_tracker_marker": leica[:, None, 19:22]}, name="leica", meta={"source": MOTOMAN}))


# ------------------------------------------------- honest prediction: k-fold held-out RMS against the predicted

def _wu_case(kind: str):
    path = folder(WU)
    return wu_robot(path), (wu_markers if kind == "markers" else wu_pose)(path), "kinematic", NOISE["wu"]


def _figaroh_case(name: str, free: str):
    robot, ds = {"talos": figaroh_talos, "tiago": figaroh_tiago}[name](folder(FIGAROH) / name)
    return robot, ds, free, NOISE["mocap"]


def _motoman_case():
    return motoman_robot(), motoman_self_touch(folder(MOTOMAN)), MOTOMAN_FREE, NOISE["motoman"]


# name -> () -> (nominal robot, data set, free, stated noise): the cases of docs/real-data.md "Honest prediction"
HONEST_CASES = {
    "wu markers": lambda: _wu_case("markers"),
    "wu frames": lambda: _wu_case("pose"),
    "motoman self-touch": _motoman_case,
    "talos offsets": lambda: _figaroh_case("talos", "offsets"),
    "talos kinematic": lambda: _figaroh_case("talos", "kinematic"),
    "tiago offsets": lambda: _figaroh_case("tiago", "offsets"),
    "tiago kinematic": lambda: _figaroh_case("tiago", "kinematic"),
}
