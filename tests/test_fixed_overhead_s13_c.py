"""Session 13 (c): the identifiability report prints only what the null space determines.

The named null directions were the echelon form of the null directions orthogonal to the solver's scale
direction, which is scale plus some other null direction that round-off picks (``symmetries.scale_null``'s
solve inverts singular values near 1e-13 in a dual arm): one-ulp changes of the joint readings moved printed
coefficients by up to 28 %. Now the scale message stands for one row of the null space's echelon form and the
others are named as they are (``identifiability._scale_pivot``), each coefficient printed to the digits its
uncertainty leaves (``_uncertainty``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from kincal import robots
from kincal.analysis import analyse
from kincal.analysis import identifiability as ident
from kincal.estimation import calibrate
from kincal.simulate.generators import generate_clamp, generate_dual
from kincal.simulate.perturb import perturb_robot

from test_fixed_overhead_s12_c import cases  # noqa: F401 (the structures: markers, pose, clamp, dual, elastic)


def _ulp(data, up: bool):
    """``data`` with every joint reading moved by one ulp."""
    return dataclasses.replace(data, q={a: np.nextafter(q, np.inf if up else -np.inf) for a, q in data.q.items()})


def _named(res):
    return [(d.pivot, [n for n, _ in d.partners], d.words) for d in res.identifiability.directions]


@pytest.fixture(scope="module")
def frida_truth():
    frida = robots.load("frida")
    return frida, perturb_robot(frida, "thesis", 7)


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_dual_arm_named_directions_survive_one_ulp_of_every_joint_reading(frida_truth, seed):
    """Pivots, partners and printed coefficients the same, word for word, when every joint reading moves by one
    ulp either way (before: 32 of 33 messages changed, coefficients by up to 28 %). The scale message's list
    of the lengths it moves most reads the solver's scale direction, whose round-off part is
    ``symmetries.scale_null``'s (its count, "and 75 more" against "76 more", can still move): left out here."""
    frida, truth = frida_truth
    dual = generate_dual(truth, n=25, rng=seed, known_clamp=False)[0]
    ref = calibrate(frida, [dual], "kinematic")
    assert ref.identifiability.scale_unidentifiable and len(ref.identifiability.directions) == 32
    for up in (True, False):
        res = calibrate(frida, [_ulp(dual, up)], "kinematic")
        assert _named(res) == _named(ref)
        named = [m for m in res.messages if not m.startswith("scale cannot be identified")]
        assert named == [m for m in ref.messages if not m.startswith("scale cannot be identified")]


def test_single_arm_clamp_report_survives_one_ulp_of_every_joint_reading(frida_truth):
    """A clamp with an unknown fixture at level kinematic (scale unidentifiable too): every message the same
    (before: 19 of 20 changed)."""
    frida, truth = frida_truth
    clamp = generate_clamp(truth, "right", n=25, rng=1, known_fixture=False)[0]
    ref = calibrate(frida, [clamp], "kinematic")
    assert ref.identifiability.scale_unidentifiable
    for up in (True, False):
        assert calibrate(frida, [_ulp(clamp, up)], "kinematic").messages == ref.messages


# what 7c28e65 printed for the `cases` markers and clamp structures: well-determined coefficients, unchanged
MARKERS = [
    "arm.shoulder_pan.offset cannot be identified from markers 'markers' (free: tracker, markers): it trades off "
    "against tracker.w_z (+1), tracker.w_x (-0.00348), tracker.w_y (+0.00223) (a rotation of the tracker about the "
    "axis of arm.shoulder_pan)",
    "arm.shoulder_lift.offset cannot be identified from markers 'markers' (free: tracker, markers): it trades off "
    "against markers.m2.y (+1.19), arm.wrist_1.xi.shift_2 (-1.19), arm.wrist_3.xi.shift_1 (+1.18), markers.m1.y "
    "(+1.15), markers.m3.y (+1.15), arm.wrist_2.xi.tilt_2 (+1) and 14 more (in a full POE model a joint offset "
    "equals rotating the later joint axes and the home pose about that joint's axis)",
    "arm.elbow.offset cannot be identified from markers 'markers' (free: tracker, markers): it trades off against "
    "arm.wrist_2.xi.tilt_2 (+1), markers.m2.y (+0.582), arm.wrist_1.xi.shift_2 (-0.573), arm.wrist_3.xi.shift_1 "
    "(+0.571), markers.m1.y (+0.541), markers.m3.y (+0.534) and 12 more (in a full POE model a joint offset equals "
    "rotating the later joint axes and the home pose about that joint's axis)",
]
CLAMP = ("right.j1.offset cannot be identified from clamp 'clamp' (free: fixture): it trades off against fixture.w_x "
         "(+0.813), fixture.w_z (+0.47), fixture.w_y (-0.343), fixture.v_y (+0.31), fixture.v_x (+0.108), "
         "fixture.v_z (+0.039) (a rotation of the fixture about the axis of right.j1)")


def test_well_determined_reports_print_what_they_printed(cases):  # noqa: F811
    """Without scale in the null space the named basis is the one before; its coefficients hold all three digits
    and no partner is dropped as undetermined, so the words are the same."""
    by_name = {name: (robot, data, free, noise) for name, robot, data, free, noise in cases}
    robot, data, free, noise = by_name["markers"]
    assert list(calibrate(robot, data, free, noise=noise).messages[:3]) == MARKERS
    robot, data, free, noise = by_name["clamp"]
    assert CLAMP in calibrate(robot, data, free, noise=noise).messages


