"""Session 13 (a): a calibration's set-up without work that depends on structure only or was done a moment ago.

The noise in effect per data set is remembered by the values it is made of (``problem._effective``: a new
``Noise`` with the same values at every call of a batch); ``Problem.blocked`` is known without making the blocks
when the problem is not evaluated by blocks; the unit check's "every value near its column's median" test runs on
Python floats for few columns. Each is held here to the general path it replaces, on several structures."""

from __future__ import annotations

import numpy as np
import pytest

from kincal import robots
from kincal.errors import DataFormatError, ModelError
from kincal.estimation import calibrate, memory
from kincal.estimation import plausibility as PL
from kincal.estimation import problem as P
from kincal.estimation.problem import Problem
from kincal.noise import Noise, effective
from kincal.params import clear_caches
from kincal.simulate.generators import generate_clamp, generate_dual, generate_markers, generate_pose
from test_structure_cache import ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)


def _fields(n: Noise) -> str:
    """Every value of ``n`` with its type (``repr`` tells 1 from 1.0 and -0.0 from 0.0)."""
    return repr((n.position, n.orientation, n.joint, n.backlash, dict(n.other)))


EXPLICIT = [None, Noise(position=5e-5, joint=0.0), Noise(position=5e-5, joint=-0.0), Noise(position=1, joint=0),
            Noise(position=1.0, joint=0.0), Noise(orientation=2e-5, other={"pixel": 0.5}),
            Noise(position=np.float64(5e-5))]
STATED = [None, {}, {"position_m": 1e-4}, {"position_m": 1e-4, "joint_rad": 0}, {"position_m": -0.0},
          {"pixel_px": 2}, {"pixel_px": 2.0}, {"position_m": "1e-4"}]


@pytest.mark.parametrize("stated", STATED)
@pytest.mark.parametrize("explicit", EXPLICIT)
def test_the_remembered_noise_is_the_rules_noise(explicit, stated):
    for _ in range(2):  # computed, then remembered
        got, want = P._effective(explicit, stated), effective(explicit, stated)
        assert got == want and _fields(got) == _fields(want)


def test_the_noise_memory_misses_on_any_other_value():
    clear_caches()
    seen = {}
    for explicit in EXPLICIT:
        for stated in STATED:
            key = P._noise_key(explicit, stated)
            if key is not None:  # one key, one noise (None and {} state nothing alike)
                want = _fields(effective(explicit, stated))
                assert seen.setdefault(key, want) == want
            P._effective(explicit, stated)
    assert len(seen) > len(EXPLICIT) and len(P._NOISES) == min(len(seen), P.NOISE_ENTRIES)
    keys = [P._noise_key(Noise(position=v), None) for v in (0.0, -0.0, 0, 1, 1.0, True)]
    assert len(set(keys)) == len(keys)
    assert P._noise_key(Noise(position=np.float64(5e-5)), None) is None  # no exact repr assumed: not remembered
    assert P._noise_key(None, {"position_m": "1e-4"}) is None
    clear_caches()  # ``params.clear_caches`` empties it too
    assert not P._NOISES


def test_a_data_sets_changed_noise_is_read_again(ur10_sets):
    from dataclasses import replace

    nominal, markers, _ = ur10_sets
    first = Problem.build(nominal, [markers], "kinematic")
    other = replace(markers, meta={**markers.meta, "noise": {"position_m": 3e-4}})
    second = Problem.build(nominal, [other], "kinematic")
    assert second.noise[0].position == 3e-4 and first.noise[0] == effective(None, markers.meta.get("noise"))


def _structures(ur10_sets):
    """(robot, data sets, free) of markers, pose, clamp and dual-arm problems."""
    nominal, markers, pose = ur10_sets
    frida = robots.load("frida")
    clamp = generate_clamp(frida, "right", n=30, rng=np.random.default_rng(2))[0]
    dual = generate_dual(frida, n=30, rng=0, noise=Noise(joint=1e-5), known_clamp=False)[0]
    return {"markers": (nominal, [markers], "kinematic"), "pose": (nominal, [pose], "kinematic"),
            "clamp": (frida, [clamp], "offsets"), "dual": (frida, [dual], "offsets"),
            "two sets": (nominal, [markers, pose], "kinematic")}


