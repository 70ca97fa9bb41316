"""Session 14 (helper retract): the state updates of a solver step (``ops.retract``, ``ops.conform``,
``ops.recentre``) with fewer numpy and Python calls, bit for bit.

``twists.tangent_frames`` lays out every joint's B and G from 18 values per joint (their negatives and zeros by
one take) into two contiguous (n, 6, 4) arrays, handed on as ``Stacked`` tuples that ``values.twist_motions`` and
``retract_twists`` use without ``np.stack``; ``conform_twists`` checks the joint types on its per-joint loop;
``State.moved`` is ``State.replace`` for new values of the same frames. Each against the path it replaces, on
several structures (markers, pose, clamp, dual arm, elastic, prismatic joints), whole calibrations included."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

from kincal import robots
from kincal.estimation import Problem, calibrate
from kincal.kinematics import twists
from kincal.params import State, clear_caches, conform, recentre, retract
from kincal.params import values as V
from kincal.simulate.generators import generate_markers
from kincal.testing import random_arm
from test_fixed_overhead_s12_c import NOISE, _bits, _digest, cases  # noqa: F401 (markers, pose, clamp, dual, elastic)

REV, PRI = "revolute", "prismatic"


@pytest.fixture(scope="module")
def prismatic_case():
    """A random 6-joint arm whose third joint is prismatic, seen by a tracker and markers."""
    arm = random_arm(np.random.default_rng(4), 6, (2,))
    robot = robots.Robot("slider", {"arm": arm})
    return "prismatic", robot, [generate_markers(robot, n=30, rng=5, noise=NOISE)[0]], "kinematic", NOISE


def _random_screws(rng, n, types):
    xi = rng.standard_normal((n, 6))
    xi = np.where(rng.random(xi.shape) < 0.3, rng.choice([0.0, -0.0], xi.shape), xi)  # signed zeros
    for j, t in enumerate(types):
        part = xi[j, 3:] if t == REV else xi[j, :3]
        if not part.any():
            part[:] = [0.0, -1.0, 1.0]  # a tie of magnitudes
    return xi


def _plain_paths(m):
    """Every replaced path back to the general one: numpy's batched frames and conformation, ``np.stack`` of the
    joints' frames, ``State.replace``."""
    m.setattr(twists, "_FEW", 0)
    m.setattr(V, "_one_width", lambda f: np.stack(f) if len({G.shape[1] for G in f}) == 1 else None)
    m.setattr(State, "moved", lambda self, arms, extras: self.replace(arms, extras))


# ------------------------------------------------------------------------------------------- pieces


@pytest.mark.parametrize("n", [0, 1, 6, 7, 16])
def test_tangent_frames_are_the_batched_numpy_ones_bit_for_bit(monkeypatch, n):
    rng = np.random.default_rng(n)
    for xi in [_random_screws(rng, n, (REV,) * n) for _ in range(20)] + [robots.load("ur10")["arm"].screws[:n]]:
        k = len(xi)
        got = twists.tangent_frames(xi, (REV,) * k)
        with monkeypatch.context() as m:
            m.setattr(twists, "_FEW", -1)
            want = twists.tangent_frames(xi, [REV] * k)
        for g, w in zip(got, want):
            assert type(g) is twists.Stacked and type(w) is tuple and len(g) == len(w) == k
            assert _bits(g) == _bits(w)
            if k:
                assert g.stack.flags.c_contiguous and _bits(g.stack) == _bits(np.stack(w))
                assert all(np.shares_memory(x, g.stack) for x in g)


def test_frame_layout_is_the_one_joint_form():
    """``_revolute_frame`` (the entries laid out by ``_FRAME_INDEX``) against ``tangent_frames`` of that joint."""
    rng = np.random.default_rng(3)
    for xi in _random_screws(rng, 30, (REV,) * 30):
        B, G = twists.tangent_frames(xi[None], (REV,))
        flat = twists._revolute_frame(xi[:3].tolist(), xi[3:].tolist())
        assert np.array(flat).tobytes() == np.concatenate([B[0].ravel(), G[0].ravel()]).tobytes()
    # u1, u2, wu2 as they are; u2, wu2 and the three cross products with p negated; the zero
    assert set(twists._FRAME_INDEX) == {*range(9), *range(21, 37)}


def test_mixed_and_unknown_joints_take_the_general_path():
    rng = np.random.default_rng(8)
    types = (REV, PRI, REV)
    B, G = twists.tangent_frames(_random_screws(rng, 3, types), types)
    assert type(B) is tuple and [b.shape[1] for b in B] == [4, 2, 4]
    with pytest.raises(ValueError, match="unknown joint type 'spherical'"), np.errstate(invalid="ignore"):
        twists.tangent_frames(np.zeros((2, 6)), (REV, "spherical"))


def test_stacked_pickles_and_copies_as_a_plain_tuple():
    B, _ = twists.tangent_frames(robots.load("ur10")["arm"].screws, (REV,) * 6)
    for other in (pickle.loads(pickle.dumps(B)), copy.deepcopy(B), copy.copy(B)):
        assert type(other) in (tuple, twists.Stacked) and _bits(other) == _bits(B)
    assert type(pickle.loads(pickle.dumps(B))) is tuple
    again = twists.Stacked(x for x in B)  # from the arrays (``dataclasses.asdict``'s way): stacked anew
    assert _bits(again) == _bits(B) and _bits(again.stack) == _bits(B.stack) and again.stack is not B.stack


