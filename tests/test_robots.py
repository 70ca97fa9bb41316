"""Built-in robots: golden values from the seeds and FK against independent implementations (1e-12 m / rad)."""

import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kincal import robots
from kincal.errors import DataFormatError
from kincal.io import builtin_names, load_robot
from kincal.io.urdf import to_urdf
from kincal.kinematics import forward_kinematics
from reference_dh import dh_fk

pin = pytest.importorskip("pinocchio")

N_CONFIGS = 1000
TOL = 1e-12


def _configs(arm, rng, n=N_CONFIGS):
    """Uniform within the joint limits (unlimited joints: [-pi, pi])."""
    lo = np.where(np.isfinite(arm.lower), arm.lower, -np.pi)
    up = np.where(np.isfinite(arm.upper), arm.upper, np.pi)
    return rng.uniform(lo, up, size=(n, arm.dof))


def _assert_poses_equal(T, ref, tol=TOL):
    """Position error (m) and rotation angle of R^T R_ref (rad) both below tol."""
    pos = np.linalg.norm(T[..., :3, 3] - ref[..., :3, 3], axis=-1).max()
    rel = np.swapaxes(T[..., :3, :3], -1, -2) @ ref[..., :3, :3]
    ang = Rotation.from_matrix(rel.reshape(-1, 3, 3)).magnitude().max()
    assert pos < tol and ang < tol, (pos, ang)


def _pinocchio_fk(xml, frame, q_by_name, base_frame=None):
    """Pose of ``frame`` (relative to ``base_frame`` if given) for each row of the dict q_by_name."""
    model = pin.buildModelFromXML(xml)
    data = model.createData()
    fid = model.getFrameId(frame)
    bid = None if base_frame is None else model.getFrameId(base_frame)
    n = len(next(iter(q_by_name.values())))
    out = np.empty((n, 4, 4))
    for k in range(n):
        q = pin.neutral(model)
        for j in range(1, model.njoints):
            name, jm = model.names[j], model.joints[j]
            if name in q_by_name:
                val = q_by_name[name][k]
                q[jm.idx_q:jm.idx_q + jm.nq] = [np.cos(val), np.sin(val)] if jm.nq == 2 else [val]
        pin.framesForwardKinematics(model, data, q)
        T = data.oMf[fid].homogeneous
        out[k] = T if bid is None else np.linalg.inv(data.oMf[bid].homogeneous) @ T
    return out


# ----------------------------------------------------------------------------------------- registry


def test_builtin_names_and_loading_by_name_or_path(tmp_path):
    assert robots.names() == ["dual7_torso", "frida", "klimchik3r", "kr270", "panda", "ur10"]
    frida = robots.load("frida")
    assert set(frida.arms) == {"left", "right"}
    assert all(set(robots.load(n).arms) == {"arm"} for n in ("klimchik3r", "panda", "ur10"))
    assert load_robot("frida") == frida
    assert robots.load("panda").meta["source"].startswith("Franka")
    with pytest.raises(DataFormatError, match="built-in robots: dual7_torso, frida, klimchik3r, kr270, panda, ur10"):
        load_robot("yumi")
    with pytest.raises(DataFormatError, match="unknown built-in robot"):
        robots.load("nope")


