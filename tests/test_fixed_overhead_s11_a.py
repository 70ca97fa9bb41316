"""Session 11 (a): the rank analysis' structure read once per solve, bit for bit.

``symmetries.Structure`` (made by ``iterate`` at its first linearization: the free coordinates' names, whether a
length is free, the rotation candidates of ``rotation_nulls``, the start of ``structure_key``'s digest) gives at
every linearization what the tests without it give; it is used only for linearizations of its own problem.
``columns.scatter_columns`` remembers its per-block plan by the blocks and columns (emptied with the structure
cache) and scatters as before; ``linalg.norms`` is ``numpy.linalg.norm(x, axis=...)`` bit for bit."""

from __future__ import annotations

import importlib
from dataclasses import replace

import numpy as np
import pytest

from kincal import robots
from kincal.analysis import columns, identify, scatter_columns, symmetries
from kincal.analysis.linalg import norms
from kincal.estimation import Problem, calibrate, steps
from kincal.estimation.iterate import scale_test_needed
from kincal.noise import Noise
from kincal.params import Layout, build_layout
from kincal.simulate import generate_clamp, generate_socket
from kincal.workflow import study as S
from test_structure_cache import NOISE, _same, ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)

ITERATE = importlib.import_module("kincal.estimation.iterate")  # the module (the package exports the function)
STATED = Noise(position=1e-9, orientation=1e-9, joint=1e-5)


class _NoStructure:
    """Stands in for ``symmetries.Structure`` in ``iterate``: every linearization analysed without one."""

    @staticmethod
    def of(*args):
        return None


def _both(monkeypatch, run):
    """(``run()`` as shipped, ``run()`` with the symmetry tests reading everything at every linearization)."""
    symmetries.clear_structure_cache()
    shipped = run()
    symmetries.clear_structure_cache()
    with monkeypatch.context() as m:
        m.setattr(ITERATE, "Structure", _NoStructure)
        plain = run()
    return shipped, plain


def _socket_and_clamp():
    panda, frida = robots.load("panda"), robots.load("frida")
    socket = generate_socket(panda, n=30, rng=np.random.default_rng(1))[0]
    clamp = generate_clamp(frida, "right", n=30, rng=np.random.default_rng(2))[0]
    return (panda, socket), (frida, clamp)


def test_a_solve_with_its_structure_gives_what_one_without_gives(monkeypatch, ur10_sets):
    """UR10 markers (a tracker turning about the first axis, exact gauges), a socket (world-frame vectors that
    turn: ``_turned_residuals``), a clamp (the consistent linearization's gauges), with noise on the readings."""
    nominal, markers, pose = ur10_sets
    (panda, socket), (frida, clamp) = _socket_and_clamp()
    rng = np.random.default_rng(9)
    socket, clamp = (replace(ds, q={a: q + rng.normal(0, 1e-5, q.shape) for a, q in ds.q.items()})
                     for ds in (socket, clamp))
    runs = [lambda: calibrate(nominal, [markers], "kinematic", noise=NOISE),
            lambda: calibrate(nominal, [pose], "kinematic", noise=NOISE),
            lambda: calibrate(panda, [socket], "offsets", noise=STATED),
            lambda: calibrate(frida, [clamp], "offsets", noise=STATED)]
    for run in runs:
        shipped, plain = _both(monkeypatch, run)
        _same(shipped, plain)


def test_a_solve_holding_the_rigid_gauges_with_its_structure_gives_what_one_without_gives(monkeypatch):
    """The held gauges' basis and pinned rows, taken once per solve (``identifiability._held``): the sagging UR10
    of tests/test_slow_path.py (kinematic and elastic, weights: the rigid model's gauges held)."""
    from test_slow_path import _sagging_ur10
    from kincal.simulate.generators import generate_markers

    nominal, true, _ = _sagging_ur10()
    ds = generate_markers(true, n=20, rng=1, markers=3, noise=Noise(position=2e-5), known_tracker=True,
                          known_markers=True)[0]
    ident = importlib.import_module("kincal.analysis.identifiability")
    calls, real = [], ident.pivot_rows
    monkeypatch.setattr(ident, "pivot_rows", lambda *a: calls.append(1) or real(*a))
    shipped, plain = _both(monkeypatch, lambda: calibrate(nominal, [ds], ["kinematic", "elastic"], outliers="keep"))
    assert shipped.held is not None and shipped.iterations >= 2
    assert len(calls) == 1 + plain.iterations  # once in the solve with its structure, at every linearization without
    _same(shipped, plain)


def test_a_solve_reads_its_structure_once(monkeypatch, ur10_sets):
    """One ``Structure`` per solve, made at its first linearization and handed to every ``identify`` of it."""
    nominal, markers, _ = ur10_sets
    made, seen, real_of, real_identify = [], [], symmetries.Structure.of, ITERATE.identify
    monkeypatch.setattr(ITERATE.Structure, "of", classmethod(lambda cls, *a: made.append(real_of(*a)) or made[-1]))
    monkeypatch.setattr(ITERATE, "identify", lambda *a, **k: seen.append(k["structure"]) or real_identify(*a, **k))
    # every linearization analysed (no step carried between analyses: tests/test_carried_step.py counts those)
    monkeypatch.setattr(ITERATE, "_carried", lambda *a: None)
    res = calibrate(nominal, [markers], "kinematic", noise=NOISE)
    assert res.iterations >= 2 and len(made) == 1 and len(seen) == res.iterations
    assert all(s is made[0] for s in seen)


