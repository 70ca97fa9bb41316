"""DLR Agile Justin (../shared/datasets/dlr-agile-justin-elastic, read from there only; no licence): a tree robot
(torso once, both arms on it, the coupled torso joint declared) calibrated from two hand markers. Levels and
published figures in ``realdata.JUSTIN_LEVELS`` and ``realdata.JUSTIN_ELASTIC``; the table is docs/real-data.md
"DLR Agile Justin" (issue 14). Skipped when the data are absent."""

import numpy as np
import pytest

import holdout as ho
import realdata as rd
from kincal.estimation import calibrate
from kincal.kinematics.branches import tree_loaded_kinematics

try:
    PATH = rd.folder(rd.JUSTIN)
except rd.DataMissing as exc:  # pragma: no cover - depends on the machine
    pytest.skip(str(exc), allow_module_level=True)


@pytest.fixture(scope="module")
def justin():
    return rd.justin_robot(PATH), rd.justin_markers(PATH)


@pytest.mark.parametrize("level", list(rd.JUSTIN_LEVELS))
def test_held_out_errors_at_or_below_the_papers_fit(justin, level):
    """5-fold held-out (train on 400 poses, predict 100 with the camera and markers of the training fit) against
    the paper's fit on all 500: kincal's held-out mean and max are no larger."""
    robot, sets = justin
    free, (mean, _, worst) = rd.JUSTIN_LEVELS[level]
    held = ho.cross_validate(robot, sets, free, k=5, noise=rd.JUSTIN_NOISE, outliers="keep").position * 1e3
    assert held.mean() <= mean and held.max() <= worst
    res = calibrate(robot, list(sets), free, noise=rd.JUSTIN_NOISE, outliers="keep")
    fit = np.concatenate([ho.prediction_errors(res, d)[0] for d in sets]) * 1e3
    assert fit.mean() <= held.mean()  # the fit is the optimistic figure
    assert res.status == "misfit"  # millimetres the model cannot explain, at the stated 0.3 mm: never a success
    assert not res.success


def test_the_torso_is_one_set_of_parameters_and_its_gauges_are_named(justin):
    """Was (issue 14): each arm through its own torso copy; at level kinematic the copies' tilt axes ended
    285-292 mm apart, and the near-exact gauges of the coupled parallel axes were named nowhere."""
    robot, sets = justin
    res = calibrate(robot, list(sets), "kinematic", noise=rd.JUSTIN_NOISE, outliers="keep")
    names = [e.name for e in res.estimates]
    assert "torso.t2.offset" in names and not any(n.startswith(("right.t", "left.t")) for n in names)
    assert res.status != "not converged" and res.iterations <= 8
    unidentifiable = [m for m in res.messages if "cannot be identified" in m]
    assert any(m.startswith("torso.t2.offset cannot be identified") and "torso.home" in m for m in unidentifiable)
    assert any(m.startswith("torso.t1.offset cannot be identified") and "camera" in m for m in unidentifiable)


def _dh(row, q):
    """Craig's link transform of a row ``[d, theta, a, alpha]`` at joint value q (SOURCE.md's JSON)."""
    d, theta, a, alpha = row
    c, s, ca, sa = np.cos(theta + q), np.sin(theta + q), np.cos(alpha), np.sin(alpha)
    return np.array([[c, -s, 0, a], [ca * s, ca * c, -sa, -d * sa], [sa * s, sa * c, ca, d * ca], [0, 0, 0, 1]])


def _frames(m, x):
    """rokin's frames 0..25 (world poses) of one configuration x (19,): torso 1-4, right base 5, right DH 6-12,
    right TCP 13, left 14-22, head base 23, head DH 24-25."""
    A = lambda k: np.asarray(m[k], float)  # noqa: E731
    f = [A("F_TORSO_BASE")]
    for row, q in zip(m["DH_TORSO"], [x[0], x[1], x[2], -x[1] - x[2]]):
        f.append(f[-1] @ _dh(row, q))
    for side, qs in (("RIGHT", x[3:10]), ("LEFT", x[10:17])):
        f.append(f[4] @ A(f"F_{side}_BASE"))
        for row, q in zip(m[f"DH_{side}"], qs):
            f.append(f[-1] @ _dh(row, q))
        f.append(f[-1] @ A("F_TCP_right_and_left"))
    f.append(f[4] @ A("F_HEAD_BASE"))
    for row in m["DH_HEAD"]:
        f.append(f[-1] @ _dh(row, 0.0))
    return f


def _hand_torques(m, x):
    """The right hand's chain (t1..t4, right j1..j7): per joint the sum of m g x r about its z axis over the masses
    beyond it, each centre of gravity in its own DH frame (rokin's ``frames2pos``), independently of kincal."""
    f = _frames(m, x)
    mk, cog = m["masses_kg"], m["mass_cog_in_frame_m"]
    masses = [*mk["torso_frames_1_to_4"], *mk["arm_frames_each_arm_7_links"], mk["hand_each"],
              *mk["arm_frames_each_arm_7_links"], mk["hand_each"], mk["head"]]
    cogs = [*cog["torso"], *cog["right_arm"], cog["hand_each"], *cog["left_arm"], cog["hand_each"], cog["head"]]
    at = {i: (mass, f[i][:3, :3] @ c + f[i][:3, 3]) for i, mass, c in zip(m["mass_frame_index_order"], masses, cogs)}
    g = np.array([0.0, 0.0, -9.81])
    beyond = {j: range(j, 26) for j in (1, 2, 3, 4)} | {j: range(j, 14) for j in range(6, 13)}  # torso carries all
    return np.array([sum(np.cross(at[i][1] - f[j][:3, 3], at[i][0] * g) for i in beyond[j] if i in at) @ f[j][:3, 2]
                     for j in beyond])