def test_io_resolves_builtin_names_without_the_robots_catalogue():
    """io sits below robots: reading a built-in model never imports kincal.robots (no cycle)."""
    assert builtin_names() == robots.names()
    code = ("import sys; from kincal.io import load_robot; r = load_robot('frida'); "
            "assert 'kincal.robots' not in sys.modules, 'io imported robots'; print(sorted(r.arms))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "['left', 'right']"


# -------------------------------------------------------------------------------------- Frida golden

# Thesis Table 4.8, nominal twists (v, w); printed with 4 decimals.
TABLE_4_8 = {
    0: (0, 0, 0, 0, 0, 1),
    1: (-0.11, 0, -0.03, 0, 1, 0),
    2: (0, 0, 0, 0, 0, 1),
    3: (-0.3565, 0, 0.0405, 0, 1, 0),
    4: (0, 0.397, 0, 1, 0, 0),
    5: (-0.3835, 0, 0.3055, 0, 1, 0),
    6: (0, 0.4105, 0, 1, 0, 0),
}


@pytest.mark.parametrize("arm", ["left", "right"])
def test_frida_twists_equal_thesis_table_4_8(arm):
    model = robots.load("frida")[arm]
    for i, xi in TABLE_4_8.items():
        np.testing.assert_allclose(model.screws[i], xi, atol=1e-15)
    # T_st as a twist, Table 4.8 (the thesis truncates to 4 decimals: 0.58748 -> 0.5874, 1.570796 -> 1.5707)
    xi_st = model.home_twist()
    np.testing.assert_array_equal(np.trunc(xi_st * 1e4) / 1e4, [-0.0573, 0, 0.5874, 0, 1.5707, 0])
    assert abs(xi_st[4] - np.pi / 2) < 1e-15


def test_frida_controller_order_gear_ratios_limits():
    right = robots.load("frida")["right"]
    # controller axes 1..7 carry model joints 1, 2, 4, 5, 6, 7, 3 (thesis: numbering 1,2,7,3,4,5,6 from the base)
    assert right.controller_order == (0, 1, 3, 4, 5, 6, 2)
    np.testing.assert_array_equal(right.gear_ratios, [100, 100, -100, 100, -101, 100, 100])
    np.testing.assert_allclose(np.degrees(right.lower), [-168.5, -143.5, -168.5, -123.5, -290, -88, -229])
    np.testing.assert_allclose(np.degrees(right.upper), [168.5, 43.5, 168.5, 80, 290, 138, 229])


PUBLISHED_BASE = {
    "right": [[0.5723, -0.1041, 0.8134, 0.0393], [0.6161, 0.7092, -0.3427, -0.0645],
              [-0.5412, 0.6973, 0.4700, 0.4035], [0, 0, 0, 1]],
    "left": [[0.5784, 0.1049, 0.8090, 0.0423], [-0.6143, 0.7084, 0.3474, 0.0626],
             [-0.5367, -0.6979, 0.4742, 0.4049], [0, 0, 0, 1]],
}


def _projected_base(arm):
    """Nearest rotation by scipy (quaternion method), independent of kincal's SVD projection."""
    M = np.array(PUBLISHED_BASE[arm])
    T = np.eye(4)
    T[:3, :3] = Rotation.from_matrix(M[:3, :3]).as_matrix()
    T[:3, 3] = M[:3, 3]
    return T


@pytest.mark.parametrize("arm", ["left", "right"])
def test_frida_base_is_the_projected_published_matrix(arm):
    model = robots.load("frida")[arm]
    published = np.array(PUBLISHED_BASE[arm])
    R = published[:3, :3]
    assert np.abs(R.T @ R - np.eye(3)).max() > 1e-5  # why the file must opt in to orthonormalize
    np.testing.assert_allclose(model.base, _projected_base(arm), atol=1e-14)
    assert np.abs(model.base - published).max() < 2e-4  # the projection moves entries by rounding size only


# Table A.1 rows: point (x, y, z), axis (x, y, z); T_st.
TABLE_A1 = [
    (0, 0, 0, 0, 0, 1), (-0.030, 0, 0.110, 0, 1, 0), (0, 0, 0.2565, 0, 0, 1), (0.0405, 0, 0.3565, 0, 1, 0),
    (0.180, 0, 0.397, 1, 0, 0), (0.3055, 0, 0.3835, 0, 1, 0), (0.3375, 0, 0.4105, 1, 0, 0),
]
T_ST = np.array([[0, 0, 1, 0.3375], [0, 1, 0, 0], [-1, 0, 0, 0.4105], [0, 0, 0, 1.0]])


def _v(x):
    return " ".join(repr(float(v)) for v in x)


def _table_a1_urdf(base):
    """URDF written directly from the Table A.1 rows: joint frames at the points, parallel to the arm base."""
    rows = ['<robot name="frida_a1">', '<link name="world"/>', '<link name="l0"/>']
    rpy = Rotation.from_matrix(base[:3, :3]).as_euler("xyz")  # extrinsic xyz = URDF rpy
    rows.append(f'<joint name="base" type="fixed"><parent link="world"/><child link="l0"/>'
                f'<origin xyz="{_v(base[:3, 3])}" rpy="{_v(rpy)}"/></joint>')
    prev = np.zeros(3)
    for i, row in enumerate(TABLE_A1):
        p = np.array(row[:3], dtype=float)
        d = p - prev
        rows.append(f'<link name="l{i + 1}"/>')
        rows.append(f'<joint name="j{i + 1}" type="revolute"><parent link="l{i}"/><child link="l{i + 1}"/>'
                    f'<origin xyz="{_v(d)}"/><axis xyz="{_v(row[3:])}"/>'
                    f'<limit lower="-6" upper="6" effort="0" velocity="0"/></joint>')
        prev = p
    d = T_ST[:3, 3] - prev
    rows.append('<link name="tcp"/>')
    rows.append(f'<joint name="st" type="fixed"><parent link="l7"/><child link="tcp"/>'
                f'<origin xyz="{_v(d)}" rpy="0 {np.pi / 2!r} 0"/></joint>')
    return "\n".join(rows + ["</robot>"])


def _sequential_rotations(rows, home, base, q):
    """Rotate the flange frame about each joint line, last joint first: no POE, no Lie layer."""
    T = np.broadcast_to(home, q.shape[:1] + (4, 4)).copy()
    for i in reversed(range(len(rows))):
        p, w = np.array(rows[i][:3], float), np.array(rows[i][3:], float)
        R = Rotation.from_rotvec(q[:, i, None] * w).as_matrix()
        M = np.zeros_like(T)
        M[:, :3, :3] = R
        M[:, :3, 3] = p - R @ p
        M[:, 3, 3] = 1
        T = M @ T
    return base @ T


@pytest.mark.parametrize("arm", ["left", "right"])
def test_frida_fk_matches_table_a1_by_pinocchio_and_sequential_rotations(arm, rng):
    model = robots.load("frida")[arm]
    q = _configs(model, rng)
    T = forward_kinematics(model, q)
    base = _projected_base(arm)
    ref_pin = _pinocchio_fk(_table_a1_urdf(base), "tcp", {f"j{i + 1}": q[:, i] for i in range(7)})
    _assert_poses_equal(T, ref_pin)
    _assert_poses_equal(T, _sequential_rotations(TABLE_A1, T_ST, base, q))


# ------------------------------------------------------------------------------------ DH / MDH / eq. 21


UR10_DH = dict(a=[0, -0.612, -0.5723, 0, 0, 0], alpha=[np.pi / 2, 0, 0, np.pi / 2, -np.pi / 2, 0],
               d=[0.1273, 0, 0, 0.163941, 0.1157, 0.0922])  # Universal Robots' CB3 table (issue #12 item 7)
PANDA_MDH = dict(a=[0, 0, 0, 0.0825, -0.0825, 0, 0.088],
                 alpha=[0, -np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, np.pi / 2],
                 d=[0.333, 0, 0.316, 0, 0.384, 0, 0])
PANDA_FLANGE = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.107], [0, 0, 0, 1.0]])