def test_table1_repeats_with_their_structure_give_what_ones_without_give(monkeypatch):
    s = S.load("table1")
    fixed = S.fixed_parts(s)
    for seed in range(2):
        ds = S.repeat_data(s, fixed.true, fixed, np.random.default_rng(seed))
        for v in s.variants:
            shipped, plain = _both(monkeypatch, lambda: S.calibrate_variant(s, v, ds))
            assert repr(shipped) == repr(plain)


def _first_linearization(robot, ds, level, noise):
    problem = Problem.build(robot, [ds], level, noise=noise)
    return problem, steps.linearize(problem, problem.start, None, scale_test_needed(problem))


def test_rotation_candidates_and_tests_equal_those_without_the_structure(ur10_sets):
    """The candidates are what ``rotation_nulls`` used to work out at every call (the socket's residuals turn,
    the tracker's do not), and the confirmed rotations, the scale test and the structure key are the same."""
    nominal, markers, _ = ur10_sets
    (panda, socket), _ = _socket_and_clamp()
    for (robot, ds, level, noise), turns in (((nominal, markers, "kinematic", NOISE), False),
                                             ((panda, socket, "offsets", STATED), True)):
        problem, lin = _first_linearization(robot, ds, level, noise)
        st = symmetries.Structure.of(lin, problem.layout, problem.experiments, 1e-9)
        assert [c[-1] for c in st.rotations] == [turns]
        assert st.names == tuple(problem.layout.names[i] for i in problem.free_idx)
        with_st = symmetries.rotation_nulls(lin, problem.layout, problem.experiments, st)
        without = symmetries.rotation_nulls(lin, problem.layout, problem.experiments)
        assert len(with_st) == len(without) == 1 and np.array_equal(with_st[0], without[0])
        assert symmetries.structure_key(lin, problem.layout, problem.experiments, 1e-9, st) == \
            symmetries.structure_key(lin, problem.layout, problem.experiments, 1e-9)
        for a, b in ((symmetries.scale_null(lin, problem.layout, st), symmetries.scale_null(lin, problem.layout)),):
            assert (a is None and b is None) or np.array_equal(a, b)


def test_a_structure_is_used_only_for_its_own_problem(ur10_sets):
    """Another problem's linearization (other free coordinates, other experiments) is not ``fit``: identify then
    analyses it as without a structure."""
    nominal, markers, pose = ur10_sets
    problem, lin = _first_linearization(nominal, markers, "kinematic", NOISE)
    other, lin2 = _first_linearization(nominal, pose, "offsets", NOISE)
    st = symmetries.Structure.of(lin, problem.layout, problem.experiments, 1e-9)
    assert st.fits(lin, problem.layout, problem.experiments, 1e-9)
    assert not st.fits(lin2, other.layout, other.experiments, 1e-9)
    assert not st.fits(lin, problem.layout, problem.experiments, 1e-8)  # another rank threshold: another key
    assert not st.fits(lin, problem.layout, list(other.experiments), 1e-9)
    a = identify(lin2, other.layout, other.experiments, report=False, structure=st)
    b = identify(lin2, other.layout, other.experiments, report=False)
    assert a.names == b.names and a.rank == b.rank and np.array_equal(a.range_space, b.range_space)


def _scatter_reference(blocks, layout: Layout, cols, shape, right=None) -> np.ndarray:
    """``scatter_columns`` as it was before its plan was remembered (session 10)."""
    col = np.full(layout.size, -1)
    col[cols] = np.arange(len(cols))
    J = np.zeros(tuple(shape) + (len(cols),))
    for b in layout.blocks:
        Jb = blocks.get(b.name)
        if Jb is None:
            continue
        if right is not None and b.name in right:
            Jb = Jb @ right[b.name]
        c = col[b.start: b.stop]
        sel = c >= 0
        if sel.any():
            J[..., c[sel]] = Jb[..., sel]
    return J


def test_scatter_columns_plans_give_the_columns_and_are_forgotten(ur10_sets):
    nominal, markers, _ = ur10_sets
    problem, _ = _first_linearization(nominal, markers, "kinematic", NOISE)
    layout, rng = problem.layout, np.random.default_rng(0)
    blocks = {b.name: rng.standard_normal((4, 3, b.stop - b.start)) for b in layout.blocks}
    right = {"tracker": rng.standard_normal((6, 6))}
    selections = [problem.free_idx, np.arange(layout.size), np.arange(0, layout.size, 3),
                  np.flatnonzero(~layout.free), np.zeros(0, int), problem.free_idx[::-1].copy()]
    for _ in range(2):  # planned, then remembered
        for cols in selections:
            for r in (None, right):
                assert np.array_equal(scatter_columns(blocks, layout, cols, (4, 3), r),
                                      _scatter_reference(blocks, layout, cols, (4, 3), r))
    assert columns._PLANS
    other = build_layout(problem.start, "offsets")  # the same names and blocks: the same plan is right
    assert np.array_equal(scatter_columns(blocks, other, selections[2], (4, 3)),
                          _scatter_reference(blocks, other, selections[2], (4, 3)))
    symmetries.clear_structure_cache()
    assert not columns._PLANS


@pytest.mark.parametrize("shape", [(7, 5), (45, 18), (3, 0), (0, 4), (53, 1)])
def test_norms_are_numpys_bit_for_bit(shape):
    x = np.random.default_rng(1).standard_normal(shape) * np.logspace(-8, 3, shape[1])
    for axis in (0, 1):
        assert np.array_equal(norms(x, axis), np.linalg.norm(x, axis=axis))
