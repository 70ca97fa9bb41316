"""The solver's slow path (``estimation.levenberg``: Levenberg-Marquardt with geodesic acceleration) in weak,
curved valleys: few evaluations where scipy's LM crawled for thousands, the same minimum, honest status, and the
Jacobian it steps with checked against finite differences."""

import numpy as np
import pytest

from kincal.estimation import Problem, SolverOptions, calibrate, levenberg, solve, steps
from kincal.kinematics import Robot
from kincal.simulate.generators import generate_markers
from kincal.simulate.noise import Noise
from kincal.simulate.perturb import Perturbation, perturb_robot
from kincal.testing import numerical_jacobian
from test_gravity import TILT, _ur10_with_weights

K = 1e4  # the valley's walls against its floor


def _banana(x):
    """A unit circle with walls K times steeper than the slope along it: a curved valley."""
    r = np.array([K * (x[0] ** 2 + x[1] ** 2 - 1.0), x[1] - 0.8, 0.1 * (x[0] - 0.3)])
    J = np.array([[2 * K * x[0], 2 * K * x[1]], [0.0, 1.0], [0.1, 0.0]])
    return r, J


@pytest.mark.parametrize("seed", range(4))
def test_a_curved_valley_is_walked_in_a_few_hundred_evaluations(seed):
    """From a random point of the valley floor a quarter turn or more away from the minimum: scipy's LM (the
    former inner solve) has not arrived after 200 evaluations; geodesic LM converges to a stationary point on
    the floor in fewer than 300."""
    a = np.random.default_rng(seed).uniform(-2.5, -1.0)
    x0 = np.array([np.cos(a), np.sin(a)])
    out = levenberg.minimize(lambda z, jac: (_banana(x0 + z)[0], _banana(x0 + z)[1] if jac else None),
                             *_banana(x0), lambda step, cost2: step < 1e-8, 10_000)
    assert out.status == "converged" and out.evaluations < 300
    x = x0 + out.z
    r, J = _banana(x)
    assert abs(x @ x - 1.0) < 1e-9 and x[1] > 0.7
    assert np.linalg.norm(np.linalg.lstsq(J, -r, rcond=None)[0]) < 1e-6  # within 1e-6 of the minimum
    np.testing.assert_allclose(out.r, r)


def test_a_spent_budget_is_not_converged():
    out = levenberg.minimize(lambda z, jac: (_banana(np.array([0.0, -1.0]) + z)[0],
                                             _banana(np.array([0.0, -1.0]) + z)[1] if jac else None),
                             *_banana(np.array([0.0, -1.0])), lambda step, cost2: step < 1e-8, 20)
    assert out.status == "budget" and out.evaluations <= 20


def _sagging_ur10():
    """The UR10 of tests/test_gravity.py on its tilted pedestal, perturbed and compliant: calibrating
    ``kinematic`` and ``elastic`` together leaves the joint offsets traded against the next axes and the home
    pose, told apart only by the weights' sag on the nominal centres of mass: a weak valley that turns by about
    90 degrees, unless the solve holds these exact gauges of the rigid model (``estimation.gauge.rigid_gauges``)."""
    nominal = Robot("ur10", {"arm": _ur10_with_weights(TILT)})
    compliance = np.array([3e-6, 2e-6, 4e-6, 8e-6, 1e-5, 1.5e-5])
    true = perturb_robot(nominal, "fine", 5)
    return nominal, Robot("ur10", {"arm": true["arm"].replace(compliance=compliance)}), compliance


@pytest.mark.parametrize("seed", [1, 2])
def test_a_sagging_arm_converges_in_few_evaluations(seed):
    """20 configurations, 3 known markers, known tracker, 0.02 mm noise. scipy's LM took 3633 evaluations
    (seed 1, 63 s) walking the valley of the offsets, the geodesic slow path a few hundred; with the rigid
    model's gauges held (named, with the reason) Gauss-Newton takes a few steps, and every compliance comes back
    within 3 std."""
    nominal, true, compliance = _sagging_ur10()
    ds, _, _ = generate_markers(true, n=20, rng=seed, markers=3, noise=Noise(position=2e-5), known_tracker=True,
                                known_markers=True)
    res = calibrate(nominal, [ds], ["kinematic", "elastic"], outliers="keep")
    assert res.status == "converged" and res.evaluations < 20
    pivots = {d.pivot for d in res.identifiability.directions}
    assert {f"arm.{j}.offset" for j in nominal["arm"].joint_names} <= pivots
    assert any("lifted only by the weight" in m for m in res.messages)
    for j, name in enumerate(nominal["arm"].joint_names):
        e = res.estimate(f"arm.{name}.compliance")
        assert e.identifiable and abs(e.value - compliance[j]) < 3 * e.std, (name, e.value, compliance[j], e.std)


def test_an_inner_solve_stopped_by_its_budget_is_not_converged(monkeypatch):
    """With the inner solve's budget cut to a few evaluations the way from a far start (errors six times the
    thesis' sizes: Gauss-Newton's step is refused, the inner solve needs about 35 evaluations) is not walked:
    the loop goes on and, out of outer iterations, says "not converged"."""
    nominal, _, compliance = _sagging_ur10()
    far = perturb_robot(nominal, Perturbation(0.06, 14.4 * np.pi / 180, 0.42, 0.001, 0.06, 14.4 * np.pi / 180), 5)
    true = Robot("ur10", {"arm": far["arm"].replace(compliance=compliance)})
    ds, _, _ = generate_markers(true, n=20, rng=1, markers=3, noise=Noise(position=2e-5), known_tracker=True,
                                known_markers=True)
    real = levenberg.minimize
    monkeypatch.setattr(levenberg, "minimize", lambda e, r, J, done, budget: real(e, r, J, done, 12))
    res = solve(Problem.build(nominal, [ds], ["kinematic", "elastic"]), SolverOptions(max_outer=3))
    assert res.status == "not converged"


def test_the_inner_solves_jacobian_matches_differences_away_from_its_start(rng):
    """The slow path steps with ``J V`` at points ``z`` away from the linearization (pose blocks stepped from
    their linearization point, twists, compliances): finite differences agree."""
    nominal, true, _ = _sagging_ur10()
    ds, _, _ = generate_markers(true, n=6, rng=3, markers=3, noise=Noise(position=2e-5), known_tracker=True,
                                known_markers=True)
    problem = Problem.build(nominal, [ds], ["kinematic", "elastic"])
    lin = steps.linearize(problem, problem.start, None, False)
    V = np.linalg.qr(rng.normal(size=(len(problem.free_idx), 8)))[0]
    V[:, 0] *= 1e-5  # one direction mostly along compliances' scale
    z = rng.normal(scale=0.05, size=8)
    r, JV = steps._evaluate_in(problem, problem.start, V, z, lin.W, True)
    num = numerical_jacobian(lambda x: steps._evaluate_in(problem, problem.start, V, x, lin.W, False)[0], z)
    np.testing.assert_allclose(JV, num, rtol=1e-5, atol=1e-6 * np.abs(JV).max())