@pytest.mark.parametrize("share", [0.0, 0.4])
def test_conform_twists_per_joint_is_the_batched_numpy_one(monkeypatch, share):
    rng = np.random.default_rng(int(10 * share))
    for trial in range(200):
        n = int(rng.integers(0, 9))
        types = tuple(PRI if rng.random() < share else REV for _ in range(n))
        xi = _random_screws(rng, n, types)
        for mode in ("line", "thesis"):
            got = twists.conform_twists(xi, types, mode)
            with monkeypatch.context() as m:
                m.setattr(twists, "_FEW", 0)
                want = twists.conform_twists(xi, list(types), mode)
            assert got.shape == want.shape == (n, 6) and got.tobytes() == want.tobytes()
            assert not np.shares_memory(got, xi)


def test_conform_twists_errors_and_zero_axes_as_before(monkeypatch):
    xi = np.ones((3, 6))
    for types in ((REV, "ball", PRI), ("ball", REV, REV)):
        with pytest.raises(ValueError, match="unknown joint type 'ball'"):
            twists.conform_twists(xi, types)
    zero = np.zeros((2, 6))  # a zero axis before an unknown type: numpy's path, which names the type
    with pytest.raises(ValueError, match="unknown joint type 'ball'"):
        twists.conform_twists(zero, (REV, "ball"))
    with np.errstate(divide="ignore", invalid="ignore"):
        got = twists.conform_twists(zero, (REV, PRI))
        with monkeypatch.context() as m:
            m.setattr(twists, "_FEW", 0)
            assert got.tobytes() == twists.conform_twists(zero, (REV, PRI)).tobytes()


def _problems(cases, prismatic_case):
    for _, robot, sets, free, noise in [*cases, prismatic_case]:
        yield Problem.build(robot, sets, free, noise=noise)


def test_retraction_and_recentring_are_the_general_paths_bit_for_bit(monkeypatch, cases, prismatic_case):
    """retract (with and without tangents), conform, recentre (both ways) from a model's values and from a
    re-centred state (whose frames are ``Stacked``), against the paths they replace."""
    for problem in _problems(cases, prismatic_case):
        step = problem.full_delta(1e-4 * np.random.default_rng(1).normal(size=len(problem.free_idx)))

        def chain():
            s = recentre(retract(problem.start, problem.layout, step))
            out = [s]
            for tangents in (True, False):
                moved = retract(s, problem.layout, 0.5 * step, tangents=tangents)
                out += [moved, conform(moved), recentre(moved), recentre(conform(moved), conformed=True)]
            return out

        got = chain()
        with monkeypatch.context() as m:
            _plain_paths(m)
            want = chain()
        for g, w in zip(got, want):
            assert _bits(dict(g.arms)) == _bits(dict(w.arms)) and _bits(dict(g.extras)) == _bits(dict(w.extras))
            assert g.kinds == w.kinds and g.mounts == w.mounts


def test_twist_motions_and_retraction_of_stacked_and_plain_frames(cases, prismatic_case):
    for problem in _problems(cases, prismatic_case):
        for a in problem.start.arms.values():
            a = recentre(State({"x": a})).arms["x"]
            plain = V.arm_replace(a, bases=tuple(a.bases), generators=tuple(a.generators))
            d = np.random.default_rng(2).normal(size=sum(G.shape[1] for G in a.generators)) * 1e-3
            assert V.twist_motions(a, d).tobytes() == V.twist_motions(plain, d).tobytes()
            for tangents in (True, False):
                assert _bits(V.retract_twists(a, d, tangents)) == _bits(V.retract_twists(plain, d, tangents))
            if all(t == REV for t in a.joint_types):
                assert type(V.retract_twists(a, d).generators) is twists.Stacked


def test_moved_is_replace_and_checks_the_frames():
    ur10 = robots.load("ur10")
    s = State.from_robot(ur10, {"tracker": np.eye(4)}, {"tracker": "pose"})
    arms, extras = dict(s.arms), {"tracker": 2 * np.eye(4)}
    got, want = s.moved(arms, extras), s.replace(arms, extras)
    assert type(got) is State and _bits(got) == _bits(want)
    assert got.arms is arms and got.extras is extras and got.kinds is s.kinds and got.mounts is s.mounts
    with pytest.raises(Exception, match="no parameter kind"):
        s.moved(arms, {"tracker": np.eye(4), "stray": np.eye(4)})


# ------------------------------------------------------------------------------------------- whole calibrations


@pytest.mark.parametrize("k", range(7))
def test_calibrations_give_what_the_general_paths_give(monkeypatch, cases, prismatic_case, k):
    """The first calibration of a structure and a repeat, then the general paths': every number and word."""
    name, robot, sets, free, noise = [*cases, prismatic_case][k]
    clear_caches()
    digests = []
    for general in (False, False, True):
        with monkeypatch.context() as m:
            if general:
                _plain_paths(m)
                clear_caches()
            digests.append(_digest(calibrate(robot, sets, free, noise=noise)))
    assert digests[0] == digests[1] == digests[2], name


def test_a_changed_bit_in_the_frames_shows(monkeypatch, cases):
    _, robot, sets, free, noise = cases[1]
    before = _digest(calibrate(robot, sets, free, noise=noise))
    with monkeypatch.context() as m:
        m.setattr(V, "_one_width", lambda f: np.stack(f) * (1 + 1e-15))
        after = _digest(calibrate(robot, sets, free, noise=noise))
    assert after != before