def _dh_urdf(table, modified, flange=None):
    """URDF of a DH chain written in the test: one fixed joint per elementary transform."""
    rows, links = ['<robot name="dh">', '<link name="l0"/>'], [0]

    def fixed(xyz="0 0 0", rpy="0 0 0"):
        k = len(links)
        links.append(k)
        return [f'<link name="l{k}"/>', f'<joint name="f{k}" type="fixed"><parent link="l{k - 1}"/>'
                f'<child link="l{k}"/><origin xyz="{xyz}" rpy="{rpy}"/></joint>']

    for i, (a, al, d) in enumerate(zip(table["a"], table["alpha"], table["d"])):
        if modified:
            rows += fixed(rpy=f"{al!r} 0 0") + fixed(xyz=f"{a!r} 0 0")
        k = len(links)
        links.append(k)
        rows += [f'<link name="l{k}"/>', f'<joint name="q{i + 1}" type="revolute"><parent link="l{k - 1}"/>'
                 f'<child link="l{k}"/><axis xyz="0 0 1"/>'
                 '<limit lower="-7" upper="7" effort="0" velocity="0"/></joint>']
        rows += fixed(xyz=f"0 0 {d!r}")
        if not modified:
            rows += fixed(xyz=f"{a!r} 0 0") + fixed(rpy=f"{al!r} 0 0")
    if flange is not None:
        rows += fixed(xyz=f"0 0 {float(flange[2, 3])!r}")
    rows.append('<link name="tip"/>')
    rows.append(f'<joint name="tipj" type="fixed"><parent link="l{len(links) - 1}"/><child link="tip"/></joint>')
    return "\n".join(rows + ["</robot>"])


