"""Session 12 (a): the rank analysis at every linearization with fewer numpy calls, bit for bit.

``linalg.complete_q`` is numpy's complete Q; ``unit_columns`` with the known column norms is the one without;
``_weak_limit`` on Python floats and ``_weak_indices``' early answer are the numpy forms; ``rotation_nulls`` with its
structure (the non-free coordinates a rotation moves found once, the base's adjoint remembered by its values) is
the one without; ``_key_start``'s remembered digest is the fresh one and a changed input misses; the scale test's
terms are kept for ``scale_visible`` only for the same linearization; ``priority`` and ``degenerate`` are their
earlier forms. And whole solves on several structures with every fast path swapped for its earlier form give the
same Result bit for bit."""

from __future__ import annotations

import importlib
import weakref
from dataclasses import replace

import numpy as np
import pytest

from kincal import robots
from kincal.analysis import symmetries
from kincal.analysis import identifiability as ident
from kincal.analysis.covariance import right_svd
from kincal.analysis.linalg import complete_q, norms, thin_svd
from kincal.analysis.linearization import ZERO_COLUMN_RTOL, unit_columns
from kincal.analysis.naming import blocks_of, degenerate
from kincal.estimation import Problem, calibrate, steps
from kincal.estimation.gauge import priority
from kincal.estimation.iterate import scale_test_needed
from kincal.lie import se3
from kincal.noise import Noise
from kincal.simulate import generate_clamp, generate_dual, generate_socket
from test_structure_cache import NOISE, _same, ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)

ITERATE = importlib.import_module("kincal.estimation.iterate")
STATED = Noise(position=1e-9, orientation=1e-9, joint=1e-5)


# ------------------------------------------------------------------------------------------- earlier forms


def _unit_columns_before(J):
    c = np.linalg.norm(J, axis=0)
    zero = c <= ZERO_COLUMN_RTOL * (c.max() if c.size else 0.0)
    c = np.where(zero, 1.0, c)
    Js = J / c
    Js[:, zero] = 0.0
    return Js, c


def _weak_limit_before(s, weak_rtol):
    if len(s) < 2 or s[0] <= 0:
        return weak_rtol
    rel = s / s[0]
    ratios = rel[:-1] / np.maximum(rel[1:], 1e-300)
    gaps = np.flatnonzero((ratios > ident.WEAK_GAP) & (rel[1:] < 1e-3))
    return max(weak_rtol, float(rel[gaps[0] + 1]) * (1 + 1e-12)) if len(gaps) else weak_rtol


def _weak_indices_before(sv, rank, rtol, weak_rtol, lifted):
    S, smax = sv.S, sv.smax
    weak_idx = np.flatnonzero((S > rtol * smax) & (S < _weak_limit_before(S[:rank], weak_rtol) * smax))
    if lifted:
        weak_idx = np.array([i for i in weak_idx if max(abs(sv.Vt[i] @ h) for h in lifted) < 0.5], dtype=int)
    return weak_idx


def _priority_before(problem):
    layout = problem.layout
    blk = blocks_of(layout, problem.free_idx)
    return sorted(range(len(problem.free_idx)), key=lambda k: (blk[k].kind.rank, k))


def _degenerate_before(Rf, rank, rtol, layout, free):
    if rank == 0:
        return True
    arm = np.array([b.arm is not None for b in blocks_of(layout, free)], bool)
    if not arm.any() or arm.all() or np.count_nonzero(~arm) < rank:
        return False
    Js = _unit_columns_before(Rf)[0]
    s_all = right_svd(Js)[0]
    s_frames = right_svd(Js[:, ~arm])[0]
    tol = rtol * s_all[0]
    return int(np.sum(s_frames > tol)) >= int(np.sum(s_all > tol))


# ----------------------------------------------------------------------------------------------- pieces


@pytest.mark.parametrize("shape", [(45, 18), (45, 1), (10, 9), (7, 3), (6, 6), (4, 7)])
def test_complete_q_is_numpys(shape):
    rng = np.random.default_rng(shape[0] * 100 + shape[1])
    A = rng.normal(size=shape)
    if shape[1] > 2:
        A[:, 2] = A[:, 0] - 3 * A[:, 1]  # a dependent column
    before = A.copy()
    assert complete_q(A).tobytes() == np.linalg.qr(A, mode="complete")[0].tobytes()
    assert np.array_equal(A, before)  # the input is not overwritten
    F = np.asfortranarray(A)  # a transposed view's layout, as ``_null_and_range`` is given
    assert complete_q(F).tobytes() == np.linalg.qr(F, mode="complete")[0].tobytes()


