"""The thesis' own algorithms reproduce the thesis' findings on noise-free simulated Frida data.

Tolerances were measured on these seeds (see docs/thesis-baselines.md); they pin what the algorithms
do, flaws included, not what a correct calibration would do.
"""

import dataclasses

import numpy as np
import pytest

from kincal import robots
from kincal.baselines import thesis as th
from kincal.baselines.identification import identification_jacobian
from kincal.baselines.thesis_common import damped_step
from kincal.baselines.thesis_dual import pose_errors
from kincal.data import Dataset
from kincal.errors import DegenerateExperimentError, ModelError, ShapeError
from kincal.kinematics import chain, forward_kinematics, space_jacobian
from kincal.lie import se3, so3
from kincal.simulate import generate_clamp, generate_dual, generate_plate, perturb_robot
from kincal.testing import numerical_jacobian, random_pose

# Thesis Tables 4.1, 4.2 and 4.5 ("actual offsets", rad).
OFFSETS = np.array([0.02, -0.03, -0.02, 0.03, 0.015, 0.04, 0.018])


@pytest.fixture(scope="module")
def frida():
    return robots.load("frida")


@pytest.fixture(scope="module")
def offset_robot(frida):
    """True Frida: nominal geometry, both arms with the thesis' joint offsets."""
    return frida.replace_arm("left", frida["left"].replace(offsets=OFFSETS)).replace_arm(
        "right", frida["right"].replace(offsets=OFFSETS)
    )


@pytest.fixture(scope="module")
def clamp_data(offset_robot):
    ds, truth, _ = generate_clamp(offset_robot, "left", n=50, rng=0, known_fixture=True, n_validation=1)
    return ds, truth


@pytest.fixture(scope="module")
def dual_data(offset_robot):
    ds, truth, _ = generate_dual(offset_robot, n=100, rng=0, n_validation=1)
    return ds, truth


# ------------------------------------------------------------------------------------ building blocks


def test_eval_error_is_mean_distance_and_mean_angle(rng):
    T = random_pose(rng, (5,))
    shift = np.array([0.003, 0.0, 0.004])  # 5 mm
    turn = so3.exp(np.array([0.0, 0.02, 0.0]))
    T2 = T.copy()
    T2[:, :3, 3] += shift
    T2[:, :3, :3] = T2[:, :3, :3] @ turn
    trans, rot = th.eval_error(T, T2)
    assert trans == pytest.approx(0.005, abs=1e-15)
    assert rot == pytest.approx(0.02, abs=1e-12)
    assert th.eval_error(T, T) == (0.0, 0.0)


def test_mean_transform_averages_translations_and_rotation_vectors():
    w = np.array([[0.1, 0.2, -0.3], [0.3, 0.0, 0.1], [-0.1, 0.1, 0.2]])
    p = np.array([[0.1, 0.0, 0.0], [0.0, 0.3, 0.0], [0.2, 0.0, 0.6]])
    M = th.mean_transform(se3.make(so3.exp(w), p))
    np.testing.assert_allclose(M[:3, 3], p.mean(axis=0), atol=1e-15)
    np.testing.assert_allclose(so3.log(M[:3, :3]), w.mean(axis=0), atol=1e-12)


def test_damped_step_is_eq_2_55(rng):
    J, y = rng.normal(size=(30, 4)), rng.normal(size=30)
    np.testing.assert_allclose(damped_step(J, y, 0.0), np.linalg.lstsq(J, y, rcond=None)[0], atol=1e-12)
    lam = 2.5
    np.testing.assert_allclose(damped_step(J, y, lam), np.linalg.solve(J.T @ J + lam * np.eye(4), J.T @ y))


