"""Session 11 (helper b): a small calibration's costs outside the outer loop, cut without changing a result.

``check_transform`` tests one transform without the batch machinery (the same verdicts and messages);
``ArmModel.replace`` keeps a transform equal bit for bit to its own instead of checking it again;
``Result.after``, ``Result.twists`` and ``Result.correlated`` are computed on first read (``Deferred``), the values the eager
computation gave, also after pickling, copying and ``dataclasses.replace``; ``residual_norms``,
``finalize._estimates`` and ``experiments._check_finite`` give what they gave."""

from __future__ import annotations

import copy
import copyreg
import dataclasses
import importlib
import io
import pickle
from types import MappingProxyType

import numpy as np
import pytest

from kincal._validate import check_transform
from kincal.data import Dataset
from kincal.errors import DataFormatError, ManifoldError, ModelError
from kincal.estimation import Problem, SolverOptions, calibrate, solve
from kincal.estimation.result import Deferred
from kincal.estimation.stats import residual_norms
from kincal.experiments import checked, remembered_kinematics
from kincal.lie import se3
from kincal.noise import ORIENTATION, PIXEL, POSITION, Noise
from test_structure_cache import NOISE, ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)

finalize_module = importlib.import_module("kincal.estimation.finalize")
base_module = importlib.import_module("kincal.experiments.base")


def _message(fn, *args):
    try:
        fn(*args)
    except Exception as exc:  # noqa: BLE001  (the verdict compared, whatever it is)
        return type(exc), str(exc)
    return None


def _batch_verdict(T, tol):
    """``check_transform``'s verdict through the batch path (a batch of one)."""
    return _message(check_transform, T[None], "T", tol)


@pytest.mark.parametrize("tol", [1e-9, 1e-6])
def test_one_transform_gets_the_batch_verdict(tol):
    rng = np.random.default_rng(11)
    good = se3.exp(rng.standard_normal(6))
    cases = [good, np.eye(4)]
    bad_row = good.copy()
    bad_row[3, 0] = 10 * tol
    off = good.copy()
    off[:3, :3] *= 1 + 10 * tol  # not orthonormal
    mirror = good.copy()
    mirror[:3, 0] *= -1  # orthonormal, det -1
    near = good.copy()
    near[3, 3] = 1 + tol / 2  # within the tolerance
    cases += [bad_row, off, mirror, near]
    for T in cases:
        got = _message(check_transform, T, "T", tol)
        want = _batch_verdict(T, tol)
        if want is None:
            assert got is None
            assert np.array_equal(check_transform(T, "T", tol), T)
        else:  # the message names no batch index for one transform: the type and its rule agree
            assert got is not None and got[0] is want[0]
            assert got[1].split(":")[0] == want[1].split(":")[0]
    with pytest.raises(ManifoldError, match="last row"):
        check_transform(bad_row, "T", tol)
    with pytest.raises(ManifoldError, match="not orthonormal"):
        check_transform(mirror, "T", tol)


def test_replace_keeps_an_unchanged_transform_and_checks_a_changed_one(ur10_sets):
    nominal = ur10_sets[0]
    arm = next(iter(nominal.arms.values()))
    same = arm.replace(base=np.array(arm.base), home=se3.exp(np.full(6, 1e-3)) @ arm.home)
    assert same.base is arm.base  # the frozen array kept: equal bit for bit
    assert not same.home.flags.writeable and not np.array_equal(same.home, arm.home)
    negzero = np.array(arm.base)
    zeros = negzero == 0
    negzero[zeros] = -0.0  # equal, other bits: checked and stored as given
    moved = arm.replace(base=negzero)
    assert moved.base is not arm.base and moved.base.tobytes() == negzero.tobytes()
    bad = np.array(arm.tool)
    bad[:3, :3] *= 1.01
    with pytest.raises(ManifoldError, match="tool"):
        arm.replace(tool=bad)