def test_ur10_matches_published_dh_and_pinocchio(rng):
    model = robots.load("ur10")["arm"]
    q = _configs(model, rng)
    T = forward_kinematics(model, q)
    _assert_poses_equal(T, dh_fk(q, **UR10_DH))
    _assert_poses_equal(T, _pinocchio_fk(_dh_urdf(UR10_DH, False), "tip", {f"q{i + 1}": q[:, i] for i in range(6)}))


def test_panda_matches_published_mdh_and_pinocchio(rng):
    model = robots.load("panda")["arm"]
    q = _configs(model, rng)
    T = forward_kinematics(model, q)
    _assert_poses_equal(T, dh_fk(q, **PANDA_MDH, modified=True, flange=PANDA_FLANGE))
    ref = _pinocchio_fk(_dh_urdf(PANDA_MDH, True, PANDA_FLANGE), "tip", {f"q{i + 1}": q[:, i] for i in range(7)})
    _assert_poses_equal(T, ref)


def test_klimchik3r_positions_equal_eq21(rng):
    model = robots.load("klimchik3r")["arm"]
    q = _configs(model, rng)
    T = forward_kinematics(model, q)
    l1, l2, l3 = 1.0, 0.8, 0.6
    q1, q2, q3 = q.T
    r = l2 * np.cos(q2) + l3 * np.cos(q2 + q3)
    eq21 = np.stack([r * np.cos(q1), r * np.sin(q1), l1 + l2 * np.sin(q2) + l3 * np.sin(q2 + q3)], axis=-1)
    assert np.abs(T[:, :3, 3] - eq21).max() < TOL
    # orientation: phi_z = q1 and a rotation of -(q2 + q3) about y (eq. 21's phi_y sign is not right-handed)
    R = Rotation.from_euler("ZY", np.stack([q1, -(q2 + q3)], axis=-1)).as_matrix()
    ang = Rotation.from_matrix(np.swapaxes(T[:, :3, :3], -1, -2) @ R).magnitude().max()
    assert ang < TOL


@pytest.mark.parametrize("name", ["frida", "klimchik3r", "panda", "ur10"])
def test_every_builtin_matches_pinocchio_on_its_exported_urdf(name, rng):
    for model in robots.load(name).arms.values():
        q = _configs(model, rng, 200)
        ref = _pinocchio_fk(to_urdf(model), "tool", {n: q[:, i] for i, n in enumerate(model.joint_names)})
        _assert_poses_equal(forward_kinematics(model, q), ref)


def test_ur10_matches_universal_robots_forward_kinematics_check():
    """The built-in UR10 against the check in Universal Robots' own driver (ur_calibration's test of the ideal
    UR10): joint values and expected tool position copied from there (issue #12, item 7)."""
    q = np.array([[-1.6007002035724085, -1.7271001974688929, -2.2029998938189905, -0.8079999128924769,
                   1.5951000452041626, -0.0309999624835413]])
    p = forward_kinematics(robots.load("ur10")["arm"], q)[0, :3, 3]
    np.testing.assert_allclose(p, [-0.179925914147547, -0.606869755162764, 0.230789102067257], atol=1e-9)