def test_residuals_fall_by_the_jacobians_the_baselines_use(offset_robot, dual_data):
    """Finite differences at the truth: each arm's error twist is y(p + d) = -J d, J eq. 2.53 or eq. 2.52."""
    ds, truth = dual_data
    a, b = offset_robot["left"], offset_robot["right"]
    qa, qb = ds.q["left"][:3], ds.q["right"][:3]
    C = truth.values["T_toolA_toolB"]
    Ci = np.linalg.inv(C)
    T_a, T_b = forward_kinematics(a, qa), forward_kinematics(b, qb)

    def y_a(o):  # arm A's offsets, arm B as the measurement
        return pose_errors(forward_kinematics(a.replace(offsets=o), qa), T_b, C, Ci)[0]

    np.testing.assert_allclose(numerical_jacobian(y_a, OFFSETS), -space_jacobian(a, qa), atol=1e-8)

    def y_b(x):  # arm B's twists and xi_st, arm A as the measurement
        home = se3.exp(b.home_twist() + x[42:])
        T = chain(b.screws + x[:42].reshape(7, 6), qb + b.offsets, b.base, home, b.tool).tool
        return pose_errors(T_a, T, C, Ci)[1]

    J = identification_jacobian(b, qb).stacked(("twists", "home"))[0]
    np.testing.assert_allclose(numerical_jacobian(y_b, np.zeros(48)), -J, atol=1e-8)


# -------------------------------------------------------------------- single arm, one fixture (Alg. 3)


def test_known_fixture_recovers_all_offsets_table_4_1(frida, clamp_data):
    ds, _ = clamp_data
    res = th.run("single_offsets", ds, frida)
    np.testing.assert_allclose(res.offsets["left"], OFFSETS, atol=1e-9)
    assert res.iterations == res.accepted <= 5  # thesis: 3(3); measured 4(4)
    assert res.converged
    assert res.final_error[0] < 1e-10 < 1e-3 < res.initial_error[0]
    assert res.parameter_names == tuple(f"left.j{i}.offset" for i in range(1, 8))
    np.testing.assert_array_equal(res.models["left"].offsets, res.estimate)


def test_baseline_result_is_written_with_kincal_schema(frida, clamp_data, tmp_path):
    """The same writer and schema as kincal's result: status, estimates as a list of entries, the model."""
    import yaml

    from kincal.io.models import load_robot
    from kincal.io.results import write_results

    ds, _ = clamp_data
    res = th.run("single_offsets", ds, frida)
    paths = write_results(res, tmp_path, robot=res.calibrated(frida))
    saved = yaml.safe_load(paths["result"].read_text())
    assert saved["status"] == res.status == "converged" and saved["method"] == "thesis.single_offsets"
    assert [e["name"] for e in saved["estimates"]] == list(res.parameter_names)
    np.testing.assert_allclose([e["value"] for e in saved["estimates"]], res.estimate, atol=1e-15)
    np.testing.assert_allclose(load_robot(paths["model"])["left"].offsets, res.estimate, atol=1e-12)


def test_unknown_fixture_gathers_poses_but_misses_joints_1_and_7_table_4_2(frida, clamp_data):
    ds, truth = clamp_data
    res = th.run("single_offsets", ds, frida, T_world_fixture=None)
    err = res.offsets["left"] - OFFSETS
    assert res.iterations_label == "10(10)"  # as in Table 4.2
    # Joints 1 and 7 stay near the initial guess (0): off by about the whole true offset (measured -0.020, -0.023).
    assert abs(err[0]) > 0.015 and abs(err[6]) > 0.015
    # The others come close (measured |err| <= 1.5 mrad, joints 3 and 5 the worst, as in the thesis).
    assert np.abs(err[1:6]).max() < 3e-3
    # Repeatability improves: the spread about the mean pose shrinks (measured 9.2 mm -> 0.43 mm;
    # ratio 0.001-0.09 on seeds 1-4, where joints 1 and 7 also carry the two largest errors).
    assert res.final_error[0] < 0.15 * res.initial_error[0]
    assert set(np.argsort(np.abs(err))[-2:]) == {0, 6}
    # ... but the gathered pose is not the true fixture.
    true_p = truth.values["T_world_fixture"][:3, 3]
    assert np.linalg.norm(res.T_world_fixture[:3, 3] - true_p) > 1e-3