def test_deferred_fields_read_as_computed_eagerly(ur10_sets):
    nominal, markers, _ = ur10_sets
    res = calibrate(nominal, [markers], "kinematic", noise=NOISE)
    assert all(isinstance(res.__dict__[k], Deferred) for k in ("after", "correlated", "twists"))
    state = res.state
    frozen = res.covariance.copy()
    names = [res.layout.names[i] for i in res.problem.free_idx]
    ok = np.array([e.identifiable for e in res.estimates])
    want_twists = finalize_module._twists(res.problem, state, frozen)
    want_corr = tuple(finalize_module.correlated_pairs(frozen, names, 0.9, ok))
    want_after = _pickled(tuple(res.problem.statistics(state, res.linearization.W)))
    pickled = pickle.loads(_pickled(res))  # before the first read: pickled computed
    copied = copy.copy(res)
    replaced = dataclasses.replace(res, status="converged")
    res.covariance[:] = 0.0  # a reader writing into the covariance changes neither
    for r in (res, pickled, copied, replaced):
        assert len(r.twists) == 36 and r.twists == want_twists
        assert r.correlated == want_corr and _pickled(r.after) == want_after
    assert not isinstance(res.__dict__["twists"], Deferred)  # kept once read


def test_after_read_late_as_computed_at_the_solve(ur10_sets):
    """``Result.after`` read after the problem was solved again (its residual cache moved on, its kinematics no
    longer remembered) gives what the solve's own statistics gave, bit for bit."""
    nominal, markers, pose = ur10_sets
    problem = Problem.build(nominal, [markers, pose], "kinematic", noise=NOISE)
    res = solve(problem)
    assert isinstance(res.__dict__["after"], Deferred)
    with remembered_kinematics(problem.experiments):
        want = tuple(problem.statistics(res.state, res.linearization.W))
    solve(problem, SolverOptions(loss="huber"))
    assert _pickled(res.after) == _pickled(want) and len(want) == 2


def _read_only(d: dict) -> MappingProxyType:
    return MappingProxyType(d)


def _pickled(obj) -> bytes:
    """``obj`` pickled with read-only mappings (a data set's meta) as the dicts they wrap (the bench's way),
    without registering that for every test."""
    buf = io.BytesIO()
    pickler = pickle.Pickler(buf)
    pickler.dispatch_table = {**copyreg.dispatch_table, MappingProxyType: lambda m: (_read_only, (dict(m),))}
    pickler.dump(obj)
    return buf.getvalue()


def test_residual_norms_as_before():
    rng = np.random.default_rng(2)

    def before(r, components):  # what it gave: the norms of the columns of each quantity, by column indices
        st = {}
        for key, q in (("position", POSITION), ("orientation", ORIENTATION), ("pixel", PIXEL)):
            cols = [i for i, c in enumerate(components) if c == q]
            if not cols:
                st[f"{key}_rms"] = st[f"{key}_max"] = None
                continue
            part = r[:, cols]
            points = key == "position" and len(cols) > 1 and len(cols) % 3 == 0
            e = (np.linalg.norm(part.reshape(len(r), -1, 3), axis=-1).ravel() if points else
                 np.abs(part).ravel() if key == "position" else np.linalg.norm(part, axis=-1))
            st[f"{key}_rms"], st[f"{key}_max"] = float(np.sqrt(np.mean(e**2))), float(np.max(e))
        return st

    for comps in [(POSITION,) * 3, (POSITION,) * 6, (POSITION,) * 3 + (ORIENTATION,) * 3, (POSITION,),
                  (PIXEL,) * 2, [dataclasses.replace(POSITION)] * 3, (ORIENTATION,) * 3 + (POSITION,) * 2]:
        r = rng.standard_normal((17, len(comps)))
        assert residual_norms(r, comps) == before(r, comps)


def test_estimates_as_before(ur10_sets):
    nominal, _, pose = ur10_sets
    res = calibrate(nominal, [pose], "kinematic", noise=NOISE)
    p, ok = res.problem, np.array([e.identifiable for e in res.estimates])
    got = finalize_module._estimates(p, res.state, ok, res.covariance)
    assert repr(got) == repr(list(res.estimates))  # (nan std: repr compares the floats exactly)
    for e in got:
        assert type(e.value) is float and type(e.std) is float and type(e.identifiable) is bool


def test_not_finite_data_named_as_before(ur10_sets):
    _, markers, _ = ur10_sets
    assert checked(markers, {"tracker": "tracker", "markers": "markers"}) is not None
    measured = {k: np.array(v) for k, v in markers.measured.items()}
    key = next(iter(measured))
    measured[key][3, 0, 1] = np.nan
    bad = Dataset(**{**{f.name: getattr(markers, f.name) for f in dataclasses.fields(markers)},
                     "measured": measured})
    with pytest.raises(DataFormatError, match=rf"sample 3 field measured\['{key}'\] at index \(3, 0, 1\) is nan"):
        checked(bad, {"tracker": "tracker", "markers": "markers"})


