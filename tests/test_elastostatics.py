"""Joint compliance under known loads (seed 001: theta = q + o + c J_b^T w), end to end."""

import time

import numpy as np
import pytest
import yaml

from kincal.cli import main
from kincal.errors import DataFormatError, ModelError
from kincal.estimation import calibrate
from kincal.io.datasets import load_dataset, write_dataset
from kincal.io.models import dump_robot, parse_robot
from kincal.kinematics import body_jacobian, forward_kinematics, load_torques, loaded_forward_kinematics
from kincal.kinematics import Robot
from kincal.robots import load
from kincal.simulate.generators import generate_markers, generate_pose
from kincal.simulate.noise import Noise
from kincal.simulate.perturb import perturb_robot

EXACT = 1e-9
PAYLOAD_N = 2500.0  # the paper's 250 kg


def _with_compliance(robot, rng, low=1e-6, high=1e-5):
    """Realistic joint compliances, 1e-6 .. 1e-5 rad/(N m), drawn per joint."""
    return Robot(robot.name, {k: m.replace(compliance=rng.uniform(low, high, m.dof)) for k, m in robot.arms.items()})


def _compliances(res, robot, arm="arm"):
    names = [f"{arm}.{j}.compliance" for j in robot[arm].joint_names]
    return np.array([res.estimate(n).value for n in names]), np.array([res.estimate(n).std for n in names])


def test_a_downward_force_makes_a_horizontal_arm_sag():
    """klimchik3r at q = 0 stretches along x: a load pulling the tool down (-z) deflects it down, by the
    joint torques' lever arms (j2 at 1.4 m, j3 at 0.6 m from the tool), and tau = J_b^T w."""
    arm = load("klimchik3r")["arm"].replace(compliance=[1e-5, 2e-5, 3e-5])
    q = np.zeros(3)
    T0 = forward_kinematics(arm, q)
    w = np.concatenate([T0[:3, :3].T @ np.array([0.0, 0.0, -1000.0]), np.zeros(3)])  # world -z, in the tool frame
    tau = load_torques(arm, q, w)
    np.testing.assert_allclose(tau, body_jacobian(arm, q).T @ w, atol=1e-12)
    sag = loaded_forward_kinematics(arm, q, w)[:3, 3] - T0[:3, 3]
    assert sag[2] < 0
    expected = 2e-5 * 1400 * 1.4 + 3e-5 * 600 * 0.6  # small rotations: c_i tau_i times the lever arm
    assert abs(-sag[2] - expected) < 0.02 * expected
    np.testing.assert_allclose(loaded_forward_kinematics(arm, q, np.zeros(6)), T0, atol=0)


def test_model_files_round_trip_compliance_and_name_bad_values():
    ur = load("ur10")
    c = np.array([1e-6, 2.5e-6, 3e-6, 7e-6, 1e-5, 0.0])
    robot = Robot("ur10", {"arm": ur["arm"].replace(compliance=c)})
    text = dump_robot(robot)
    assert "compliance: 2.5e-06" in text
    back = parse_robot(text, "model.yaml")
    assert back == robot and np.array_equal(back["arm"].compliance, c)
    assert back != ur  # compliance is part of model equality
    data = yaml.safe_load(text)
    data["arms"]["arm"]["joints"][1]["compliance"] = -1e-6
    with pytest.raises(DataFormatError, match=r"model.yaml: arms.arm.joints\[1\].compliance: expected a compliance "
                                              r">= 0 \(angle unit/\(N m\)\), found -1e-06"):
        parse_robot(yaml.safe_dump(data), "model.yaml")
    data["arms"]["arm"]["joints"][1]["compliance"] = float("inf")
    with pytest.raises(DataFormatError, match=r"joints\[1\].compliance: expected a finite number"):
        parse_robot(yaml.safe_dump(data), "model.yaml")
    with pytest.raises(ModelError, match="compliance must have 6 entries"):
        ur["arm"].replace(compliance=[1e-6] * 5)
    with pytest.raises(ModelError, match="compliance must be >= 0"):
        ur["arm"].replace(compliance=[-1e-6] * 6)
    # file units: revolute compliance in <angle unit>/(N m)
    data["units"]["angle"] = "deg"
    data["arms"]["arm"]["joints"][1]["compliance"] = 1.0
    for j in data["arms"]["arm"]["joints"]:  # twists are unitless in w; v in length units (m): unchanged
        j.pop("limits", None)
    deg = parse_robot(yaml.safe_dump(data), "model.yaml")
    assert deg["arm"].compliance[1] == pytest.approx(np.pi / 180)


@pytest.fixture(scope="module")
def ur10_case():
    ur = load("ur10")
    true = _with_compliance(perturb_robot(ur, "fine", 3), np.random.default_rng(11))
    ds, _, val = generate_markers(true, n=60, rng=4, markers=3, wrench=PAYLOAD_N)
    return ur, true, ds, val


def test_ur10_geometry_and_compliance_from_loaded_markers_noise_free(ur10_case):
    """Tracker of unknown pose, 3 unknown markers, 2500 N random loads, nominal model with zero compliance:
    every compliance to 1e-9 relative (noise-free data; the solve stops at ~1e-13, limited by round-off of
    metre-sized residuals against millimetre deflections) and fresh loaded marker positions to 1e-9 m."""
    ur, true, ds, val = ur10_case
    res = calibrate(ur, [ds], ["kinematic", "elastic"], validation=list(val.values()))
    assert res.status == "converged"
    c, std = _compliances(res, ur)
    truth = true["arm"].compliance
    assert np.max(np.abs(c - truth) / truth) < EXACT
    assert all(res.estimate(f"arm.{j}.compliance").identifiable for j in ur["arm"].joint_names)
    assert not any("compliance" in m for m in res.messages)
    np.testing.assert_allclose(res.robot["arm"].compliance, c, rtol=0, atol=1e-18)
    v = res.validation[0]
    assert v.before.position_rms > 1e-3 and v.after.position_max < EXACT
    assert "wrench_tool" in val["arm"].measured  # the validation configurations are loaded too