@pytest.mark.parametrize("tiny", [False, True])
@pytest.mark.parametrize("case", ["markers", "pose", "clamp", "dual", "two sets"])
def test_blocked_is_the_blocks_verdict(monkeypatch, ur10_sets, case, tiny):
    robot, sets, free = _structures(ur10_sets)[case]
    with monkeypatch.context() as m:
        if tiny:
            m.setattr(memory, "CHUNK_BYTES", 20_000)  # a few configurations per block
        quick = Problem.build(robot, sets, free)
        assert quick.blocked is tiny
        assert (quick.cache.parts is not None) is tiny  # the blocks made only where they are used
        general = Problem.build(robot, sets, free)
        assert general.blocked == (len(general.parts()) > len(general.experiments)) == tiny


def test_an_unknown_frame_cannot_be_fixed(ur10_sets):
    nominal, markers, _ = ur10_sets
    with pytest.raises(ModelError, match="unknown .* cannot be fixed"):
        calibrate(nominal, [markers], "kinematic", fixed=iter(["tracker"]))
    assert calibrate(nominal, [markers], "kinematic", fixed=iter([])).status == \
        calibrate(nominal, [markers], "kinematic").status


def _within_numpy(flat, bound):
    hi, lo = flat.max(axis=0), flat.min(axis=0)
    return bool(hi.max(initial=-np.inf) <= 1e300 and lo.min(initial=np.inf) >= -1e300 and (hi - lo <= bound).all())


@pytest.mark.parametrize("columns", [0, 1, 3, 9, PL._FEW_COLUMNS, PL._FEW_COLUMNS + 1])
def test_the_unit_checks_spread_test_on_floats_is_numpys(columns):
    rng = np.random.default_rng(columns)
    for trial in range(60):
        flat = rng.normal(size=(7, columns)) * 10.0 ** rng.integers(-3, 4)
        if columns and trial % 3:
            flat[rng.integers(7), rng.integers(columns)] = rng.choice([np.nan, np.inf, -np.inf, 1e301, -1e301,
                                                                        150.0, -99.0, 1e300])
        for bound in (100.0, 1e-3, 0.0):
            assert PL._within(flat, bound) is _within_numpy(flat, bound)


def test_repeated_data_set_names_are_refused(ur10_sets):
    nominal, markers, _ = ur10_sets
    with pytest.raises(DataFormatError, match=f"unique; repeated: {markers.name}$"):
        calibrate(nominal, [markers, markers], "kinematic")


def test_shared_frames_of_different_shapes_are_refused(ur10_sets):
    """The shapes are read where a frame is shared or given (``sharing._check_shapes``), and only there."""
    from dataclasses import replace

    nominal = ur10_sets[0]
    one, two = (generate_markers(nominal, n=6, rng=k, markers=k)[0] for k in (1, 2))
    one, two = (replace(d, name=f"set{k}", frames={"markers": "cluster"}) for k, d in ((1, one), (2, two)))
    with pytest.raises(DataFormatError, match="share frame 'cluster' .* different shapes: \\(1, 3\\) in 'set1', "
                                              "\\(2, 3\\) in 'set2'"):
        Problem.build(nominal, [one, two], "offsets")
    same = replace(two, name="set3")
    problem = Problem.build(nominal, [two, same], "offsets")
    assert problem.nominal.extras["cluster"].shape == (2, 3)


def test_a_kinds_own_start_is_asked_and_the_default_one_skipped(ur10_sets, monkeypatch):
    """``starting_state`` skips the kinds whose ``start`` is ``Experiment.start`` (never a correction), and only
    those: an experiment's own ``start`` (here patched on the kind) is asked with the free arm poses."""
    from kincal.experiments.markers import MarkersExperiment
    from kincal.lie import se3

    nominal, markers, _ = ur10_sets
    assert Problem.build(nominal, [markers], "kinematic").start.arms["arm"].tool is nominal_tool(nominal)
    X = se3.make(np.eye(3), np.array([0.0, 0.0, 0.01]))
    asked = []

    def start(self, state, free, unknown):
        asked.append(tuple(free))
        return {"arm.tool": X}
    monkeypatch.setattr(MarkersExperiment, "start", start)
    problem = Problem.build(nominal, [markers], "kinematic")
    assert asked == [("arm.home",)]  # the kinematic level frees the home pose, not the tool
    assert problem.start is not problem.nominal and problem.start.arms["arm"].tool is nominal_tool(nominal)
    assert not np.array_equal(problem.start.arms["arm"].home, problem.nominal.arms["arm"].home)


def nominal_tool(robot):
    from kincal.params import ArmValues

    return ArmValues.from_model(robot["arm"]).tool