def test_accept_factor_changes_nothing_when_every_step_improves(frida, clamp_data):
    ds, _ = clamp_data
    strict = th.run("single_offsets", ds, frida, T_world_fixture=None)
    relaxed = th.run("single_offsets", ds, frida, T_world_fixture=None, accept_factor=1.5)
    np.testing.assert_array_equal(strict.estimate, relaxed.estimate)


# ------------------------------------------------------------------- several fixed points (Sec. 3.3)


def test_plate_recovers_joints_2_to_7_but_not_joint_1_table_4_4(frida):
    true = frida.replace_arm("left", frida["left"].replace(offsets=OFFSETS))
    ds, truth, _ = generate_plate(true, "left", n=40, rng=0, candidates=10, n_validation=1)
    res = th.run("several_points", ds, frida)
    err = res.offsets["left"] - OFFSETS
    assert np.abs(err[1:]).max() < 1e-5  # measured < 1e-6
    assert abs(err[0]) > 0.005  # joint 1 trades against a rotation of the plate (measured -0.015)
    assert res.cost["eq_3_6"] < 1e-9
    T_true = truth.values["T_world_plate"] @ truth.values["T_plate_fixture"][0]
    miss = np.linalg.norm(res.T_world_fixture[:3, 3] - T_true[:3, 3])
    assert 1e-3 < miss < 0.03  # thesis: 6 mm; measured 5.7 mm
    assert res.parameter_names[-1] == "fixture.w_z" and len(res.estimate) == 13


# ------------------------------------------------------------------------ dual arm, offsets (Alg. 2)


def test_dual_offsets_known_clamp_tables_4_5_and_4_7(frida, dual_data):
    ds, _ = dual_data
    strict = th.run("dual_offsets", ds, frida)
    relaxed = th.run("dual_offsets", ds, frida, accept_factor=1.5)
    assert strict.iterations == relaxed.iterations == 10
    # Measured 10(4) and 10(10) (thesis: 10(2) and 10(10)). A property of this data set, not a law: on
    # seeds 1-4 the strict test accepted 2, 10, 5 and 5 of 10 iterations, the relaxed one always 10.
    assert strict.accepted < relaxed.accepted == 10
    for res in (strict, relaxed):
        assert res.final_error[0] < 0.3 * res.initial_error[0]  # measured 19 mm -> 3.8 / 2.7 mm (seeds 1-4: <= 0.26)
        err = np.concatenate([res.offsets["left"], res.offsets["right"]]) - np.tile(OFFSETS, 2)
        assert 1e-3 < np.abs(err).max() < 0.012  # close, not exact (measured 7.9 / 5.0 mrad)
        assert set(res.cost) == {"left", "right"}


def test_dual_offsets_halved_update_is_the_sec_2_10_reading(frida, dual_data):
    ds, _ = dual_data
    res = th.run("dual_offsets", ds, frida, share=0.5)
    assert res.iterations_label == "10(10)"
    assert res.final_error[0] < 0.25 * res.initial_error[0]


def test_clamp_estimate_eq_3_8(frida, offset_robot, dual_data):
    ds, truth = dual_data
    q = (ds.q["left"], ds.q["right"])
    exact = th.estimate_clamp(offset_robot["left"], offset_robot["right"], *q)
    np.testing.assert_allclose(exact, truth.values["T_toolA_toolB"], atol=1e-10)
    rough = th.estimate_clamp(frida["left"], frida["right"], *q)
    R = rough[:3, :3]
    assert np.abs(R.T @ R - np.eye(3)).max() > 1e-5  # an elementwise mean is not a rotation
    res = th.run("dual_offsets", ds, frida, T_toolA_toolB=None)
    assert res.meta["clamp"] == "estimated (eq. 3.8)"
    np.testing.assert_array_equal(res.T_toolA_toolB, rough)


def test_wrong_clamp_spoils_the_offsets_table_4_14(frida, dual_data):
    ds, truth = dual_data
    C = truth.values["T_toolA_toolB"]
    wrong = C @ se3.make(so3.exp(np.array([-0.1, 0.1, 0.1])), np.array([0.01, 0.01, -0.01]))
    good = th.run("dual_offsets", ds, frida)
    bad = th.run("dual_offsets", ds, frida, T_toolA_toolB=wrong)
    norm = lambda r, arm: np.linalg.norm(r.offsets[arm] - OFFSETS)  # noqa: E731
    for arm in ("left", "right"):
        assert norm(bad, arm) > 3 * norm(good, arm)  # Table 4.14: 0.018 -> 0.116 (left)