def test_unit_columns_with_known_norms_are_the_ones_without(ur10_sets):
    nominal, markers, _ = ur10_sets
    problem = Problem.build(nominal, [markers], "kinematic", noise=NOISE)
    lin = steps.linearize(problem, problem.start, None, True)
    assert not lin.colnorm.flags.writeable  # shared as the analysis' column scale
    for J, c in ((lin.Rf, lin.colnorm), (lin.Rf, None)):
        Js, cs = unit_columns(J, c)
        ref_Js, ref_c = _unit_columns_before(J)
        assert Js.tobytes() == ref_Js.tobytes() and cs.tobytes() == ref_c.tobytes()
    Z = lin.Rf.copy()
    Z[:, [3, 7]] = 0.0  # zero columns: scale 1, left exactly zero, the known norms not written
    cz = norms(Z, 0)
    kept = cz.copy()
    Js, cs = unit_columns(Z, cz)
    ref_Js, ref_c = _unit_columns_before(Z)
    assert Js.tobytes() == ref_Js.tobytes() and cs.tobytes() == ref_c.tobytes() and np.array_equal(cz, kept)
    assert cs[3] == 1.0 and not Js[:, 3].any()


def _spectra():
    rng = np.random.default_rng(3)
    out = [np.array([1.0]), np.array([0.0, 0.0]), np.array([2.0, 1.0, 0.5])]
    for _ in range(200):
        low = -14 if rng.random() < 0.7 else -3.2  # some well conditioned (no gap possible: the early answer)
        s = np.sort(10.0 ** rng.uniform(low, 0, size=rng.integers(2, 30)))[::-1]
        if rng.random() < 0.5:  # a gap of more than WEAK_GAP below 1e-3
            k = rng.integers(1, len(s))
            s[k:] *= 10.0 ** rng.uniform(-6, -2)
        out.append(s)
    return out


def test_weak_limit_and_indices_are_the_numpy_forms():
    weak = 0
    for s in _spectra():
        for weak_rtol in (1e-5, 1e-9):
            assert ident._weak_limit(s, weak_rtol) == _weak_limit_before(s, weak_rtol)
        S = np.concatenate([s, np.zeros(3)])
        smax = S[0]
        rank = int(np.count_nonzero(S > 1e-9 * smax)) if smax > 0 else 0
        sv = ident._Spectrum(S, np.eye(len(S)), np.ones(len(S)), smax, rank)
        for r in {rank, max(rank - 1, 0)}:
            got, ref = ident._weak_indices(sv, r, 1e-9, 1e-5, []), _weak_indices_before(sv, r, 1e-9, 1e-5, [])
            assert np.array_equal(got, ref) and got.dtype == ref.dtype
            weak += len(ref) > 0
    assert weak > 20  # the spectra have weak directions, the early answer is not the only one taken


def _first_linearization(robot, ds, level, noise):
    problem = Problem.build(robot, [ds], level, noise=noise)
    return problem, steps.linearize(problem, problem.start, None, scale_test_needed(problem))


def _socket():
    panda = robots.load("panda")
    return panda, generate_socket(panda, n=30, rng=np.random.default_rng(1))[0]


def test_rotation_nulls_with_remembered_adjoint_are_the_ones_without(ur10_sets):
    nominal, markers, _ = ur10_sets
    panda, socket = _socket()
    for robot, ds, level, noise in ((nominal, markers, "kinematic", NOISE), (panda, socket, "offsets", STATED)):
        problem, lin = _first_linearization(robot, ds, level, noise)
        st = symmetries.Structure.of(lin, problem.layout, problem.experiments, 1e-9)
        for _ in range(2):  # computed, then remembered
            a = symmetries.rotation_nulls(lin, problem.layout, problem.experiments, st)
            b = symmetries.rotation_nulls(lin, problem.layout, problem.experiments)
            assert len(a) == len(b) == 1 and a[0].tobytes() == b[0].tobytes()
        arm = st.rotations[0][0]
        base = lin.state.arms[arm].base
        assert se3.remembered(se3.adjoint, base).tobytes() == se3.adjoint(base).tobytes()
        moved = base.copy()
        moved[0, 3] += 1e-3  # another base: another key, never the remembered adjoint
        assert se3.remembered(se3.adjoint, moved).tobytes() == se3.adjoint(moved).tobytes()
        assert not np.array_equal(se3.adjoint(moved), se3.adjoint(base))