def test_role_kinds_are_the_schemas(ur10_sets):
    from kincal.experiments import KINDS
    from kincal.experiments import sharing
    from kincal.params import FRAME_KINDS

    clear_caches()
    assert not sharing._ROLE_KINDS
    nominal, markers, pose = ur10_sets
    for ds in (markers, pose):
        exp = KINDS[ds.kind](ds, {})
        for _ in range(2):  # computed, then remembered
            for r in exp.SCHEMA.roles:
                assert sharing.role_kind(exp, r.name) is FRAME_KINDS[r.parameter]
    assert len(sharing._ROLE_KINDS) == sum(len(KINDS[d.kind].SCHEMA.roles) for d in (markers, pose))
    clear_caches()
    assert not sharing._ROLE_KINDS


def _markers_guess_earlier(exp, state, W):
    """The marker guess of 0295a4a's ``MarkersExperiment.initial`` from the tracker ``W``."""
    from kincal.lie import se3

    F, y = exp._fk(state, exp.arms[0]), exp.dataset.measured["p_tracker_marker"]
    local = se3.transform_points(se3.inverse(F)[:, None], se3.transform_points(W, y))
    return np.add.reduce(local, axis=0) / len(local)


@pytest.mark.parametrize("n, markers", [(1, 1), (7, 3), (50, 1), (300, 2)])
def test_the_markers_initial_guess_is_the_earlier_forms_bit_for_bit(ur10_sets, n, markers):
    from kincal.experiments import KINDS
    from kincal.lie import se3
    from kincal.params import State
    from kincal.simulate import perturb_robot

    nominal = ur10_sets[0]
    true = perturb_robot(nominal, "fine", rng=np.random.default_rng(n))
    ds, _, _ = generate_markers(true, n=n, rng=n + markers, markers=markers, noise=Noise(position=1e-4))
    state = State.from_robot(nominal)
    exp = KINDS[ds.kind](ds, {"tracker": "tracker", "markers": "markers"})
    fitted = exp.initial(state, {})
    other = se3.exp(np.array([0.3, -1.2, 2.5, 0.4, -0.2, 1.1])) @ fitted["tracker"]
    for W, got in ((fitted["tracker"], fitted["markers"]), (other, exp.initial(state, {"tracker": other})["markers"])):
        want = _markers_guess_earlier(exp, state, W)
        assert got.shape == want.shape and got.tobytes() == want.tobytes()


def test_named_frames_are_still_checked_against_the_arms(ur10_sets):
    """``frame_names`` skips the check of a data set naming no frame, and only of those."""
    from dataclasses import replace

    nominal, markers, _ = ur10_sets
    named = replace(markers, frames={"tracker": "arm.tracker"})
    with pytest.raises(DataFormatError, match="does not start with an arm of the model \\('arm'"):
        Problem.build(nominal, [named], "offsets")
    assert "my_tracker" in Problem.build(nominal, [replace(markers, frames={"tracker": "my_tracker"})],
                                         "offsets").nominal.extras


@pytest.mark.parametrize("tiny", [False, True])
def test_calibrate_solves_within_the_kinematics_its_build_remembers(monkeypatch, ur10_sets, tiny):
    """``calibrate`` solves by ``solver._solved`` inside the build's ``keep``: the experiments' kinematics are
    remembered during the solve exactly as ``solve`` would remember them (none when solved by blocks), and the
    result is ``solve``'s."""
    from kincal.estimation import solver
    from kincal.experiments import base

    nominal, markers, _ = ur10_sets
    seen = []
    original = solver.iterate

    def spy(problem, options):
        seen.append((problem.blocked, [e in base._KINEMATICS for e in problem.experiments]))
        return original(problem, options)
    with monkeypatch.context() as m:
        if tiny:
            m.setattr(memory, "CHUNK_BYTES", 20_000)
        m.setattr(solver, "iterate", spy)
        got = calibrate(nominal, [markers], "kinematic", outliers="keep")
        want = solver.solve(Problem.build(nominal, [markers], "kinematic"))
    assert seen == [(tiny, [not tiny]), (tiny, [not tiny])]
    assert (got.status, got.messages, got.iterations) == (want.status, want.messages, want.iterations)
    for a, b in zip(got.estimates, want.estimates):
        assert (a.name, a.value) == (b.name, b.value) and (a.std == b.std or np.isnan(a.std) and np.isnan(b.std))