def test_solve_reuses_the_kinematics_of_the_initial_guesses(ur10_sets, monkeypatch):
    """``calibrate`` keeps the experiments' kinematics from the frames' initial guesses (the nominal forward
    kinematics) for its solve: one forward kinematics fewer, the same result bit for bit, nothing kept after."""
    nominal, markers, _ = ur10_sets
    calls = []
    fresh = base_module.Experiment._fresh_kin

    def counted(self, state, arm):
        calls.append(arm)
        return fresh(self, state, arm)

    monkeypatch.setattr(base_module.Experiment, "_fresh_kin", counted)
    plain = solve(Problem.build(nominal, [markers], "kinematic", noise=NOISE))
    without = len(calls)
    calls.clear()
    res = calibrate(nominal, [markers], "kinematic", noise=NOISE, outliers="keep")
    assert len(calls) == without - 1
    assert repr(res.estimates) == repr(plain.estimates) and res.covariance.tobytes() == plain.covariance.tobytes()
    assert not base_module._KINEMATICS and res.problem.experiments  # closed with the call (res keeps them alive)
    with pytest.raises(ModelError, match="cannot be fixed"):  # raised by the build, within the call
        calibrate(nominal, [markers], [], fixed=["*"], noise=NOISE)
    assert not base_module._KINEMATICS


def test_whiteners_without_encoder_noise_computed_once_per_problem(ur10_sets, monkeypatch):
    """Without encoder noise the whiteners depend on the stated noise and the residuals' shapes alone: a problem
    computes them once (its first linearization; the outlier screen reuses them), the same arrays as computed
    afresh. With encoder noise they follow the state and are computed every time."""
    nominal, markers, pose = ur10_sets
    calls = []
    at = Problem._whitened_at

    def counted(self, residuals):
        calls.append(self)
        return at(self, residuals)

    monkeypatch.setattr(Problem, "_whitened_at", counted)
    res = calibrate(nominal, [markers, pose], "kinematic", noise=NOISE)
    problem = res.problem
    assert calls.count(problem) == 1
    kept = problem.whiteners(res.state)
    fresh = at(problem, problem.residuals(res.state))  # computed afresh
    assert calls.count(problem) == 1 and all(a.tobytes() == b.tobytes() for a, b in zip(kept, fresh))
    calls.clear()
    noisy = calibrate(nominal, [markers], "kinematic", noise=Noise(position=1e-5, joint=1e-5), outliers="keep")
    assert calls.count(noisy.problem) > 1  # not kept: each fresh whitening at its state


def test_remembered_blocks_follow_the_structure(ur10_sets):
    """``build_layout``'s blocks remembered per structure: the arms' values objects and the frames' names, kinds
    and shapes; another marker count, another arm model or renamed joints get their own, and every hit equals
    what ``_blocks`` computes."""
    from kincal.params import POINTS, POSE, State, clear_caches, layout as layout_module
    from kincal.robots import load

    nominal = ur10_sets[0]

    def state(robot, markers: int):
        return State.from_robot(robot, {"tracker": np.eye(4), "markers": np.zeros((markers, 3))},
                                {"tracker": POSE, "markers": POINTS})

    renamed = load("ur10")
    arm = next(iter(renamed.arms))
    renamed = renamed.replace_arm(arm, dataclasses.replace(
        renamed.arms[arm], joint_names=tuple(f"q{i}" for i in range(renamed.arms[arm].dof))))
    clear_caches()
    for robot, m in [(nominal, 1), (nominal, 2), (nominal, 1), (renamed, 1), (renamed, 2), (nominal, 2)]:
        s = state(robot, m)
        want = layout_module._blocks(s, list(s.arms))
        got = layout_module._remembered_blocks(s, list(s.arms))
        assert [tuple(x) for x in got[:3]] == [tuple(x) for x in want[:3]] and got[3] == want[3]
        assert sum(n.startswith("markers.m") for n in got[0]) == 3 * m
    assert len(layout_module._BLOCKS) == 4
    clear_caches()
    assert not layout_module._BLOCKS
