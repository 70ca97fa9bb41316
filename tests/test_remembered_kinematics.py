"""An accepted trial point's kinematics are not computed twice (``experiments.base.remembered_kinematics``): while
a solve remembers them, an experiment reuses its last kinematics per arm at a state of the same geometry, and
the residuals and Jacobians are bit for bit those computed afresh."""

from contextlib import nullcontext
from dataclasses import fields

import numpy as np
import pytest

from kincal.estimation import Problem, SolverOptions, solver
from kincal.experiments import base, remembered_kinematics
from kincal.kinematics import Robot
from kincal.noise import Noise as Stated
from kincal.params import conform, recentre, retract
from kincal.robots import load
from kincal.simulate.generators import generate_markers
from kincal.simulate.noise import Noise
from kincal.simulate.perturb import perturb_robot
from test_tree_gravity import _sagging_torso


def _markers_problem():
    true = perturb_robot(load("ur10"), "fine", 3)
    ds, _, _ = generate_markers(true, n=30, rng=4, markers=2, noise=Noise(position=5e-5))
    return Problem.build(load("ur10"), [ds], "kinematic", noise=Stated(position=5e-5, joint=0.0))


def _tree_problem(lateral: bool):
    """Markers on both hands of a sagging torso carrying two arms (``test_tree_gravity``), small."""
    nominal, true = _sagging_torso("kinematic")
    if lateral:
        nominal, true = (Robot(r.name, {a: m.replace(lateral=np.zeros((m.dof, 2))) for a, m in r.arms.items()},
                               mounts=r.mounts) for r in (nominal, true))
    sets = []
    for seed, arm in ((1, "left"), (2, "right")):
        ds, _, _ = generate_markers(true, arm, n=20, rng=seed, markers=2, noise=Noise(position=2e-5))
        sets.append(ds.__class__(**{**ds.__dict__, "name": f"{arm}-hand"}))
    return Problem.build(nominal, sets, ["kinematic", "elastic"] + (["lateral"] if lateral else []))


def _delta(problem):
    rng = np.random.default_rng(7)
    units = np.array(problem.layout.units)[problem.free_idx]
    step = np.select([units == "rad/Nm", units == "m/N"], [1e-5, 1e-7], 1e-3)
    return step * rng.uniform(0.5, 1.0, len(units)) * rng.choice([-1.0, 1.0], len(units))


class _Count:
    def __init__(self, monkeypatch):
        self.fresh, original = 0, base.Experiment._fresh_kin

        def fresh(exp, state, arm):
            self.fresh += 1
            return original(exp, state, arm)
        monkeypatch.setattr(base.Experiment, "_fresh_kin", fresh)


@pytest.mark.parametrize("case", ["markers", "tree", "tree lateral"])
def test_a_trial_then_its_jacobian_reuses_the_kinematics_bit_for_bit(case, monkeypatch):
    problem = _markers_problem() if case == "markers" else _tree_problem(case == "tree lateral")
    state, delta = problem.start, _delta(problem)
    W = problem.whiteners(state)
    r0, J0 = problem.evaluate(state, delta, W, jac=True)  # nothing remembered: computed afresh
    count = _Count(monkeypatch)
    with remembered_kinematics(problem.experiments):
        r_trial = problem.evaluate(state, delta, W, jac=False)[0]  # the trial (no tangent bases)
        spent = count.fresh
        r, J = problem.evaluate(state, delta, W, jac=True)  # its Jacobian: the same geometry
        assert count.fresh == spent  # nothing computed again
        np.testing.assert_array_equal(r, r0)
        np.testing.assert_array_equal(J, J0)
        np.testing.assert_array_equal(r_trial, r0)
        problem.evaluate(state, 0.5 * delta, W, jac=False)  # another geometry: computed
        assert count.fresh > spent
    assert not any(e in base._KINEMATICS for e in problem.experiments)  # forgotten after the block
    problem.evaluate(state, delta, W, jac=False)
    problem.evaluate(state, delta, W, jac=True)
    assert count.fresh > 0 and count.fresh == 4 * spent  # outside the block every evaluation computes its own


