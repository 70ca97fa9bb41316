"""Session 13 (c): the identifiability report prints only what the data determine.

The named null directions are the echelon form of the null directions orthogonal to the solver's scale direction.
That direction was ``s + u`` with u numpy's minimum-norm solve (``symmetries.scale_null``), whose cut at eps kept
null singular values near 1e-13 in a dual arm: round-off added other null directions to it (3e-4 under one-ulp
changes of the joint readings), and the named directions moved with it (coefficients by up to 28 %). The solve
is now cut at the rank of the analysis' own spectrum (``identifiability._scale_at_rank``, ``_minimum_norm``), and
each coefficient is printed to the digits its uncertainty leaves (``_uncertainty``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from kincal import robots
from kincal.analysis import analyse
from kincal.analysis import identifiability as ident
from kincal.analysis.linalg import lstsq
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
    ulp either way (before: 32 of 33 messages changed, coefficients by up to 28 %), the scale message's too."""
    frida, truth = frida_truth
    dual = generate_dual(truth, n=25, rng=seed, known_clamp=False)[0]
    ref = calibrate(frida, [dual], "kinematic")
    assert ref.identifiability.scale_unidentifiable and len(ref.identifiability.directions) == 32
    for up in (True, False):
        res = calibrate(frida, [_ulp(dual, up)], "kinematic")
        assert _named(res) == _named(ref)
        assert res.messages == ref.messages


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


def _scales(monkeypatch) -> list:
    """Per analysis with the scale test's solve from here on: (the scale direction the report reads, numpy's
    ``s + lstsq(Rf, b)``, whether numpy's default cut-off cuts every singular value of Rf below the rank)."""
    seen, at_rank, minimum = [], ident._scale_at_rank, ident._minimum_norm

    def scale_at_rank(scale, J, sv):
        d, u = at_rank(scale, J, sv)
        if u is not None:
            S = np.linalg.svd(J, compute_uv=False)
            cut = int(np.count_nonzero(S > np.finfo(float).eps * max(J.shape) * S[0])) == sv.rank
            seen.append([None, scale(lstsq), cut])
        return d, u

    def minimum_norm(d, u, N0):
        seen[-1][0] = minimum(d, u, N0)
        return seen[-1][0]

    monkeypatch.setattr(ident, "_scale_at_rank", scale_at_rank)
    monkeypatch.setattr(ident, "_minimum_norm", minimum_norm)
    return seen


def _unit(v):
    return v / np.linalg.norm(v)


def test_the_scale_direction_survives_one_ulp_of_every_joint_reading(frida_truth, monkeypatch):
    """The dual arm's scale direction at the report moves by round-off only (numpy's by 3e-4) when every joint
    reading moves by one ulp."""
    frida, truth = frida_truth
    dual = generate_dual(truth, n=25, rng=3, known_clamp=False)[0]
    runs = []
    for data in (dual, _ulp(dual, True), _ulp(dual, False)):
        seen = _scales(monkeypatch)
        calibrate(frida, [data], "kinematic")
        assert seen and seen[-1][0] is not None
        runs.append(seen[-1])
    for other in runs[1:]:
        assert np.linalg.norm(_unit(other[0]) - _unit(runs[0][0])) < 1e-9
    # numpy's moved by far more: what the cut removes
    assert max(np.linalg.norm(_unit(o[1]) - _unit(runs[0][1])) for o in runs[1:]) > 1e-6


def test_the_scale_direction_is_numpys_where_its_cut_off_cuts_the_null_space(frida_truth, monkeypatch):
    """Where numpy's default cut-off already cuts every singular value below the rank (a single arm on a clamp),
    the scale direction is numpy's minimum-norm one, to round-off."""
    frida, truth = frida_truth
    clamp = generate_clamp(truth, "right", n=25, rng=1, known_fixture=False)[0]
    seen = _scales(monkeypatch)
    calibrate(frida, [clamp], "kinematic")
    cut = [(d, d_lstsq) for d, d_lstsq, c in seen if c]
    assert cut
    for d, d_lstsq in cut:
        np.testing.assert_allclose(d, d_lstsq, rtol=0, atol=1e-9 * np.linalg.norm(d_lstsq))


def test_the_scale_solve_is_cut_at_the_rank_only_where_the_spectrum_is_the_matrix_own():
    """A solve of another matrix than the analysed one, or of a spectrum without U (a tall J), is numpy's."""
    rng = np.random.default_rng(4)
    J, N0 = _null_problem(rng, m=30)
    b = J @ rng.normal(size=J.shape[1])
    s = N0[:, 0]
    sv = ident._spectrum(J, 1e-9)  # tall: no U
    d, u = ident._scale_at_rank(lambda solve: s + solve(J, b), J, sv)
    assert u is None and np.array_equal(d, s + lstsq(J, b))
    R = np.linalg.qr(J, mode="r")
    sv = ident._spectrum(R, 1e-9)
    assert sv.U is not None
    d, u = ident._scale_at_rank(lambda solve: s + solve(R.copy(), b[:10]), R, sv)
    assert u is None and np.array_equal(d, s + lstsq(R, b[:10]))
    d, u = ident._scale_at_rank(lambda solve: s + solve(R, b[:10]), R, sv)
    x = np.linalg.pinv(R, rcond=1e-9) @ b[:10]  # same min-norm where the columns are of one size
    assert u is not None and np.allclose(R @ u, R @ x)


def test_whole_calibrations_are_numpys_solve_but_for_the_words_it_left_to_round_off(cases, monkeypatch):  # noqa: F811
    """Markers, pose, clamp, dual arm, elastic: the same rank, status, estimates and std (1e-10 relative) as with
    numpy's solve for the scale direction, and the same messages except the dual arm's null directions (which
    numpy's round-off decided: the test above)."""
    for name, robot, data, free, noise in cases:
        res = calibrate(robot, data, free, noise=noise)
        with monkeypatch.context() as m:
            m.setattr(ident, "_scale_at_rank", lambda scale, J, sv: (scale(lstsq), None))
            ref = calibrate(robot, data, free, noise=noise)
        assert (res.status, res.identifiability.rank) == (ref.status, ref.identifiability.rank), name
        if name != "dual":
            assert res.messages == ref.messages, name
        else:
            assert res.identifiability.scale_unidentifiable and len(res.messages) == len(ref.messages)
        np.testing.assert_allclose([e.value for e in res.estimates], [e.value for e in ref.estimates],
                                   rtol=1e-10, atol=1e-12, err_msg=name)
        np.testing.assert_allclose([e.std for e in res.estimates], [e.std for e in ref.estimates],
                                   rtol=1e-10, atol=1e-15, equal_nan=True, err_msg=name)
