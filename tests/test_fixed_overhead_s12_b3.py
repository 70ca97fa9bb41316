"""Session 12 round 3 (helper b3): fewer passes over the rows of a linearization.

``jacobians._twist_columns`` writes its product straight into the result's columns (no transposed copy),
``columns.scatter_columns`` skips the zeros when its blocks write every column, and ``Problem._stack`` returns a
single experiment's Jacobian without copying it; the joints' exponentials and adjoints add their identity in the
product of their coefficients (``Kinematics.unit_coefficients``). The same numbers bit for bit: compared with the code they
replace, kernel by kernel and through whole calibrations (markers, pose, clamp, dual arm, elastic).

An experiment's unloaded chain takes the sines of its joint values by the angle sum from its readings' own,
computed once (``Experiment._turns``, ``fk.shifted_turns``): round-off, so compared to 1e-10 relative."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.analysis import columns, scatter_columns
from kincal.estimation import calibrate
from kincal.estimation import problem as problem_module
from kincal.experiments import base as experiments_base
from kincal.kinematics import fk
from kincal.kinematics import jacobians as jac
from kincal.params import build_layout
from kincal.robots import load
from kincal.lie import se3
from test_fixed_overhead_s11_a import _scatter_reference  # zeros first, then every block's columns
from test_fixed_overhead_s12_b import _random_screws
from test_fixed_overhead_s12_b2 import _coefficients, _words
from test_fixed_overhead_s12_c import cases  # noqa: F401 (the structures: markers, pose, clamp, dual, elastic)


def _twist_reference(M, generators, step, N, k):
    """``_twist_columns`` before (session 12 round 2); joints of several widths went joint by joint, as now."""
    widths = {g.shape[1] for g in generators}
    if len(widths) > 1:
        return _TWIST_COLUMNS(M, generators, step, N, k)
    n, t = len(generators), widths.pop()
    D = M[0: step * n: step] - M[step: step * (n + 1): step]
    return (D @ np.array(generators)).reshape(n, N, k, t).transpose(1, 2, 0, 3).reshape(N, k, n * t)


_TWIST_COLUMNS = jac._twist_columns


@pytest.mark.parametrize("N", [1, 3, 50, 200, 1001])
@pytest.mark.parametrize("k", [1, 3, 6])
def test_twist_columns_are_the_transposed_product_bit_for_bit(N, k):
    rng = np.random.default_rng(N * 10 + k)
    for n, step, widths in ((6, 1, [4] * 6), (3, 3, [4, 4, 4]), (7, 1, [2] * 7), (4, 1, [4, 2, 4, 2])):
        M = rng.standard_normal((step * n + 1, N * k, 6)) * np.logspace(-3, 2, 6)
        M[:, : k, 2] = -0.0  # signed zeros go through as the product gives them
        gens = [rng.standard_normal((6, w)) for w in widths]
        got = jac._twist_columns(M, gens, step, N, k)
        want = _twist_reference(M, gens, step, N, k)
        assert got.shape == want.shape and got.flags.c_contiguous
        assert got.tobytes() == want.tobytes()


def test_scatter_columns_without_zeros_only_when_every_column_is_written():
    robot = load("ur10")
    from kincal.params import State
    state = State.from_robot(robot)
    layout = build_layout(state, "kinematic")
    rng = np.random.default_rng(0)
    blocks = {b.name: rng.standard_normal((5, 3, b.stop - b.start)) for b in layout.blocks}
    free = np.flatnonzero(layout.free)
    selections = [free, np.arange(layout.size), free[::-1].copy(), np.concatenate([free, free[:2]]),
                  np.zeros(0, int), np.arange(0, layout.size, 2)]
    some = dict(list(blocks.items())[1:])  # a block missing: its columns zero
    for _ in range(2):  # planned, then remembered
        for cols in selections:
            for b in (blocks, some):
                for right in (None, {layout.blocks[-1].name: se3.adjoint(se3.exp(rng.standard_normal(6)))}):
                    np.empty((5, 3, len(cols))).fill(np.nan)  # a reused buffer would show
                    got = scatter_columns(b, layout, cols, (5, 3), right)
                    assert got.tobytes() == _scatter_reference(b, layout, cols, (5, 3), right).tobytes()
    columns.clear_plans()


def test_whole_calibrations_are_the_replaced_code_bit_for_bit(cases, monkeypatch):  # noqa: F811
    for name, robot, data, free, noise in cases:
        new = calibrate(robot, data, free, noise=noise)
        with monkeypatch.context() as m:
            m.setattr(jac, "_twist_columns", _twist_reference)
            m.setattr(problem_module, "scatter_columns", _scatter_reference)
            m.setattr(problem_module, "_joined", lambda parts: np.concatenate(parts))
            old = calibrate(robot, data, free, noise=noise)
        assert new.status == old.status and tuple(new.messages) == tuple(old.messages), name
        assert new.identifiability.rank == old.identifiability.rank, name
        for a, b in zip(new.estimates, old.estimates, strict=True):
            assert a.name == b.name and a.identifiable == b.identifiable, name
            assert np.float64(a.value).tobytes() == np.float64(b.value).tobytes(), (name, a.name)
            assert np.float64(a.std).tobytes() == np.float64(b.std).tobytes(), (name, a.name)


@pytest.mark.parametrize("N", [1, 2, 7, 50, 200, 1000])
def test_unit_coefficients_add_the_identity_in_the_product_bit_for_bit(N):
    """``[a, b, 1] @ [X, X^2, I]`` (``sample_chain``, ``_sample_projections``) is ``(a X + b X^2) + I``, the sum
    they computed before (exact screws of both kinds, joints at zero, negative angles: signed zeros)."""
    rng = np.random.default_rng(N)
    for screws in (load("ur10")["arm"].screws, _random_screws(rng, 7)):
        theta = rng.uniform(-3.5, 3.5, (N, len(screws)))
        theta[:, 0] = 0.0
        theta[: N // 2, -1] = -0.0
        kin = fk.sample_chain(screws, theta, np.eye(4), np.eye(4), np.eye(4))
        assert kin.coefficients.shape == (len(screws), N, 2) and kin.unit_coefficients.shape == (len(screws), N, 3)
        assert (kin.unit_coefficients[..., 2] == 1.0).all()
        for basis, d in ((fk._HAT_BASIS, 4), (jac._AD_BASIS, 6)):
            before = kin.coefficients @ fk.powers(screws, basis) + np.eye(d).ravel()
            assert (kin.unit_coefficients @ fk.powers(screws, basis, unit=True)).tobytes() == before.tobytes()
            assert fk.powers(screws, basis, unit=True)[:, :2].tobytes() == fk.powers(screws, basis).tobytes()
        fresh = fk.Kinematics(kin.theta, kin.screws, kin.prefixes, kin.flange, kin.tool)
        assert fresh.unit_coefficients.tobytes() == kin.unit_coefficients.tobytes()


def _direct_turns(self, arm, offsets):
    """``Experiment._turns`` computed directly: the sines of the rounded ``q + offsets``."""
    theta = self.dataset.q[arm] + offsets
    return np.cos(theta), np.sin(theta)


def test_shifted_turns_are_the_sums_turns_to_round_off():
    rng = np.random.default_rng(2)
    q = rng.uniform(-7.0, 7.0, (500, 6))
    q[:7] = [0.0, -0.0, np.pi, -np.pi / 2, 1e-300, 3.0]
    for offsets in (rng.normal(0, 0.01, 6), rng.uniform(-4, 4, 6), np.zeros(6)):
        c, s = fk.shifted_turns(np.cos(q), np.sin(q), offsets)
        np.testing.assert_allclose(c, np.cos(q + offsets), rtol=0, atol=1.5e-15)
        np.testing.assert_allclose(s, np.sin(q + offsets), rtol=0, atol=1.5e-15)
    c, s = fk.shifted_turns(np.cos(q), np.sin(q), np.zeros(6))  # no offset: the readings' own, bit for bit
    assert c.tobytes() == np.cos(q).tobytes() and np.array_equal(s, np.sin(q))


def test_readings_turns_are_kept_by_their_bytes(cases):  # noqa: F811
    _, robot, data, _, _ = cases[0]
    from kincal.experiments import build as build_experiments
    from kincal.params import State
    (exp,), _, _ = build_experiments(data, State.from_robot(robot))
    arm = exp.arms[0]
    offsets = np.linspace(-0.01, 0.01, 6)
    got = exp._turns(arm, offsets)
    assert all(np.allclose(a, b, rtol=0, atol=1.5e-15) for a, b in zip(got, _direct_turns(exp, arm, offsets)))
    assert not exp.dataset.q[arm].flags.writeable  # checked readings do not change in place
    stale = np.zeros_like(got[0])
    exp.__dict__["_reading_turns"][arm] = (b"other readings", stale, stale)  # kept for other bytes: a miss
    assert all(np.array_equal(a, b) for a, b in zip(exp._turns(arm, offsets), got))


def test_whole_calibrations_with_shifted_turns_agree_to_round_off(cases, monkeypatch):  # noqa: F811
    """Rank, status, messages the same; estimates and std within 1e-10 relative (the dual arm's null-direction
    coefficients are round-off's, ``test_fixed_overhead_s12_b2``: the same words there)."""
    for name, robot, data, free, noise in cases:
        new = calibrate(robot, data, free, noise=noise)
        with monkeypatch.context() as m:
            m.setattr(experiments_base.Experiment, "_turns", _direct_turns)
            old = calibrate(robot, data, free, noise=noise)
        assert new.status == old.status and new.identifiability.rank == old.identifiability.rank, name
        if name == "dual":  # the same words; the coefficients of its null directions are round-off's
            assert [_words(x) for x in new.messages] == [_words(x) for x in old.messages]
            for x, y in zip(new.messages, old.messages):
                np.testing.assert_allclose(_coefficients(x), _coefficients(y), rtol=0.2)
        else:
            assert tuple(new.messages) == tuple(old.messages), name
        for a, b in zip(new.estimates, old.estimates, strict=True):
            assert a.name == b.name and a.identifiable == b.identifiable, name
            scale = max(abs(a.value), abs(b.value), abs(b.std) if a.identifiable else 1.0)
            assert abs(a.value - b.value) <= 1e-10 * scale, (name, a.name, a.value, b.value)
            assert abs(a.std - b.std) <= 1e-10 * abs(b.std) if np.isfinite(b.std) else not np.isfinite(a.std)
