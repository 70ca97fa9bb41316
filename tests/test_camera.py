"""The camera kind (a pinhole camera of known intrinsics sees one tool point), added in three files: its
experiment module, its generator module and this test. Jacobians, whitening, calibration, files, scenarios."""

import numpy as np
import pytest
import yaml

from kincal.data import Dataset
from kincal.errors import DataFormatError, ModelError
from kincal.estimation import calibrate
from kincal.experiments.camera import camera_from_views, project
from kincal.io.datasets import load_dataset, load_scenario, write_dataset
from kincal.kinematics import forward_kinematics
from kincal.lie import se3, so3
from kincal.noise import Noise
from kincal.robots import load
from kincal.simulate import perturb_robot, perturbation
from kincal.simulate.generators import generate_camera
from kincal.simulate.scenario import build_scenario, run
from test_residuals import _robot, check_residual

PIXEL_SIGMA = 0.1
NOISE = Noise(joint=1e-7, other={"pixel": PIXEL_SIGMA})
OFFSETS_ONLY = perturbation("thesis", twist_m=0.0, twist_rad=0.0, home_m=0.0, home_rad=0.0)


def _looking_at_origin(rng, distance=8.0):
    """A camera ``distance`` from the origin with its z axis through it (every test arm point in front)."""
    z = rng.normal(size=3)
    z /= np.linalg.norm(z)
    x = np.cross(z, rng.normal(size=3))
    x /= np.linalg.norm(x)
    return se3.make(np.stack([x, np.cross(z, x), z], axis=-1), -distance * z)


def _consistent(rng, robot, n=4):
    a = robot["a"]
    q = rng.uniform(-2, 2, (n, a.dof))
    C, x, K = _looking_at_origin(rng), rng.uniform(-0.1, 0.1, 3), np.array([1.5, 1.2, 0.1, -0.2])
    uv = project(se3.transform_points(se3.inverse(C) @ forward_kinematics(a, q), x), K)[0]
    return Dataset("camera", "r", ("a",), {"a": q}, {"pixel": uv},
                   {"intrinsics": K, "T_world_camera": C, "p_tool_point": x})


@pytest.mark.parametrize("prismatic", [(), (2,)])
def test_residual_zero_at_truth_and_jacobian_matches_differences(rng, prismatic):
    robot = _robot(rng, prismatic)
    check_residual(rng, robot, _consistent(rng, robot))


def test_projection_and_camera_placement(rng):
    C = _looking_at_origin(rng, 3.0)
    p = rng.uniform(-0.8, 0.8, (20, 3))
    K = np.array([800.0, 790.0, 640.0, 480.0])
    uv, D = project(se3.transform_points(se3.inverse(C), p), K)
    c = se3.transform_points(se3.inverse(C), p)
    np.testing.assert_allclose(uv[:, 0], 800 * c[:, 0] / c[:, 2] + 640)
    np.testing.assert_allclose(C[:3, :3] @ [0, 0, 1.0], -C[:3, 3] / 3.0, atol=1e-12)  # looks at the origin
    np.testing.assert_allclose(camera_from_views(p, uv, K), C, atol=1e-9)
    assert camera_from_views(p[:5], uv[:5], K) is None  # too few views to place it


@pytest.fixture(scope="module")
def ur10():
    return load("ur10")


def _offset_errors(res, true):
    return res.robot["arm"].offsets - true["arm"].offsets


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_offsets_recovered_with_known_camera_and_point(ur10, seed):
    """Joint offsets of thesis size (up to 0.07 rad), pixel noise 0.1 px: every offset is identifiable from the
    pixels when the camera and the point are known, and found within 4 reported standard deviations."""
    true = perturb_robot(ur10, OFFSETS_ONLY, seed)
    ds, truth, val = generate_camera(true, n=60, rng=10 + seed, noise=Noise(other={"pixel": PIXEL_SIGMA}),
                                     known_camera=True, known_point=True)
    res = calibrate(ur10, [ds], "offsets", noise=NOISE, validation=list(val.values()))
    assert res.status == "converged" and res.identifiability.rank == 6 and not res.messages
    std = np.array([e.std for e in res.estimates if e.name.endswith(".offset")])
    err = _offset_errors(res, true)
    assert np.all(np.abs(err) < 4 * std) and np.abs(err).max() < 5e-3
    assert np.abs(ur10["arm"].offsets - true["arm"].offsets).max() > 0.02
    v = res.validation[0]
    assert v.kind == "camera" and v.before.pixel_rms > 2.0 and v.after.pixel_rms < 3 * PIXEL_SIGMA