def test_rotation_candidates_name_the_moved_coordinates_that_are_not_free(ur10_sets):
    nominal, markers, _ = ur10_sets
    problem, lin = _first_linearization(nominal, markers, "kinematic", NOISE)
    layout = problem.layout
    (arm, i1, frames, outside, turns), = symmetries._rotation_candidates(lin.state, layout, problem.experiments,
                                                                           lin.free)
    assert len(outside) == 0
    b = frames[0][1]
    fewer = np.setdiff1d(lin.free, [b.start + 1])  # one tracker coordinate held: the rotation moves it
    (_, _, _, outside, _), = symmetries._rotation_candidates(lin.state, layout, problem.experiments, fewer)
    assert outside.tolist() == [b.start + 1]


def test_key_start_remembered_is_the_fresh_digest_and_a_change_misses(ur10_sets):
    import hashlib

    nominal, markers, _ = ur10_sets
    problem, lin = _first_linearization(nominal, markers, "kinematic", NOISE)
    layout = problem.layout

    def fresh(free, rtol):
        h = hashlib.blake2b(digest_size=20)
        h.update(repr((layout.names, free.tolist(), rtol)).encode())
        return h.digest()

    symmetries.clear_structure_cache()
    for free, rtol in ((lin.free, 1e-9), (lin.free, 1e-9), (lin.free[1:], 1e-9), (lin.free, 1e-8),
                       (lin.free, np.float64(1e-9)), (lin.free.astype(np.int32), 1e-9)):
        h = symmetries._key_start(layout, free, rtol)
        assert h.digest() == fresh(free, rtol)
        h.update(b"completed by the caller")  # a copy: the remembered digest stays as it was
    assert symmetries._key_start(layout, lin.free, 1e-9).digest() == fresh(lin.free, 1e-9)
    assert len(symmetries._KEY_STARTS) == 5  # int32 indices and a numpy rtol are keys of their own
    symmetries.clear_structure_cache()
    assert not symmetries._KEY_STARTS


def test_scale_terms_are_kept_for_the_same_linearization_only(ur10_sets):
    nominal, markers, _ = ur10_sets
    problem, lin = _first_linearization(nominal, markers, "kinematic", NOISE)
    layout = problem.layout
    st = symmetries.Structure.of(lin, layout, problem.experiments, 1e-9)
    a = symmetries.scale_null(lin, layout, st)
    b = symmetries.scale_null(lin, layout)
    assert (a is None and b is None) or a.tobytes() == b.tobytes()
    assert symmetries.scale_visible(lin, layout, st) == symmetries.scale_visible(lin, layout)
    kept = st.derived["scale gap"]
    assert kept[0]() is lin  # held weakly since session 13: the Structure outlives the solve's linearizations
    moved = replace(lin, R=lin.R * 2.0)  # another linearization: its own terms, not the kept ones
    assert symmetries._scale_gap(moved, layout, st)[0] == symmetries._scale_terms(moved, layout)[0] != kept[2][0]
    gone = weakref.ref(moved)
    del moved
    assert gone() is None  # the memo does not keep a linearization (its residuals, whiteners) alive


def test_priority_and_degenerate_are_their_earlier_forms(ur10_sets):
    nominal, markers, pose = ur10_sets
    panda, socket = _socket()
    cases = ((nominal, markers, "kinematic", NOISE), (nominal, pose, "offsets", NOISE),
             (panda, socket, "offsets", STATED))
    for robot, ds, level, noise in cases:
        problem, lin = _first_linearization(robot, ds, level, noise)
        assert priority(problem, "min-change") == _priority_before(problem)
        for rank in (0, 1, 3, 9, 12, 27, lin.p):
            assert degenerate(lin.Rf, rank, 1e-9, problem.layout, lin.free) == \
                _degenerate_before(lin.Rf, rank, 1e-9, problem.layout, lin.free)


# ------------------------------------------------------------------------------------------ whole solves


def _earlier_forms(m):
    """Every fast path of this session swapped for its earlier form."""
    m.setattr(ident, "complete_q", lambda a, overwrite=False: np.linalg.qr(a, mode="complete")[0])
    m.setattr(ident, "thin_svd", lambda a: tuple(np.linalg.svd(a, full_matrices=False)))
    m.setattr(ident, "unit_columns", lambda J, c=None: _unit_columns_before(J))
    m.setattr(ident, "_weak_limit", _weak_limit_before)
    m.setattr(ident, "_weak_indices", _weak_indices_before)
    m.setattr(symmetries.se3, "remembered", lambda fn, T: fn(T))
    m.setattr(symmetries, "_scale_gap", lambda lin, layout, structure=None: symmetries._scale_terms(lin, layout))
    m.setattr(ITERATE, "priority", lambda problem, gauge: _priority_before(problem))