# --------------------------------------------------------------------- dual arm, kinematic (Alg. 1)


@pytest.fixture(scope="module")
def kinematic_data(frida):
    """Right arm with the thesis' kinematic errors (twists, T_st), no offsets; left arm nominal."""
    true = perturb_robot(frida, "thesis", rng=0, arms=("right",), offset_rad=0.0)
    ds, _, _ = generate_dual(true, n=100, rng=0, n_validation=1)
    return ds, true


def test_one_arm_known_recovers_the_kinematic_parameters_table_4_8(frida, kinematic_data):
    ds, true = kinematic_data
    before = np.abs(frida["right"].screws - true["right"].screws).max()
    res = th.run("dual_kinematic", ds, frida, known="left")
    m = res.models["right"]
    assert before > 0.01
    np.testing.assert_allclose(m.screws, true["right"].screws, atol=1e-9)
    np.testing.assert_allclose(m.home, true["right"].home, atol=1e-9)
    assert res.converged and res.iterations == res.accepted <= 6  # measured 4(4)
    assert res.models["left"] == frida["left"]
    assert res.parameter_names[0] == "right.j1.xi.v_x" and res.parameter_names[-1] == "right.home.w_z"
    assert len(res.estimate) == 48 and res.meta["share"] == 1.0


def test_both_arms_unknown_closes_the_chain_without_finding_the_parameters_table_4_9(frida, kinematic_data):
    ds, true = kinematic_data
    res = th.run("dual_kinematic", ds, frida)
    assert res.meta["share"] == 0.5
    assert res.final_error[0] < 0.5 * res.initial_error[0]
    assert np.abs(res.models["right"].screws - true["right"].screws).max() > 1e-3
    assert len(res.parameter_names) == 96


# ------------------------------------------------------------------------------------- interface


def test_result_is_frozen(frida, clamp_data):
    res = th.run("single_offsets", clamp_data[0], frida, max_iter=1)
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.iterations = 3
    with pytest.raises(TypeError):
        res.offsets["left"] = np.zeros(7)
    assert res.history.shape == (res.iterations + 1, 2) and res.damping.shape == (res.iterations + 1,)


def test_bad_input_is_named(frida, clamp_data, dual_data):
    with pytest.raises(ShapeError, match="q: arm 'left' has 7 joints"):
        th.calib_single_offsets(frida["left"], np.zeros((5, 6)))
    with pytest.raises(DegenerateExperimentError, match="needs a 'dual' data set, got 'clamp'"):
        th.run("dual_offsets", clamp_data[0], frida)
    with pytest.raises(DegenerateExperimentError, match="expected one of"):
        th.run("calib_everything", clamp_data[0], frida)
    with pytest.raises(ModelError, match="known: expected one of"):
        th.run("dual_kinematic", dual_data[0], frida, known="middle")
    with pytest.raises(ModelError, match="two distinct arm names"):
        th.calib_dual_offsets(frida["left"], frida["left"], dual_data[0].q["left"], dual_data[0].q["right"])
    with pytest.raises(ShapeError, match="equal N"):
        th.calib_dual_offsets(frida["left"], frida["right"], np.zeros((5, 7)), np.zeros((4, 7)), arms=("l", "r"))
    with pytest.raises(ShapeError, match="T_toolA_toolB: expected a finite"):
        th.run("dual_offsets", dual_data[0], frida, T_toolA_toolB=np.eye(3))
    ds = clamp_data[0]
    one_fixture = Dataset("plate", ds.robot, ds.arms, dict(ds.q), {"fixture": np.zeros(ds.size, dtype=int)},
                          {"T_plate_fixture": np.eye(4)[None]})
    with pytest.raises(DegenerateExperimentError, match="uses BFGS"):
        th.run("several_points", one_fixture, frida, accept_factor=1.5)