def test_gravity_torques_equal_a_hand_computation():
    """The mass model's frames (centres of gravity in DH frame i after joint i's rotation, hands in the TCP frame,
    the head on the torso's last frame, gravity -z of the torso base): kincal's torques on the right hand's chain
    (both arms and the head on the torso) equal the sum of m g x r per joint axis on rokin's frames, up to the
    published frames' rounding (0.866 for cos 30 deg, which the loader projects)."""
    m = rd._justin_model(PATH)
    x = rd._csv(PATH / "measurements_flat.csv", skiprows=1)[::25, :19]
    ds, _ = rd.justin_markers(PATH, both_arms=True)
    kin = tree_loaded_kinematics(rd.justin_robot(PATH, masses=True), "right",
                                 {a: v[::25] for a, v in ds.q.items()})
    hand = np.array([_hand_torques(m, row) for row in x])
    assert np.abs(hand).max() > 100  # the tilts carry the upper body
    np.testing.assert_allclose(kin.tau, hand, atol=5e-3)


def test_joint_compliances_loaded_by_the_weight_meet_the_target_held_out():
    """The compliant level (``realdata.justin_elastic_case``: geometry and every joint compliance loaded by the mass
    model's weight, in one solve; the coupled t4's torque held by the t2 and t3 drives), 5-fold held out as above:
    at or below the issue's 5.0 mm (4.47 measured; paper's fit 5.64). Was: staged (geometry, then compliances)
    7.40 mm, because the joint solve walked the torso's axes metres along gauges only the weight lifts (now held,
    ``estimation.gauge.rigid_gauges``); 4.76 with t4's compliance on its own torque only; the first trial's 29.61
    mm scored a compliant fit with the rigid pose."""
    robot, sets, options = rd.justin_elastic_case(PATH, "joint compliances")
    free = options.pop("free")
    held = ho.cross_validate(robot, sets, free, k=5, **options).position * 1e3
    assert held.mean() <= 5.0 and held.max() <= 15.0
    res = calibrate(robot, sets, free, **options)
    assert res.iterations <= 8 and res.evaluations <= 40
    fit = np.concatenate([ho.prediction_errors(res, d)[0] for d in sets]) * 1e3
    assert fit.mean() <= 4.40 and fit.mean() <= held.mean()
    # residuals about 10 times the stated 0.3 mm: at the misfit rule's edge (variance factor 100), said either way
    assert res.status in ("converged", "misfit") and 50 < res.sigma2 < 150
    assert any("lifted only by the weight" in m for m in res.messages)
    # the model predicts through the weight what the solver fitted: its errors are the solver's residuals
    m = 3 * len(fit)  # whitened components: chi^2 / (m - rank) is the variance factor
    assert np.sqrt(np.mean(fit**2) / 3 * m / (m - res.identifiability.rank)) / 0.3 == pytest.approx(
        np.sqrt(res.sigma2), rel=1e-3)
    est = {e.name: e for e in res.estimates}
    assert est["torso.t2.compliance"].value > 5 * est["torso.t2.compliance"].std  # the tilts carry the upper body
    negative = [n for n, e in est.items() if n.endswith(".compliance") and e.value < -1e-9]
    assert negative and all(any(n in m for m in res.messages) for n in negative)  # reported, never zeroed
    for name in negative:
        arm, joint, _ = name.split(".")
        model = res.robot[arm]
        assert model.compliance[model.joint_names.index(joint)] == pytest.approx(est[name].value, rel=1e-9)


def test_lateral_compliances_loaded_by_the_weight_fit_below_the_paper():
    """The lateral level on kincal's lateral compliance kind (``realdata.justin_lateral``: every joint of the torso
    and the arms bends about its DH frame's x and y axes), geometry and every compliance in one solve: fit 2.86 mm
    on all 500 poses, below the paper's 3.12 (held-out 3.00 in docs/real-data.md, by bench/real_data.py). Was 6.32
    (rigid geometry first, then the compliances), 3.73 (the joint level, then the compliances: freed together with
    the geometry the wrists' compliances walked a valley until t4's torque went to the t2 and t3 drives).
    Negative lateral compliances are reported and kept."""
    robot, sets, options = rd.justin_elastic_case(PATH, "lateral compliances")
    free = options.pop("free")
    res = calibrate(robot, sets, free, **options)
    assert res.status in ("converged", "misfit") and res.iterations <= 6
    fit = np.concatenate([ho.prediction_errors(res, d)[0] for d in sets]) * 1e3
    assert fit.mean() <= 2.92 and fit.max() <= 14.0
    m = 3 * len(fit)  # whitened components: chi^2 / (m - rank) is the variance factor
    assert np.sqrt(np.mean(fit**2) / 3 * m / (m - res.identifiability.rank)) / 0.3 == pytest.approx(
        np.sqrt(res.sigma2), rel=1e-3)
    est = {e.name: e for e in res.estimates}
    lateral = [n for n in est if ".lateral_" in n]
    assert len(lateral) == 2 * (4 + 7 + 7)
    for name in [n for n in lateral if est[n].value < -1e-9]:
        arm, joint, axis = name.split(".")
        model = res.robot[arm]
        assert model.lateral[model.joint_names.index(joint), "xy".index(axis[-1])] == est[name].value
        assert any(name in c.name for c in res.negative_compliances)
