"""Issue 9, finding 6: full-model jobs report estimates and standard deviations in a named gauge, the change from
nominal split into what the data determine and a gauge move, and derived quantities (axis geometry, tool pose
at the nominal zero) with standard deviations that cover the truth."""

import io
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console

from kincal.analysis import identify
from kincal.analysis.derived import evaluate, groups, jacobian, names
from kincal.analysis.gauge import NAME, min_change, weights
from kincal.cli.calibrate_cmds import print_summary
from kincal.estimation import calibrate, steps
from kincal.io.datasets import load_scenario
from kincal.io.results import result_to_dict
from kincal.lie import se3
from kincal.noise import Noise
from kincal.params import State, displacement, retract
from kincal.robots import load
from kincal.simulate.generators import generate_markers
from kincal.simulate.perturb import perturb_robot
from kincal.simulate.scenario import build_scenario, run

NOISE = Noise(position=2e-5, joint=3e-5)
SEEDS = range(12)
SCENARIOS = Path(__file__).resolve().parents[1] / "src" / "kincal" / "scenarios"


@pytest.fixture(scope="module")
def ur():
    """A UR5-like arm (the built-in UR10) seen by a tracker with 3 markers, tracker and markers unknown, at
    ``free: kinematic``; one true robot, data and noise drawn anew per seed."""
    nominal = load("ur10")
    true = perturb_robot(nominal, "fine", 3)
    results = []
    for seed in SEEDS:
        ds, _, _ = generate_markers(true, n=80, rng=100 + seed, markers=3, noise=NOISE)
        results.append(calibrate(nominal, [ds], "kinematic", noise=NOISE))
    return true, results


@pytest.fixture(scope="module")
def plate4():
    """frida_plate4 (Frida's right arm clamped at 4 fixtures of a plate of unknown pose) at ``free: kinematic``."""
    sc = build_scenario(load_scenario(SCENARIOS / "frida_plate4.yaml"))
    true, ds, _, _ = run(sc)
    return true, calibrate(sc.robot, [ds], "kinematic", noise=sc.noise)


def _truth(result, true_robot):
    arms = {a: groups(result.problem.nominal, a) for a in result.problem.nominal.arms}
    return evaluate(State.from_robot(true_robot), arms)


def test_every_parameter_gets_a_standard_deviation_in_the_named_gauge(ur):
    _, results = ur
    res = results[0]
    assert res.status == "converged" and res.identifiability.rank == 33
    assert not any(e.identifiable for e in res.estimates)  # 51 of 51: no coordinate is determined on its own
    assert res.gauge.name == NAME
    for e in res.estimates:
        det, std, move = res.gauge.split(e.name)
        assert np.isfinite(std) and np.isfinite(det)
        assert det + move == pytest.approx(e.value - e.nominal, abs=1e-12)
    # the determined part is the least change over the arm's coordinates: a gauge move never shortens it
    arm = np.array([not e.name.startswith(("tracker", "markers")) for e in res.estimates])
    det = res.gauge.determined[arm]
    change = np.array([e.value - e.nominal for e in res.estimates])[arm]
    assert np.linalg.norm(det) <= np.linalg.norm(change)


def test_derived_quantities_cover_the_truth_over_seeds(ur):
    """Axis geometry is identifiable (gauge invariant) with finite standard deviations; over 12 seeds the
    normalized errors against the truth have RMS near 1 (the std matches the Monte Carlo scatter) and none is
    beyond 4; the tool pose moves with the unknown tracker and markers and is reported as a gauge quantity."""
    true, results = ur
    z = []
    for res in results:
        ok = np.array([d.identifiable for d in res.derived])
        labels = [d.name for d in res.derived]
        assert ok.sum() == 12 and all("tool_at_zero" not in n for n, k in zip(labels, ok) if k)
        value = np.array([d.value for d in res.derived])
        std = np.array([d.std for d in res.derived])
        assert np.all(np.isfinite(std[ok])) and np.all(std[ok] > 0)
        z.append(((value - _truth(res, true)) / std)[ok])
    z = np.array(z)
    assert np.max(np.abs(z)) < 4.0
    assert 0.7 < np.sqrt(np.mean(z**2)) < 1.4


def test_estimates_in_the_gauge_scatter_as_their_std(ur):
    """The arm's values in the min-change gauge are one point per class of equally fitting values, so over seeds
    (one true robot) they scatter by the estimation error alone: normalized by the reported standard deviations
    their spread about the mean is near 1; the coordinates the gauge holds at nominal stay there."""
    _, results = ur
    arm = np.array([not n.startswith(("tracker", "markers")) for n in results[0].gauge.names])
    det = np.array([r.gauge.determined[arm] for r in results])
    std = np.array([r.gauge.std[arm] for r in results])
    held = std.max(axis=0) < 1e-9  # shoulder_pan's offset (tracker), wrist_3's and home (markers)
    assert held.sum() == 8 and np.max(np.abs(det[:, held])) < 1e-7
    z = (det - det.mean(axis=0)) / std
    spread = np.sqrt(np.mean(z[:, ~held] ** 2) * len(results) / (len(results) - 1))
    assert 0.75 < spread < 1.3 and np.max(np.abs(z[:, ~held])) < 4.0