def test_without_loads_compliance_is_reported_unidentifiable():
    r = load("klimchik3r")
    true = _with_compliance(perturb_robot(r, "fine", 3), np.random.default_rng(1))
    ds, _, _ = generate_markers(true, n=30, rng=4, markers=3)
    assert "wrench_tool" not in ds.measured
    res = calibrate(r, [ds], ["kinematic", "elastic"])
    for j in r["arm"].joint_names:
        e = res.estimate(f"arm.{j}.compliance")
        assert not e.identifiable and np.isnan(e.std)
        assert any(m.startswith(f"arm.{j}.compliance cannot be identified") and "does not affect any residual" in m
                   and "no data set applies a load" in m for m in res.messages)


def test_pose_data_with_loads_noise_free():
    r = load("klimchik3r")
    true = _with_compliance(perturb_robot(r, "fine", 5), np.random.default_rng(2))
    ds, _, _ = generate_pose(true, n=20, rng=6, wrench=PAYLOAD_N)
    res = calibrate(r, [ds], ["kinematic", "elastic"])
    c, _ = _compliances(res, r)
    assert np.max(np.abs(c - true["arm"].compliance) / true["arm"].compliance) < EXACT


def test_compliance_standard_deviations_match_the_scatter():
    """klimchik3r, 3 markers, tracker 0.02 mm, 2500 N random loads, 120 seeded repetitions of 20
    configurations: (estimate - truth) / reported std over the 3 joints has unit spread."""
    r = load("klimchik3r")
    true = _with_compliance(perturb_robot(r, "fine", 3), np.random.default_rng(3))
    noise = Noise(position=2e-5)
    z = []
    start = time.perf_counter()
    for rep in range(120):
        ds, _, _ = generate_markers(true, n=20, rng=1000 + rep, markers=3, noise=noise, wrench=PAYLOAD_N)
        res = calibrate(r, [ds], ["kinematic", "elastic"], noise=_stated(2e-5))
        c, std = _compliances(res, r)
        z.append((c - true["arm"].compliance) / std)
    z = np.concatenate(z)
    assert 0.75 < np.std(z) < 1.3
    assert abs(np.mean(z)) < 0.3
    assert time.perf_counter() - start < 60


def _stated(sigma_m):
    from kincal.estimation.problem import Noise as Stated

    return Stated(position=sigma_m, orientation=1e-5, joint=0.0)


@pytest.mark.parametrize("kind", ["pose", "markers"])
def test_dataset_files_round_trip_wrench_columns(tmp_path, kind):
    r = load("klimchik3r")
    gen = generate_pose if kind == "pose" else generate_markers
    ds, _, _ = gen(r, n=5, rng=1, wrench=PAYLOAD_N)
    m = write_dataset(ds, tmp_path / f"{kind}.yaml", r, model="klimchik3r")
    assert "wrench.fx" in (tmp_path / f"{kind}.csv").read_text().splitlines()[0]
    back = load_dataset(m)
    np.testing.assert_array_equal(back.measured["wrench_tool"], ds.measured["wrench_tool"])


def test_job_with_elastic_level_writes_compliances(tmp_path, capsys):
    r = load("klimchik3r")
    true = _with_compliance(perturb_robot(r, "fine", 3), np.random.default_rng(4))
    ds, _, _ = generate_markers(true, n=30, rng=4, markers=3, wrench=PAYLOAD_N)
    write_dataset(ds, tmp_path / "loaded.yaml", r, model="klimchik3r")
    (tmp_path / "job.yaml").write_text("format: kincal-job\nversion: 1\nmodel: klimchik3r\ndata: [loaded.yaml]\n"
                                       "free: [kinematic, elastic]\n")
    assert main(["calibrate", str(tmp_path / "job.yaml"), "-o", str(tmp_path / "out"), "--quiet"]) == 0
    model = yaml.safe_load((tmp_path / "out" / "model.yaml").read_text())
    c = np.array([j["compliance"] for j in model["arms"]["arm"]["joints"]])
    np.testing.assert_allclose(c, true["arm"].compliance, rtol=1e-7)
    result = yaml.safe_load((tmp_path / "out" / "result.yaml").read_text())
    units = {e["name"]: e["unit"] for e in result["estimates"]}
    assert units["arm.j2.compliance"] == "rad/Nm"


def test_perturbation_compliance_keeps_the_other_draws():
    ur = load("ur10")
    plain = perturb_robot(ur, "fine", 3)
    soft = perturb_robot(ur, "fine", 3, compliance=1e-5)
    assert soft["arm"].replace(compliance=None) == plain["arm"]
    assert np.all((soft["arm"].compliance > 0) & (soft["arm"].compliance <= 1e-5))
    ds0, _, _ = generate_markers(plain, n=5, rng=2)
    ds1, _, _ = generate_markers(soft, n=5, rng=2)  # no loads: compliance has no effect
    np.testing.assert_array_equal(ds0.measured["p_tracker_marker"], ds1.measured["p_tracker_marker"])
