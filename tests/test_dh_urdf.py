"""DH / modified-DH and URDF import against independent forward kinematics (per-link products, pinocchio)."""

import sys
from pathlib import Path

import numpy as np
import pytest

from kincal import robots
from kincal.errors import DataFormatError, ModelError, ShapeError
from kincal.kinematics import forward_kinematics
from kincal.kinematics.dh import from_dh
from kincal.io.urdf import from_urdf, to_urdf
from kincal.testing import random_arm

from reference_dh import dh_fk, tr

pin = pytest.importorskip("pinocchio")
pytest.importorskip("yourdfpy")

DATASETS = Path(__file__).resolve().parents[2] / "shared" / "datasets"


@pytest.mark.parametrize("modified", [False, True])
def test_random_dh_tables_with_prismatic_joints(rng, modified):
    n = 6
    a, alpha, d, theta = (rng.uniform(-0.5, 0.5, n), rng.uniform(-np.pi, np.pi, n), rng.uniform(-0.5, 0.5, n),
                          rng.uniform(-np.pi, np.pi, n))
    prismatic = [False, False, True, False, True, False]
    types = ["prismatic" if p else "revolute" for p in prismatic]
    model = from_dh(a, alpha, d, theta, modified=modified, joint_types=types)
    q = rng.uniform(-2, 2, (50, n))
    np.testing.assert_allclose(forward_kinematics(model, q), dh_fk(q, a, alpha, d, theta, prismatic, modified),
                               atol=1e-13)


def test_dh_flange_and_model_fields():
    model = from_dh([0, 0.5], [0, 0], [0.1, 0], modified=True, flange=tr(0, 0.2), name="two", lower=[-1, -2],
                    upper=[1, 2], joint_names=("a", "b"))
    np.testing.assert_allclose(model.home[:3, 3], [0.5, 0, 0.3])
    assert model.name == "two" and model.joint_names == ("a", "b") and model.lower.tolist() == [-1, -2]


def test_dh_rejects_ragged_table():
    with pytest.raises(ShapeError, match="DH column d"):
        from_dh([0, 0], [0, 0], [0.1])


# ------------------------------------------------------------------------------- pybotics UR10 vectors


def _pybotics_vectors():
    path = DATASETS / "pybotics-fk-vectors" / "ur10-joints-poses.csv"
    if not path.is_file():
        pytest.skip(f"data set not available: {path}")
    data = np.loadtxt(path, delimiter=",", comments="#")
    T = data[:, 6:].reshape(-1, 4, 4).copy()
    T[:, :3, 3] *= 1e-3  # mm -> m
    return np.radians(data[:, :6]), T


def test_pybotics_mdh_table_imports_to_their_fk_vectors():
    q, T = _pybotics_vectors()
    # pybotics ur10(): rows [alpha, a, theta, d] in rad, mm (SOURCE.md)
    model = from_dh(alpha=[0, np.pi / 2, 0, 0, -np.pi / 2, np.pi / 2], a=[0, 0, 0.6127, 0.5716, 0, 0],
                    theta=[0, np.pi, 0, 0, 0, np.pi], d=[0.118, 0, 0, 0.1639, 0.1157, 0.0922], modified=True)
    got = forward_kinematics(model, q)
    assert np.abs(got[:, :3, 3] - T[:, :3, 3]).max() < 1e-12
    assert np.abs(got[:, :3, :3] - T[:, :3, :3]).max() < 1e-12


def test_builtin_ur10_is_universal_robots_table_not_pybotics():
    """pybotics' UR10 (the vectors above) is another UR10 table (d1 0.118, a2 0.6127, a3 0.5716, d4 0.1639);
    the built-in follows Universal Robots' CB3 table since issue #12 item 7 (checked against the
    manufacturer's own forward-kinematics test in tests/test_robots.py). The two differ by millimetres."""
    q, T = _pybotics_vectors()
    got = forward_kinematics(robots.load("ur10")["arm"], q)
    gap = np.linalg.norm(got[:, :3, 3] - T[:, :3, 3], axis=1)
    assert 1e-3 < np.median(gap) < 0.05