def test_unknown_camera_and_point_name_what_pixels_cannot_see(ur10):
    """With the camera and point unknown, the first joint's offset turns with the camera and the last joint's
    moves the point about its axis: kincal names both trade-offs; the others are recovered."""
    true = perturb_robot(ur10, OFFSETS_ONLY, 4)
    ds, truth, val = generate_camera(true, n=60, rng=5, noise=Noise(other={"pixel": PIXEL_SIGMA}))
    res = calibrate(ur10, [ds], "offsets", noise=NOISE, validation=list(val.values()))
    assert res.status == "converged" and res.identifiability.rank == 13  # 6 offsets + 6 camera + 3 point - 2
    text = "\n".join(res.messages)
    assert "arm.shoulder_pan.offset cannot be identified" in text and "a rotation of the camera about the axis of " \
        "arm.shoulder_pan" in text
    assert "arm.wrist_3.offset cannot be identified" in text and "point.x" in text
    assert np.abs(_offset_errors(res, true)[1:5]).max() < 5e-3
    assert res.validation[0].after.pixel_rms < 3 * PIXEL_SIGMA


def test_full_kinematic_calibration_from_pixels(ur10):
    """Every geometric parameter from 300 views of one point, camera and point unknown. The pixels see the tool
    point's position up to a rigid motion (with the camera) and up to scale: kincal says scale cannot be
    identified, also with camera and point known (home absorbs the known point offset; a projection does not
    change when every length scales about the camera). Fresh configurations: predicted pixels match the truth."""
    true = perturb_robot(ur10, "fine", 3)
    ds, truth, val = generate_camera(true, n=300, rng=4, noise=Noise(other={"pixel": PIXEL_SIGMA}))
    res = calibrate(ur10, [ds], "kinematic", noise=NOISE, validation=list(val.values()))
    assert res.status == "converged" and res.identifiability.rank == 26  # a one-marker tracker gives 27, less scale
    assert any(m.startswith("scale cannot be identified") for m in res.messages)
    v = res.validation[0]
    assert v.before.pixel_rms > 1.0 and v.after.pixel_rms < 2 * PIXEL_SIGMA
    # held out, nothing refitted: the calibrated arm, camera and point predict the true pixels
    qv = val["arm"].q["arm"]
    K = ds.known["intrinsics"]
    pred = project(se3.transform_points(se3.inverse(res.extras["camera"]) @ forward_kinematics(res.robot["arm"], qv),
                                        res.extras["point"]), K)[0]
    assert np.sqrt(np.mean(np.sum((pred - val["arm"].measured["pixel"]) ** 2, axis=-1))) < 2 * PIXEL_SIGMA
    known, _, _ = generate_camera(true, n=300, rng=4, noise=Noise(other={"pixel": PIXEL_SIGMA}), known_camera=True,
                                  known_point=True)
    res = calibrate(ur10, [known], "kinematic", noise=NOISE)
    assert any(m.startswith("scale cannot be identified") for m in res.messages)


def test_pixel_noise_must_be_stated(ur10):
    ds, _, _ = generate_camera(ur10, n=20, rng=1, known_camera=True, known_point=True)
    with pytest.raises(ModelError, match=r"pixel residuals \(px\) but the stated noise gives no pixel standard "
                                         r"deviation"):
        calibrate(ur10, [ds], "offsets", noise=Noise(position=1e-5, joint=1e-5))


def test_manifest_round_trip(tmp_path, ur10):
    ds, truth, _ = generate_camera(ur10, n=12, rng=2, noise=Noise(other={"pixel": 0.3}), known_camera=True,
                                   known_point=True)
    path = write_dataset(ds, tmp_path / "cam.yaml", ur10, model="ur10", angle="deg", length="mm")
    text = (tmp_path / "cam.csv").read_text().splitlines()[0]
    assert text.endswith("pixel.u,pixel.v")
    manifest = yaml.safe_load(path.read_text())
    assert manifest["noise"] == {"pixel_px": 0.3} and manifest["known"]["intrinsics"] == [800.0, 800.0, 640.0, 480.0]
    np.testing.assert_allclose(manifest["known"]["p_tool_point"], truth.values["p_tool_point"] * 1000)
    back = load_dataset(path)
    assert back.kind == "camera" and back.meta["noise"] == {"pixel_px": 0.3}
    np.testing.assert_allclose(back.measured["pixel"], ds.measured["pixel"], rtol=1e-15)
    for key in ("T_world_camera", "p_tool_point", "intrinsics"):
        np.testing.assert_allclose(back.known[key], ds.known[key], atol=1e-12)
    np.testing.assert_allclose(back.q["arm"], ds.q["arm"], atol=1e-12)
    manifest["known"]["intrinsics"] = [800.0, 640.0, 480.0]
    path.write_text(yaml.safe_dump(manifest))
    with pytest.raises(DataFormatError,
                       match=r"cam\.yaml: known\.intrinsics: expected a list of 4 numbers, found a list of length 3"):
        load_dataset(path)


