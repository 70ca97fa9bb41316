"""The solver on tracker data (forward kinematics only): recovery, robust loss, priors, bad input, degeneracy."""

import numpy as np
import pytest

from kincal.data import Dataset
from kincal.errors import DataFormatError, DegenerateExperimentError, ModelError
from kincal.estimation import Noise, calibrate
from kincal.kinematics import Robot, forward_kinematics
from kincal.lie import se3
from kincal.params import Prior
from kincal.testing import random_arm


def _pose_data(rng, arm, n=40, W=np.eye(4)):
    q = rng.uniform(-2, 2, (n, arm.dof))
    return Dataset("pose", "r", ("arm",), {"arm": q}, {"T_tracker_tool": se3.inverse(W) @ forward_kinematics(arm, q)},
                   {"T_world_tracker": W})


def _markers_data(rng, arm, x, n=40):
    q = rng.uniform(-2, 2, (n, arm.dof))
    p = se3.transform_points(forward_kinematics(arm, q)[:, None], x)
    return Dataset("markers", "r", ("arm",), {"arm": q}, {"p_tracker_marker": p}, {"T_world_tracker": np.eye(4)})


def test_markers_full_kinematic_recovery(rng):
    """Partial pose (3 markers, positions only, metres; marker offsets unknown): twists, home and offsets up to
    the POE redundancy (6) and the markers' rigid motion in the tool frame, which the home pose absorbs (6)."""
    true = random_arm(rng, 6, name="arm")
    x = rng.uniform(-0.1, 0.1, (3, 3))
    nominal = true.replace(offsets=np.zeros(6), home=se3.exp(np.full(6, 0.01)) @ true.home)
    res = calibrate(Robot("r", {"arm": nominal}), [_markers_data(rng, true, x)], "kinematic")
    assert res.status == "converged" and res.identifiability.deficiency == 12
    assert "markers.m1.x" in res.layout.names
    q = rng.uniform(-2, 2, (50, 6))
    predicted = se3.transform_points(forward_kinematics(res.robot["arm"], q)[:, None], res.extras["markers"])
    np.testing.assert_allclose(predicted, se3.transform_points(forward_kinematics(true, q)[:, None], x), atol=1e-9)


def test_robust_loss_resists_outliers(rng):
    true = random_arm(rng, 6, name="arm")
    ds = _pose_data(rng, true, n=60)
    T = np.array(ds.measured["T_tracker_tool"])
    T[:3, :3, 3] += 0.05  # three gross outliers (5 cm)
    bad = Dataset("pose", "r", ("arm",), ds.q, {"T_tracker_tool": T}, ds.known)
    nominal = Robot("r", {"arm": true.replace(offsets=np.zeros(6))})
    noise = Noise(1e-5, 1e-5, 0.0)
    plain = calibrate(nominal, [bad], "offsets", noise=noise, outliers="keep")
    robust = calibrate(nominal, [bad], "offsets", noise=noise, loss="soft_l1", f_scale=3.0, outliers="keep")
    err = lambda r: np.max(np.abs([r.estimate(f"arm.j{i}.offset").value for i in range(1, 7)] - true.offsets))  # noqa
    assert err(robust) < 1e-5 and err(plain) > 100 * err(robust)


def test_prior_pulls_an_unidentifiable_parameter(rng):
    true = random_arm(rng, 6, name="arm")
    ds = _pose_data(rng, true)
    nominal = Robot("r", {"arm": true.replace(offsets=np.zeros(6))})
    res = calibrate(nominal, [ds], ["arm.*.offset", "arm.base"], priors={"arm.base": Prior(1e-3)})
    assert res.identifiability.deficiency == 0  # the prior makes the base identifiable
    assert res.status == "converged"


def test_bad_input_gives_clear_errors(rng):
    true = random_arm(rng, 6, name="arm")
    robot = Robot("r", {"arm": true})
    ds = _pose_data(rng, true, n=5)
    with pytest.raises(DegenerateExperimentError, match="every parameter is fixed"):
        calibrate(robot, [ds], [])
    with pytest.raises(DegenerateExperimentError, match="30 equations for 36 unknowns"):
        calibrate(robot, [ds], "kinematic")
    clamp3 = Dataset("clamp", "r", ("arm",), {"arm": rng.uniform(-1, 1, (3, 6))})
    with pytest.raises(DegenerateExperimentError, match="18 equations for 42 unknowns"):
        calibrate(robot, [clamp3], "kinematic")
    wrong = Dataset("clamp", "r", ("arm",), {"arm": rng.uniform(-1, 1, (10, 7))})
    with pytest.raises(DataFormatError, match=r"q\[arm\] has 7 joints per sample, expected 6"):
        calibrate(robot, [wrong], "offsets")
    T = np.array(ds.measured["T_tracker_tool"])
    T[2, 1, 3] = np.nan
    nan = Dataset("pose", "r", ("arm",), ds.q, {"T_tracker_tool": T}, ds.known)
    with pytest.raises(DataFormatError, match=r"sample 2 field measured\['T_tracker_tool'\] .* is nan"):
        calibrate(robot, [nan], "offsets")
    with pytest.raises(ModelError, match="unknown .* cannot be fixed"):
        calibrate(robot, [Dataset("clamp", "r", ("arm",), {"arm": rng.uniform(-1, 1, (10, 6))})], "offsets",
                  fixed=["fixture"])