def test_derived_jacobian_matches_finite_differences(ur):
    _, results = ur
    res = results[0]
    arms = {"arm": groups(res.problem.nominal, "arm")}
    free = res.problem.free_idx
    G = jacobian(res.state, res.layout, free, arms)
    rng = np.random.default_rng(0)
    for _ in range(3):
        v = np.zeros(res.layout.size)
        v[free] = rng.normal(size=len(free))
        t = 1e-5
        fd = (evaluate(retract(res.state, res.layout, t * v), arms)
              - evaluate(retract(res.state, res.layout, -t * v), arms)) / (2 * t)
        np.testing.assert_allclose(G @ v[free], fd, rtol=1e-5, atol=1e-8)


def test_identifiable_quantities_ignore_null_moves(ur):
    """A step along each unidentifiable direction leaves the identifiable derived quantities (to far below their
    std) and moves some of the others."""
    _, results = ur
    res = results[0]
    arms = {"arm": groups(res.problem.nominal, "arm")}
    ok = np.array([d.identifiable for d in res.derived])
    std = np.array([d.std for d in res.derived])
    base = evaluate(res.state, arms)
    moved_gauge = 0.0
    for n in res.identifiability.null_space.T:
        d = np.zeros(res.layout.size)
        d[res.problem.free_idx] = 1e-4 * n / np.linalg.norm(n)
        change = np.abs(evaluate(retract(res.state, res.layout, d), arms) - base) / std
        assert np.max(change[ok]) < 0.05
        moved_gauge = max(moved_gauge, np.max(change[~ok]))
    assert moved_gauge > 1.0


def _offset_gauge(model, i: int, delta: float):
    """The exact finite gauge of a full POE model: joint i's offset + delta, every later axis and home turned by
    -delta about joint i's axis (the same forward kinematics)."""
    g = se3.exp(-model.screws[i] * delta)
    screws = np.array(model.screws)
    screws[i + 1:] = (se3.adjoint(g) @ screws[i + 1:].T).T
    offsets = np.array(model.offsets)
    offsets[i] += delta
    return model.replace(screws=screws, offsets=offsets, home=g @ model.home)


def test_finite_gauge_moves_leave_the_geometry_unchanged():
    """Large exact gauge moves (offsets against the later axes and home, a rigid motion of the whole arm): the
    axis geometry and the tool pose in the frame of the first two axes do not change, the world tool pose does
    under the rigid motion."""
    nominal = load("ur10")
    true = perturb_robot(nominal, "fine", 3)
    arms = {"arm": groups(State.from_robot(nominal), "arm")}
    labels = names(arms)
    ref = evaluate(State.from_robot(true), arms)
    model = true["arm"]
    for i, delta in enumerate((0.3, -0.2, 0.25, 0.1, -0.3, 0.2)):
        model = _offset_gauge(model, i, delta)
    moved = model.replace(base=se3.exp(np.array([0.05, -0.02, 0.03, 0.1, -0.05, 0.2])) @ model.base)
    gauged = evaluate(State.from_robot(true.replace_arm("arm", model)), arms)
    rigid = evaluate(State.from_robot(true.replace_arm("arm", moved)), arms)
    np.testing.assert_allclose(gauged, ref, atol=1e-10)
    world = np.array([".world." in n for n in labels])
    np.testing.assert_allclose(rigid[~world], ref[~world], atol=1e-10)
    assert np.max(np.abs(rigid[world] - ref[world])) > 1e-3