def _cases(ur10_sets):
    nominal, markers, pose = ur10_sets
    panda, socket = _socket()
    frida = robots.load("frida")
    clamp = generate_clamp(frida, "right", n=30, rng=np.random.default_rng(2))[0]
    rng = np.random.default_rng(9)
    socket, clamp = (replace(ds, q={a: q + rng.normal(0, 1e-5, q.shape) for a, q in ds.q.items()})
                     for ds in (socket, clamp))
    dual = generate_dual(frida, n=30, rng=0, noise=Noise(joint=1e-5), known_clamp=False)[0]
    return {"markers": lambda: calibrate(nominal, [markers], "kinematic", noise=NOISE),
            "pose": lambda: calibrate(nominal, [pose], "kinematic", noise=NOISE),
            "socket": lambda: calibrate(panda, [socket], "offsets", noise=STATED),
            "clamp": lambda: calibrate(frida, [clamp], "offsets", noise=STATED),
            "dual": lambda: calibrate(frida, [dual], "offsets", noise=Noise(joint=1e-5))}


@pytest.mark.parametrize("case", ["markers", "pose", "socket", "clamp", "dual"])
def test_solves_with_the_fast_paths_give_what_the_earlier_forms_give(monkeypatch, ur10_sets, case):
    run = _cases(ur10_sets)[case]
    for _ in range(2):  # the structure cold, then seen before
        shipped = run()
        with monkeypatch.context() as m:
            _earlier_forms(m)
            plain = run()
        _same(shipped, plain)


def test_an_elastic_solve_holding_gauges_with_the_fast_paths_gives_what_the_earlier_forms_give(monkeypatch):
    from test_slow_path import _sagging_ur10
    from kincal.simulate.generators import generate_markers

    nominal, true, _ = _sagging_ur10()
    ds = generate_markers(true, n=20, rng=1, markers=3, noise=Noise(position=2e-5), known_tracker=True,
                          known_markers=True)[0]
    run = lambda: calibrate(nominal, [ds], ["kinematic", "elastic"], outliers="keep")  # noqa: E731
    shipped = run()
    with monkeypatch.context() as m:
        _earlier_forms(m)
        plain = run()
    assert shipped.held is not None
    _same(shipped, plain)


def test_complete_q_on_scratch_is_numpys():
    A = np.random.default_rng(4).normal(size=(45, 18))
    ref = np.linalg.qr(A, mode="complete")[0]
    assert complete_q(A.copy(), overwrite=True).tobytes() == ref.tobytes()
    assert complete_q(np.asfortranarray(A), overwrite=True).tobytes() == ref.tobytes()
    low = A.astype(np.float32)  # another dtype: numpy's own call
    assert complete_q(low, overwrite=True).tobytes() == np.linalg.qr(low, mode="complete")[0].tobytes()


@pytest.mark.parametrize("shape", [(45, 45), (53, 45), (10, 4), (3, 1)])
def test_thin_svd_is_numpys(shape, monkeypatch):
    rng = np.random.default_rng(shape[0] + 7 * shape[1])
    A = rng.normal(size=shape)
    A[:, -1] = A[:, 0]  # rank deficient
    for a in (A, np.asfortranarray(A), A[::-1]):
        got, ref = thin_svd(a), np.linalg.svd(a, full_matrices=False)
        assert type(got) is tuple and all(x.tobytes() == y.tobytes() for x, y in zip(got, ref))
    assert all(x.dtype == y.dtype for x, y in zip(thin_svd(A.astype(np.float32)),
                                                  np.linalg.svd(A.astype(np.float32), full_matrices=False)))
    linalg = importlib.import_module("kincal.analysis.linalg")

    class Failing:  # a gesdd that does not converge: ``svd``'s fallback answers
        @staticmethod
        def svd_s(a, signature):
            raise np.linalg.LinAlgError("SVD did not converge")

    fallback = []
    monkeypatch.setattr(linalg, "_kernels", Failing)
    monkeypatch.setattr(linalg, "svd", lambda a, full_matrices=True: fallback.append(1) or np.linalg.svd(a, False))
    got = thin_svd(A)
    assert fallback and all(x.tobytes() == y.tobytes() for x, y in zip(got, np.linalg.svd(A, full_matrices=False)))