def test_degenerate_experiment_is_reported_not_converged(rng):
    """Every sample in the same configuration, fixture unknown: nothing about the arm can be learnt."""
    true = random_arm(rng, 6, name="arm")
    q = np.repeat(rng.uniform(-1, 1, (1, 6)), 10, axis=0)
    ds = Dataset("clamp", "r", ("arm",), {"arm": q})
    res = calibrate(Robot("r", {"arm": true}), [ds], "offsets")
    assert res.status == "degenerate" and not res.success
    assert any("degenerate experiment" in m for m in res.messages)
    assert all(np.isnan(e.std) for e in res.estimates)


def test_model_that_cannot_explain_the_data_is_reported_and_settles():
    """Offsets only, but the true arm also has thesis-size twist errors: the loop must settle (whitening is
    held after the first estimate) and the result must say the model does not fit, not just 'converged'."""
    from kincal.robots import load
    from kincal.simulate.generators import generate_clamp
    from kincal.simulate.perturb import perturb_robot

    frida = load("frida")
    ds, _, _ = generate_clamp(perturb_robot(frida, "thesis", 3), "right", n=40, rng=1, known_fixture=False)
    res = calibrate(frida, [ds], "offsets")
    assert res.status == "misfit" and res.iterations <= 5
    assert res.sigma2 > 100
    assert res.messages[0].startswith("the model does not explain the data")


def test_gauss_newton_and_inner_solve_paths_agree(rng, monkeypatch, caplog):
    """Gauss-Newton steps are the fast path; with them refused, the inner solve (geodesic Levenberg-Marquardt)
    alone reaches the same estimate."""
    import logging

    from kincal.estimation import steps

    true = random_arm(rng, 6, name="arm")
    nominal = true.replace(offsets=true.offsets + rng.normal(scale=0.05, size=6),
                           home=se3.exp(rng.normal(scale=0.01, size=6)) @ true.home)
    data = [_pose_data(rng, true, W=se3.exp(rng.normal(size=6)))]
    robot = Robot("r", {"arm": nominal})
    with caplog.at_level(logging.DEBUG, logger="kincal.estimation.iterate"):
        fast = calibrate(robot, data, "kinematic")
    assert "Gauss-Newton" in caplog.text and "inner solve" not in caplog.text
    caplog.clear()
    monkeypatch.setattr(steps, "gauss_newton", lambda lin, V, *factor: (np.zeros(V.shape[1]), 0.0))  # never helps
    with caplog.at_level(logging.DEBUG, logger="kincal.estimation.iterate"):
        slow = calibrate(robot, data, "kinematic")
    assert "inner solve" in caplog.text
    assert fast.status == slow.status == "converged"
    q = rng.uniform(-2, 2, (30, 6))
    for res in (fast, slow):
        T = se3.inverse(res.extras["tracker"]) @ forward_kinematics(res.robot["arm"], q)
        np.testing.assert_allclose(T, se3.inverse(data[0].known["T_world_tracker"]) @ forward_kinematics(true, q),
                                   atol=1e-9)


def test_spine_build_solve_equals_calibrate(rng):
    """Problem.build + solve(SolverOptions) is what calibrate runs; the problem is frozen, the result keeps it,
    statistics and twists are typed."""
    import dataclasses

    from kincal.estimation import Problem, ResidualStats, SolverOptions, TwistEstimate, solve

    true = random_arm(rng, 6, name="arm")
    ds = _pose_data(rng, true)
    nominal = Robot("r", {"arm": true.replace(offsets=np.zeros(6))})
    problem = Problem.build(nominal, [ds], "kinematic")
    with pytest.raises(dataclasses.FrozenInstanceError):
        problem.start = problem.nominal
    res = solve(problem, SolverOptions())
    ref = calibrate(nominal, [ds], "kinematic")
    assert res.status == ref.status == "converged" and res.iterations == ref.iterations
    assert [e.value for e in res.estimates] == [e.value for e in ref.estimates]
    assert res.problem is problem and res.linearization.state is res.state
    assert isinstance(res.after[0], ResidualStats) and res.after[0].position_max < 1e-9
    assert isinstance(res.twists[0], TwistEstimate) and res.twists[0].name == "arm.j1.xi.v_x"
    with pytest.raises(ModelError, match="gauge must be"):
        SolverOptions(gauge="smallest")


def test_residuals_well_above_the_stated_noise_are_said_below_the_misfit_rule():
    """Joint noise three times what is stated (the clamp's other noise as stated): the fit's variance factor is
    between 4 and the misfit rule's 100, so the status stays 'converged' and a message says how many times the
    stated noise the residuals are. Stated right, the same data get no such message."""
    from kincal.estimation.finalize import MISFIT_VARIANCE_FACTOR, NOISE_NOTE_FACTOR
    from kincal.robots import load
    from kincal.simulate.generators import generate_clamp
    from kincal.simulate.perturb import perturb_robot

    frida = load("frida")
    sigma = 1e-4
    for seed in (2, 3):
        ds, _, _ = generate_clamp(perturb_robot(frida, "thesis", seed), "right", n=40, rng=seed,
                                  noise=Noise(joint=sigma), known_fixture=False)
        right = calibrate(frida, [ds], "kinematic", noise=Noise(joint=sigma))
        low = calibrate(frida, [ds], "kinematic", noise=Noise(joint=sigma / 3))
        assert right.status == low.status == "converged"
        assert right.sigma2 < NOISE_NOTE_FACTOR < low.sigma2 < MISFIT_VARIANCE_FACTOR
        notes = [m for m in low.messages if "times the stated noise" in m]
        assert len(notes) == 1 and notes[0].startswith(f"residuals are {np.sqrt(low.sigma2):.3g} times")
        assert not any("times the stated noise" in m for m in right.messages)