def test_min_change_is_the_least_weighted_norm_solution(rng):
    """Linear toy problem: the determined part is the minimum weighted-norm representative, W-orthogonal to
    the null space, and its covariance that of the minimum-norm estimator."""
    J = rng.normal(size=(40, 5))
    J[:, 4] = J[:, 0] - 0.5 * J[:, 2]  # one null direction
    N = np.array([[1.0, 0, -0.5, 0, -1.0]]).T / np.linalg.norm([1, 0, -0.5, 0, -1])
    w = np.array([1.0, 2.0, 0.5, 1.0, 3.0])
    x = rng.normal(size=5)
    cov = np.linalg.pinv(J.T @ J)
    view = min_change(x, np.eye(5), N, cov, w)
    assert abs(N[:, 0] @ (w * view.determined)) < 1e-12
    np.testing.assert_allclose(view.determined + view.gauge_move, x)
    Wh = np.diag(1 / np.sqrt(w))
    A = Wh @ np.linalg.pinv(J @ Wh)  # minimum W-norm solution operator y -> x
    np.testing.assert_allclose(view.covariance, A @ A.T, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(view.determined, A @ (J @ x), atol=1e-10)


def test_result_yaml_console_and_plot_show_the_gauge(ur, tmp_path):
    _, results = ur
    res = results[0]
    d = result_to_dict(res)
    assert d["gauge"]["name"] == NAME and "least norm" in d["gauge"]["description"]
    assert all(e["determined_std"] is not None for e in d["estimates"])
    assert any(q["identifiable"] and q["std"] > 0 for q in d["derived"])
    out = io.StringIO()
    print_summary(Console(file=out, width=250), res, "job")
    text = out.getvalue()
    assert f"gauge '{NAME}'" in text and "gauge: min-change" in text and "shoulder_lift-elbow.distance" in text
    pytest.importorskip("matplotlib")
    from kincal.report.plots import _uncertainty_rows, write_plots

    rows = _uncertainty_rows(res)
    assert len(rows) == 12 and all(r[3] for r in rows)
    assert (tmp_path / "p" / "uncertainty.png") in write_plots(res, tmp_path / "p")


def test_plate4_scenario_at_kinematic(plate4):
    """frida_plate4 at ``free: kinematic`` (47 of 47 coordinates unidentifiable): every coordinate has a standard
    deviation in the gauge, the angles between consecutive axes are identifiable and recover the truth."""
    true, res = plate4
    assert res.status == "converged" and not any(e.identifiable for e in res.estimates)
    assert np.all(np.isfinite(res.gauge.std)) and len(res.gauge.std) == len(res.estimates)
    ok = np.array([q.identifiable for q in res.derived])
    labels = [q.name for q in res.derived]
    assert {n for n, k in zip(labels, ok) if k} >= {f"right.j{i}-j{i + 1}.angle" for i in range(1, 7)}
    value = np.array([q.value for q in res.derived])
    std = np.array([q.std for q in res.derived])
    assert np.all(std[ok] > 0)
    assert np.max(np.abs((value - _truth(res, true)) / std)[ok]) < 4.0


@pytest.mark.parametrize("case", ["ur", "plate4"])
def test_determined_values_are_the_min_change_point(case, ur, plate4):
    """The estimate is walked along its orbit to the min-change point (``GaugeView.state``): splitting there again
    leaves no gauge move (the first-order split at the solved state would be off by up to a hundred standard
    deviations on frida_plate4), the identifiable derived quantities stay where the solve put them, and the fit
    stays within the walk's guard (gauges that the residuals lift, held like exact ones, cost a little chi^2)."""
    res = ur[1][0] if case == "ur" else plate4[1]
    g = res.gauge
    assert g.state is not None
    problem, free = res.problem, res.problem.free_idx
    cost = sum(s.chi2 for s in problem.statistics(g.state, res.linearization.W))
    assert cost <= 1.05 * sum(s.chi2 for s in res.after)
    arms = {a: groups(problem.nominal, a) for a in problem.nominal.arms}
    ok = np.array([q.identifiable for q in res.derived])
    std = np.array([q.std for q in res.derived])
    shift = (evaluate(g.state, arms) - evaluate(res.state, arms)) / std
    assert np.max(np.abs(shift[ok])) < 0.1
    lin = steps.linearize(problem, g.state, res.linearization.W, True)
    null = identify(lin, res.layout, problem.experiments, report=False).null_space
    disp, D = displacement(g.state, problem.nominal, res.layout)
    again = min_change(disp[free], D[np.ix_(free, free)], null, np.eye(len(free)), weights(res.layout, free))
    assert np.max(np.abs(again.gauge_move)) < 1e-8
    np.testing.assert_allclose(again.determined, g.determined, atol=1e-8)


def test_robust_loss_keeps_the_first_order_split_and_degenerate_has_none():
    """With a robust loss the walk (plain Gauss-Newton) would leave the robust optimum: the split is taken at the
    solved values (``state`` None), still with a standard deviation for every coordinate. A degenerate solve has
    no gauge view and no derived quantities."""
    nominal = load("ur10")
    ds, _, _ = generate_markers(perturb_robot(nominal, "fine", 3), n=60, rng=7, markers=3, noise=NOISE)
    res = calibrate(nominal, [ds], "kinematic", noise=NOISE, loss="cauchy", outliers="keep")
    assert res.weights is not None and res.gauge.state is None
    assert np.all(np.isfinite(res.gauge.std))
    np.testing.assert_allclose(res.gauge.determined + res.gauge.gauge_move,
                               [e.value - e.nominal for e in res.estimates], atol=1e-12)
    assert sum(q.identifiable for q in res.derived) == 12
    gone = replace(res, status="degenerate")
    assert gone.gauge is None and gone.derived == ()
    assert "determined" not in result_to_dict(gone)["estimates"][0]