SCENARIO = """\
format: kincal-scenario
version: 1
name: ur10-camera
model: ur10
seed: 3
units: {length: mm, angle: deg}
truth: {level: fine}
experiment:
  kind: camera
  n: 40
  T_world_camera: {xyz: [2500, 0, 400], rpy: [-90, 0, 90]}
  p_tool_point: [0, 50, 80]
  known_point: true
  intrinsics: [900, 900, 640, 480]
noise: {pixel_px: 0.2, joint_deg: 0.001}
validation: 10
"""


def test_scenario_through_the_generic_loader(tmp_path):
    (tmp_path / "s.yaml").write_text(SCENARIO)
    spec = load_scenario(tmp_path / "s.yaml")
    assert spec["kind"] == "camera" and spec["options"]["known_point"] is True
    np.testing.assert_allclose(spec["options"]["p_tool_point"], [0, 0.05, 0.08])
    np.testing.assert_allclose(spec["options"]["T_world_camera"][:3, 3], [2.5, 0, 0.4])
    assert spec["noise"].sigma("pixel") == 0.2
    true, ds, truth, validation = run(build_scenario(spec))
    assert ds.kind == "camera" and ds.size == 40 and ds.name == "ur10-camera"
    np.testing.assert_allclose(ds.known["p_tool_point"], [0, 0.05, 0.08])
    assert "T_world_camera" not in ds.known and validation["arm"].kind == "camera"
    R = truth.values["T_world_camera"][:3, :3]
    np.testing.assert_allclose(R, so3.exp(np.array([0, 0, np.pi / 2])) @ so3.exp(np.array([-np.pi / 2, 0, 0])),
                               atol=1e-12)
    for old, new, message in (
        ("known_point: true", "known_point: 1", r"experiment\.known_point: expected true or false, found 1"),
        ("intrinsics: [900, 900, 640, 480]", "intrinsics: [900, 900]",
         r"experiment\.intrinsics: expected a list of 4 numbers, found a list of length 2"),
        ("n: 40", "nn: 40", r"experiment\.nn: unknown key 'nn'; allowed keys: T_world_camera, arm, image, intrinsics"),
    ):
        (tmp_path / "s.yaml").write_text(SCENARIO.replace(old, new))
        with pytest.raises(DataFormatError, match=message):
            load_scenario(tmp_path / "s.yaml")


def test_job_with_camera_data_and_validation(tmp_path):
    """Files all the way: the scenario simulated and written, a job calibrates from the data set's own pixel
    noise and scores the written validation set (noise-free, stated as 0 px) in pixels."""
    from kincal.io.datasets import write_simulation
    from kincal.io.jobs import load_job
    from kincal.workflow import run_job

    (tmp_path / "s.yaml").write_text(SCENARIO.replace("truth: {level: fine}", "truth: {level: thesis, twist_mm: 0, "
                                                      "twist_deg: 0, home_mm: 0, home_deg: 0}"))
    sc = build_scenario(load_scenario(tmp_path / "s.yaml"))
    true, ds, truth, validation = run(sc)
    write_simulation(tmp_path / "out", ds, truth, validation, sc.robot, model=sc.model)
    (tmp_path / "job.yaml").write_text(yaml.safe_dump({
        "format": "kincal-job", "version": 1, "model": "ur10", "data": ["out/data.yaml"],
        "validation": ["out/validation/arm.yaml"], "free": "offsets"}))
    res = run_job(load_job(tmp_path / "job.yaml"))
    v = res.validation[0]
    assert res.status == "converged" and v.kind == "camera"
    assert v.before.pixel_rms > 2.0 and v.after.pixel_rms < 3 * 0.2


def test_a_camera_that_cannot_see_the_arm_says_so(ur10):
    from kincal.errors import DegenerateExperimentError

    away = se3.make(np.eye(3), np.array([0.0, 0.0, 3.0]))  # above the arm, looking up
    with pytest.raises(DegenerateExperimentError, match="place the camera to see the arm"):
        generate_camera(ur10, n=10, rng=1, T_world_camera=away)