def _null_problem(rng, p=10, k=4, m=30):
    """A Jacobian (m, p) whose null space is span(N0) (p, k), and N0."""
    N0 = np.linalg.qr(rng.normal(size=(p, k)))[0]
    J = rng.normal(size=(m, p)) @ (np.eye(p) - N0 @ N0.T)
    return J, N0


def test_named_directions_do_not_depend_on_which_scale_representative_is_given():
    """Scale plus another null direction is scale too: the named directions are the same for either (the
    directions orthogonal to the given one were not)."""
    J, N0 = _null_problem(np.random.default_rng(1))
    names = [f"c{i}" for i in range(J.shape[1])]
    d = N0 @ np.array([1.0, 0.2, -0.3, 0.1])
    other = N0 @ np.array([0.0, 0.1, 0.05, -0.2])
    a = analyse(J, names, scale=d)
    b = analyse(J, names, scale=d + other)
    assert a.scale_unidentifiable and b.scale_unidentifiable and len(a.directions) == 3
    assert [x.words for x in a.directions] == [x.words for x in b.directions]
    for x, y in zip(a.directions, b.directions):
        np.testing.assert_allclose(x.vector, y.vector, atol=1e-12)
    # each named direction is a row of the whole null space's echelon form; the scale stands for the fourth
    full = analyse(J, names)
    assert [x.words for x in a.directions] == [x.words for x in full.directions if x.pivot in
                                                {y.pivot for y in a.directions}]


def test_the_uncertainty_bounds_how_far_the_echelon_form_moves():
    """Turning a null basis by a small angle moves each coefficient by at most its ``_uncertainty`` (first order:
    within 10 % at an angle of 1e-5), and the bound is not vacuous (some coefficient moves by half of it)."""
    rng = np.random.default_rng(2)
    worst = 0.0
    for trial in range(20):
        p, k = 12, 4
        N = np.linalg.qr(rng.normal(size=(p, k)) * np.geomspace(1, 1e-2, p)[:, None])[0]  # ill-conditioned pivots
        order = list(rng.permutation(p))
        R = np.array(ident._rref(N.T, order))
        perp = np.linalg.qr(np.column_stack([N, rng.normal(size=(p, p - k))]))[0][:, k:]
        angle = 1e-5  # every bound above 1e-6: given (None only below)
        E = rng.normal(size=(p - k, k))
        moved = np.linalg.qr(N + perp @ (angle * E / np.linalg.norm(E, 2)))[0]
        R2 = np.array(ident._rref(moved.T, order))
        bound = ident._uncertainty(R, angle)
        assert np.all(np.abs(R2 - R) <= 1.1 * bound + 1e-14)
        worst = max(worst, float(np.max(np.abs(R2 - R) / bound)))
    assert worst > 0.5


def test_coefficients_are_printed_to_the_digits_they_hold():
    v = np.array([1.0, 0.123456, 0.0123])
    Nd = (v / np.linalg.norm(v))[:, None]
    names = ["a", "b", "c"]
    words = ident._directions(Nd, [0, 1, 2], names, None, "")[0].words
    assert words == "a cannot be identified: it trades off against b (+0.123), c (+0.0123)"
    assert ident._uncertainty(v[None, :], ident.NAMING_ACCURACY) is None  # every coefficient holds three digits
    # known to 1e-3: b's coefficient to two digits, c's (uncertainty 1e-3) to one
    words = ident._directions(Nd, [0, 1, 2], names, None, "", accuracy=1e-3)[0].words
    assert words == "a cannot be identified: it trades off against b (+0.12), c (+0.01)"
    # known to 2e-3: b's to one digit; c's within ten times its uncertainty, not claimed as a partner
    d = ident._directions(Nd, [0, 1, 2], names, None, "", accuracy=2e-3)[0]
    assert d.words == "a cannot be identified: it trades off against b (+0.1)" and [n for n, _ in d.partners] == ["b"]


def test_scale_pivot_is_the_last_of_the_pivots_the_scale_moves_much():
    """Of the pivots that the scale direction moves at least half as much as its largest, the last in order:
    two equal sizes (equal lengths) do not make it depend on round-off."""
    p = 6
    N = np.eye(p)[:, :3]  # pivots 0, 1, 2
    s = np.array([0.6, 0.6, 0.2, 0, 0, 0])
    assert ident._scale_pivot(N, s / np.linalg.norm(s), list(range(p))) == 1
    for tilt in (1e-9, -1e-9):
        t = s + np.array([tilt, -tilt, 0, 0, 0, 0])
        assert ident._scale_pivot(N, t / np.linalg.norm(t), list(range(p))) == 1
    assert ident._scale_pivot(N, s / np.linalg.norm(s), [1, 0, 2, 3, 4, 5]) == 0
    # an order without coordinate 2 gives no echelon form spanning N: none (the message names the directions
    # orthogonal to s instead)
    assert ident._scale_pivot(N, s / np.linalg.norm(s), [0, 1, 3, 4, 5]) is None
    kept, found, _ = ident._scale_message(N, s, [f"c{i}" for i in range(p)], False, [0, 1, 3, 4, 5])
    assert found and kept.shape == (p, 2) and np.allclose(kept.T @ s, 0.0)