# ------------------------------------------------------------------------------------------- URDF import


def _pin_fk(urdf, base, tip, q_by_name, from_file=False):
    model = pin.buildModelFromUrdf(urdf) if from_file else pin.buildModelFromXML(urdf)
    data = model.createData()
    fb, ft = model.getFrameId(base), model.getFrameId(tip)
    n = len(next(iter(q_by_name.values())))
    out = np.empty((n, 4, 4))
    for k in range(n):
        q = pin.neutral(model)
        for j in range(1, model.njoints):
            jm, name = model.joints[j], model.names[j]
            if name in q_by_name:
                v = q_by_name[name][k]
                q[jm.idx_q:jm.idx_q + jm.nq] = [np.cos(v), np.sin(v)] if jm.nq == 2 else [v]
        pin.framesForwardKinematics(model, data, q)
        out[k] = np.linalg.inv(data.oMf[fb].homogeneous) @ data.oMf[ft].homogeneous
    return out


MIXED_URDF = """<?xml version="1.0"?>
<robot name="mixed">
  <link name="world"/><link name="base"/><link name="a"/><link name="b"/><link name="c"/><link name="d"/>
  <link name="e"/><link name="tip"/><link name="side"/>
  <joint name="mount" type="fixed"><parent link="world"/><child link="base"/>
    <origin xyz="0.1 -0.2 0.3" rpy="0.1 0.2 0.3"/></joint>
  <joint name="j1" type="revolute"><parent link="base"/><child link="a"/>
    <origin xyz="0 0 0.3" rpy="0 0 0.5"/><axis xyz="0 0 1"/>
    <limit lower="-2.5" upper="2.5" effort="10" velocity="1"/></joint>
  <joint name="j2" type="continuous"><parent link="a"/><child link="b"/>
    <origin xyz="0.05 0.1 0.2" rpy="1.2 -0.4 0.7"/><axis xyz="1 2 2"/></joint>
  <joint name="bracket" type="fixed"><parent link="b"/><child link="c"/>
    <origin xyz="0.3 0 -0.1" rpy="0 1.5707963267948966 0"/></joint>
  <joint name="slide" type="prismatic"><parent link="c"/><child link="d"/>
    <origin xyz="0 0.1 0" rpy="0.3 0 0"/><axis xyz="0 1 0"/>
    <limit lower="0" upper="0.4" effort="10" velocity="1"/></joint>
  <joint name="j4" type="revolute"><parent link="d"/><child link="e"/>
    <origin xyz="0.1 0.1 0.1" rpy="-0.2 0.3 -2.8"/><axis xyz="0.6 -0.8 0"/>
    <limit lower="-1" upper="1" effort="10" velocity="1"/></joint>
  <joint name="flange" type="fixed"><parent link="e"/><child link="tip"/>
    <origin xyz="0 0 0.12" rpy="3.0 0.1 -1.0"/></joint>
  <joint name="branch" type="revolute"><parent link="a"/><child link="side"/>
    <origin xyz="1 0 0"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>
"""


def test_urdf_chain_with_fixed_prismatic_continuous_and_tilted_axes(rng):
    model = from_urdf(MIXED_URDF, "world", "tip")
    assert model.joint_names == ("j1", "j2", "slide", "j4")
    assert model.joint_types == ("revolute", "revolute", "prismatic", "revolute")
    np.testing.assert_array_equal(model.lower, [-2.5, -np.inf, 0, -1])
    np.testing.assert_array_equal(model.upper, [2.5, np.inf, 0.4, 1])
    lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
    up = np.where(np.isfinite(model.upper), model.upper, np.pi)
    q = rng.uniform(lo, up, (300, 4))
    ref = _pin_fk(MIXED_URDF, "world", "tip", {n: q[:, i] for i, n in enumerate(model.joint_names)})
    np.testing.assert_allclose(forward_kinematics(model, q), ref, atol=1e-13)