def test_equal_geometry_is_bit_for_bit_and_tangent_bases_do_not_count():
    problem = _markers_problem()
    s = problem.start
    a = s.arms["arm"] if "arm" in s.arms else next(iter(s.arms.values()))
    name = next(k for k, v in s.arms.items() if v is a)
    same = s.replace({name: a.__class__(**{**a.__dict__, "screws": a.screws.copy(), "bases": None})})
    assert base._same_geometry(base._geometry(s), base._geometry(same))
    moved = a.screws.copy()
    moved[0, 0] = np.nextafter(moved[0, 0], 1.0)  # one bit
    other = s.replace({name: a.__class__(**{**a.__dict__, "screws": moved})})
    assert not base._same_geometry(base._geometry(s), base._geometry(other))
    zero = a.offsets.copy()
    zero[zero == 0] = -0.0  # the same value, another bit pattern: computed again
    if np.any(a.offsets == 0):
        signed = s.replace({name: a.__class__(**{**a.__dict__, "offsets": zero})})
        assert not base._same_geometry(base._geometry(s), base._geometry(signed))


@pytest.mark.parametrize("case", ["markers", "tree"])
def test_solves_with_and_without_remembered_kinematics_agree_bit_for_bit(case, monkeypatch):
    problem = _markers_problem() if case == "markers" else _tree_problem(False)
    options = SolverOptions()
    if case == "tree":
        options = SolverOptions(max_outer=3)  # enough steps (Levenberg-Marquardt's accepted trials included)
    count = _Count(monkeypatch)
    kept = solver.solve(problem, options)
    with_memo = count.fresh
    fresh_problem = _markers_problem() if case == "markers" else _tree_problem(False)
    monkeypatch.setattr(solver, "remembered_kinematics", lambda *a, **k: nullcontext())
    count.fresh = 0
    plain = solver.solve(fresh_problem, options)
    assert with_memo < count.fresh  # something was reused
    assert kept.status == plain.status and kept.iterations == plain.iterations
    for a, b in zip(kept.estimates, plain.estimates):
        assert (a.name, a.value, a.std) == (b.name, b.value, b.std) or (a.name == b.name and np.isnan(a.std)
                                                                          and np.isnan(b.std) and a.value == b.value)


def test_a_problem_solved_by_blocks_remembers_nothing(monkeypatch):
    """``on`` False (``solve`` passes ``not problem.blocked``): no kinematics kept, each evaluation its own."""
    seen, original = [], base.remembered_kinematics

    def spy(experiments, on=True):
        seen.append(on)
        return original(experiments, on)
    monkeypatch.setattr(solver, "remembered_kinematics", spy)
    problem = _markers_problem()
    solver.solve(problem)
    assert seen == [not problem.blocked] == [True]
    delta, W = _delta(problem), problem.whiteners(problem.start)
    count = _Count(monkeypatch)
    with remembered_kinematics(problem.experiments, on=False):
        assert not any(e in base._KINEMATICS for e in problem.experiments)
        problem.evaluate(problem.start, delta, W, jac=False)
        spent = count.fresh
        problem.evaluate(problem.start, delta, W, jac=True)
        assert count.fresh == 2 * spent > 0


@pytest.mark.parametrize("case", ["markers", "tree lateral"])
def test_a_conformed_trial_recentres_to_the_same_point_bit_for_bit(case):
    """``recentre(conform(x), conformed=True)`` is ``recentre(x)`` field by field, bit for bit, and keeps the
    trial's screws (the same arrays): an accepted Gauss-Newton trial's kinematics serve the next linearization."""
    problem = _markers_problem() if case == "markers" else _tree_problem(True)
    trial = retract(problem.start, problem.layout, problem.full_delta(_delta(problem)), tangents=False)
    conformed = conform(trial)
    old, new = recentre(trial), recentre(conformed, conformed=True)
    for name, a in old.arms.items():
        for f in fields(a):  # the tangent bases and generators included
            assert base.same_bits(getattr(a, f.name), getattr(new.arms[name], f.name)), f.name
        assert new.arms[name].screws is conformed.arms[name].screws
    assert base._same_geometry(base._geometry(conformed), base._geometry(new))


def test_the_linearization_after_an_accepted_gauss_newton_step_reuses_its_trial(monkeypatch):
    problem = _markers_problem()
    count = _Count(monkeypatch)
    solver.solve(problem)
    with_memo = count.fresh
    count.fresh = 0
    monkeypatch.setattr(solver, "remembered_kinematics", lambda *a, **k: nullcontext())
    solver.solve(_markers_problem())
    assert count.fresh - with_memo >= 2  # two accepted Gauss-Newton trials (three outer iterations)