def test_urdf_errors_name_file_and_links(tmp_path):
    with pytest.raises(DataFormatError, match="tip_link 'nowhere' is not a link"):
        from_urdf(MIXED_URDF, "world", "nowhere")
    with pytest.raises(DataFormatError, match="tip_link 'side' is not below base_link 'b'"):
        from_urdf(MIXED_URDF, "b", "side")
    with pytest.raises(DataFormatError, match="no such URDF file"):
        from_urdf(tmp_path / "none.urdf", "a", "b")
    mimic = MIXED_URDF.replace('<axis xyz="0.6 -0.8 0"/>', '<axis xyz="0.6 -0.8 0"/><mimic joint="j1"/>')
    with pytest.raises(DataFormatError, match="joint 'j4': mimic joints are not supported"):
        from_urdf(mimic, "world", "tip")


def test_missing_yourdfpy_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "yourdfpy", None)
    with pytest.raises(ModelError, match=r"kincal\[urdf\]"):
        from_urdf(MIXED_URDF, "world", "tip")


def test_export_import_round_trip_with_offsets_and_prismatic(rng):
    arm = random_arm(rng, 7, prismatic=(3,))
    arm = arm.replace(lower=np.full(7, -2.0), upper=np.full(7, 2.0))
    back = from_urdf(to_urdf(arm), "world", "tool", base=np.eye(4))
    assert back.joint_names == arm.joint_names
    q = rng.uniform(-2, 2, (100, 7))
    np.testing.assert_allclose(forward_kinematics(back, q), forward_kinematics(arm, q), atol=1e-13)
    np.testing.assert_array_equal(back.lower, arm.lower)
    ref = _pin_fk(to_urdf(arm), "world", "tool", {n: q[:, i] for i, n in enumerate(arm.joint_names)})
    np.testing.assert_allclose(forward_kinematics(arm, q), ref, atol=1e-13)


# ---------------------------------------------------------------------------- URDFs shipped with data sets


def _dataset_file(*parts):
    path = DATASETS.joinpath(*parts)
    if not path.is_file():
        pytest.skip(f"data set not available: {path}")
    return path


def test_figaroh_ur10_urdf_import_matches_pinocchio(rng):
    path = _dataset_file("figaroh-geometric", "ur10", "ur10_robot.urdf")
    model = from_urdf(path, "base_link", "tool0")
    assert model.joint_names == ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
                                 "wrist_2_joint", "wrist_3_joint")
    q = rng.uniform(model.lower, model.upper, (200, 6))
    ref = _pin_fk(str(path), "base_link", "tool0", {n: q[:, i] for i, n in enumerate(model.joint_names)}, True)
    np.testing.assert_allclose(forward_kinematics(model, q), ref, atol=1e-12)


def test_mukca_panda_urdf_import_matches_pinocchio_and_builtin_panda(rng):
    path = _dataset_file("mukca-fixed-point", "urdf", "panda.urdf")
    names = tuple(f"panda_joint{i}" for i in range(1, 8))
    to_ball = from_urdf(path, "panda_link0", "ball_link")
    assert to_ball.joint_names == names  # the fixed hand, tcp and ball joints are folded into home
    q = rng.uniform(to_ball.lower, to_ball.upper, (200, 7))
    by_name = {n: q[:, i] for i, n in enumerate(names)}
    ref = _pin_fk(str(path), "panda_link0", "ball_link", by_name, True)
    np.testing.assert_allclose(forward_kinematics(to_ball, q), ref, atol=1e-12)
    # the built-in panda (from the published MDH table) is the URDF's panda_link0 -> panda_link8
    flange = from_urdf(path, "panda_link0", "panda_link8")
    builtin = robots.load("panda")["arm"]
    np.testing.assert_allclose(forward_kinematics(builtin, q), forward_kinematics(flange, q), atol=1e-12)
    np.testing.assert_array_equal(builtin.lower, flange.lower)
    np.testing.assert_array_equal(builtin.upper, flange.upper)
