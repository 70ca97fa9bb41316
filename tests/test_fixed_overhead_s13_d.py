"""Session 13 (d): a calibration's per-linearization and per-trial work with fewer Python/numpy calls, bit for bit.

``base._same_values`` reads each values class's compared fields once (``_compared_fields``) and skips the fields
a retraction kept (the same objects): the ``dataclasses.fields`` form's verdict, on every field moved by one bit
and on the tangent fields; ``tangent_frames`` joins the joints' floats by ``list``'s extend; ``point_jacobian``
takes its entries from the point, its negation and constants in one ``take``; a whitener made from a stated
diagonal remembers that diagonal (``ResidualCache.made``) as ``_constant_diagonal`` reads it off the whitener;
``Problem.evaluate`` of a trial point (no step) builds no full step. Each is its earlier form's numbers bit for bit,
and whole calibrations (markers, pose, socket, clamp, dual arm, elastic) with every one swapped for its earlier form
give the same Result bit for bit."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import pytest

from kincal.analysis import prediction
from kincal.estimation import problem as P
from kincal.experiments import _kernel, base, camera, distance, markers, plane, socket
from kincal.kinematics import fk, twists
from kincal.lie import se3, so3
from kincal.params import kinds, values
from test_fixed_overhead_s12_a import _cases
from test_fixed_overhead_s12_a2 import _elastic
from test_remembered_kinematics import _delta, _markers_problem, _tree_problem
from test_structure_cache import _same, ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)


# ------------------------------------------------------------------------------------------- earlier forms


def _same_values_before(a, b) -> bool:
    return all(base.same_bits(getattr(a, f.name), getattr(b, f.name)) for f in fields(a)
               if f.name not in base._TANGENT_FIELDS)


def _tangent_frames_before(screws, joint_types):
    xi = np.asarray(screws, dtype=float)
    if len(xi) <= twists._FEW and all(t == twists.REVOLUTE for t in joint_types):
        BG = np.array([c for x in xi.tolist() for c in twists._revolute_frame(x[:3], x[3:])]).reshape(len(xi), 2, 6, 4)
        return tuple(BG[:, 0]), tuple(BG[:, 1])
    return _TANGENT_FRAMES(screws, joint_types)


_TANGENT_FRAMES = twists.tangent_frames


def _point_jacobian_before(p):
    p = np.asarray(p, dtype=float)
    out = np.zeros(p.shape[:-1] + (3, 6))
    out[..., :3, :3] = np.eye(3)
    out[..., :3, 3:] = -so3.hat(p)
    return out


def _made_before(self, W, diagonal=None):
    d = P._constant_diagonal(W)
    if d is not None:
        d.flags.writeable = False
    P.remember(self.diagonals, id(W), (W, d), P.DIAGONAL_ENTRIES)


def _evaluate_before(self, state0, delta_free, whiteners, jac=True):
    delta = self.full_delta(delta_free)
    state = P.retract(state0, self.layout, delta, tangents=jac) if delta_free.any() else state0
    if not jac:
        return self._stack(state, self._residuals(state, False), whiteners, None, {})[0], None
    Rl = {k: v for k, v in P.pose_retraction_jacobians(self.layout, delta).items() if k in self.want}
    res = [exp.residual(state, want=self.want, jq=False) for exp in self.experiments]
    return self._stack(state, res, whiteners, self.free_idx, Rl)


def _few_exps_before(xi, t):
    a, b, c3 = se3.exp_coeffs(t)
    out = []
    for (v0, v1, v2, x, y, z), ak, bk, ck, c in zip(xi.tolist(), a, b, c3, np.cos(t).tolist()):
        wv = so3.cross_tuple((x, y, z), (v0, v1, v2))
        wwv = so3.cross_tuple((x, y, z), wv)
        bxy, bxz, byz = bk * x * y, bk * x * z, bk * y * z
        out += [c + bk * x * x, bxy - ak * z, bxz + ak * y, v0 + bk * wv[0] + ck * wwv[0],
                bxy + ak * z, c + bk * y * y, byz - ak * x, v1 + bk * wv[1] + ck * wwv[1],
                bxz - ak * y, byz + ak * x, c + bk * z * z, v2 + bk * wv[2] + ck * wwv[2], 0.0, 0.0, 0.0, 1.0]
    return np.array(out).reshape(len(xi), 4, 4)


def _parts_before(self, arm, want):
    return tuple(p for p in _kernel.ARM_PARTS if want is None or f"{arm}.{p}" in want)


def _arm_jacobians_before(a, kin, G, parts=_kernel.ARM_PARTS, with_jq=True, q=None):
    basis = None if q is None else a.compliance_basis(q)
    return _kernel.tool_jacobians(kin, G, a.screws, a.generators, a.joint_compliance, parts, with_jq, basis)


def _turns_before(self, arm, offsets):
    q = self.dataset.q[arm]
    return _shifted_turns_before(np.cos(q), np.sin(q), offsets)


def _shifted_turns_before(cos, sin, offsets):
    co, so = np.cos(offsets), np.sin(offsets)
    return cos * co - sin * so, sin * co + cos * so


def _earlier_forms(m):
    m.setattr(se3, "_few_exps", _few_exps_before)
    m.setattr(base.Experiment, "_parts", _parts_before)
    m.setattr(base, "arm_jacobians", _arm_jacobians_before)
    m.setattr(base.Experiment, "_turns", _turns_before)
    m.setattr(base, "_same_values", _same_values_before)
    for module in (twists, kinds, values):
        m.setattr(module, "tangent_frames", _tangent_frames_before)
    for module in (markers, plane, camera, socket, distance, prediction):
        m.setattr(module, "point_jacobian", _point_jacobian_before)
    m.setattr(P.ResidualCache, "made", _made_before)
    m.setattr(P.Problem, "evaluate", _evaluate_before)


# ------------------------------------------------------------------------------------------- pieces


def _arm(problem):
    return next(iter(problem.start.arms.values()))


@pytest.mark.parametrize("case", ["markers", "tree lateral"])
def test_same_values_is_the_fields_form_on_every_field(case):
    problem = _markers_problem() if case == "markers" else _tree_problem(True)
    a = _arm(problem)
    copy = a.__class__(**{k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in
                          ((f.name, getattr(a, f.name)) for f in fields(a))})
    assert base._same_values(a, a) and base._same_values(a, copy) == _same_values_before(a, copy) is True
    for f in fields(a):
        v = getattr(a, f.name)
        if isinstance(v, np.ndarray) and v.size:
            moved = v.copy()
            moved.flat[-1] = np.nextafter(moved.flat[-1], np.inf)  # one bit
        elif isinstance(v, tuple) and v and isinstance(v[0], np.ndarray):
            moved = (v[0] + 1.0,) + v[1:]
        else:
            continue
        other = a.__class__(**{**a.__dict__, f.name: moved})
        want = _same_values_before(a, other)
        assert base._same_values(a, other) == want
        assert want == (f.name in base._TANGENT_FIELDS), f.name


def test_compared_fields_are_read_per_class():
    @dataclass(frozen=True)
    class Other:
        x: np.ndarray
        bases: tuple = ()

    a, b = Other(np.zeros(2), (np.ones(1),)), Other(np.zeros(2), ())
    assert base._compared_fields(Other) == ("x",)
    assert base._same_values(a, b) and not base._same_values(a, Other(np.ones(2)))
    assert "screws" in base._compared_fields(type(_arm(_markers_problem())))


@pytest.mark.parametrize("n", [1, 6, 7, 16])
def test_tangent_frames_are_the_earlier_form_bit_for_bit(n):
    rng = np.random.default_rng(n)
    w = rng.normal(size=(n, 3))
    w[0] = [0.0, 0.0, 1.0]  # equal magnitudes: argmin's first
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    xi = np.concatenate([-np.cross(w, rng.normal(size=(n, 3))), w], axis=1)
    got, want = twists.tangent_frames(xi, ("revolute",) * n), _tangent_frames_before(xi, ("revolute",) * n)
    for g, h in zip(got, want):
        assert len(g) == len(h) == n
        assert all(x.shape == y.shape and x.tobytes() == y.tobytes() for x, y in zip(g, h))


@pytest.mark.parametrize("shape", [(50, 1, 3), (50, 3), (3,), (7, 2, 3), (0, 3), (4, 0, 3)])
def test_point_jacobian_is_the_earlier_form_bit_for_bit(shape):
    p = np.random.default_rng(len(shape)).normal(size=shape)
    if p.size:
        p.flat[0], p.flat[-1] = 0.0, -0.0
    got, want = _kernel.point_jacobian(p), _point_jacobian_before(p)
    assert got.shape == want.shape and got.tobytes() == want.tobytes()
    assert _kernel.point_jacobian(p.tolist() if p.size else p).tobytes() == want.tobytes()


@pytest.mark.parametrize("sigmas", [[1e-4, 2e-4, 3e-4], [1e-4, np.inf, 1e-3], [np.nan, 1.0, 1.0], [0.0, 1.0, 1.0]])
def test_a_made_whitener_remembers_the_diagonal_read_off_it(sigmas):
    d = 1.0 / np.sqrt(np.maximum(np.array(sigmas) ** 2, P.VARIANCE_FLOOR))
    W = np.broadcast_to(np.diag(d), (5, 3, 3))
    cache = P.ResidualCache()
    cache.made(W, d)
    want = P._constant_diagonal(W)
    got = cache.diagonal(W)
    assert (got is None) == (want is None)
    if want is not None:
        assert got.tobytes() == want.tobytes() and not got.flags.writeable and got is not d


def test_a_trial_evaluation_is_the_earlier_forms(monkeypatch):
    problem = _markers_problem()
    W, delta = problem.whiteners(problem.start), _delta(problem)
    for step in (np.zeros_like(delta), delta):
        for jac in (False, True):
            got = problem.evaluate(problem.start, step, W, jac=jac)
            want = _evaluate_before(problem, problem.start, step, W, jac=jac)
            for g, h in zip(got, want):
                assert (g is None and h is None) or g.tobytes() == h.tobytes()


@pytest.mark.parametrize("scale", [0.0, 1e-9, 1e-3, 0.5, 3.0])
def test_few_exponentials_are_the_earlier_form_bit_for_bit(scale):
    xi = np.random.default_rng(7).normal(size=(9, 6)) * scale
    xi[0, 3:] = 0.0  # a pure translation
    for m in (1, 7, 9):
        t = so3.angle(xi[:m, 3:])
        assert se3._few_exps(xi[:m], t).tobytes() == _few_exps_before(xi[:m], t).tobytes()
        assert se3.exp(xi[:m]).tobytes() == _few_exps_before(xi[:m], t).tobytes()


@pytest.mark.parametrize("case", ["markers", "tree lateral", "tree"])
def test_the_free_columns_want_the_blocks_assemble_found(case):
    """``linearize`` of the free columns asks the experiments for ``Problem.want``: ``_blocks_of`` of them."""
    problem = _markers_problem() if case == "markers" else _tree_problem(case == "tree lateral")
    assert problem.want == P._blocks_of(problem.layout, problem.free_idx)
    fixed = np.flatnonzero(~problem.layout.free)
    wider = np.concatenate([problem.free_idx, fixed[:7]])
    assert P._blocks_of(problem.layout, wider) >= problem.want
    W = problem.whiteners(problem.start)
    r, J = problem.linearize(problem.start, W)[:2]
    r2, J2 = problem.linearize(problem.start, W, problem.free_idx.copy())[:2]  # another array: looked up
    assert r.tobytes() == r2.tobytes() and J.tobytes() == J2.tobytes()


def test_parts_kept_per_wanted_blocks_are_the_fresh_ones_and_another_set_misses():
    problem = _tree_problem(True)
    exp = problem.experiments[0]
    for arm in problem.start.arms:
        for want in (problem.want, frozenset({f"{arm}.offsets", f"{arm}.tool", "other"}), frozenset(), None,
                     {f"{arm}.twists"}):
            for _ in range(2):  # computed, then kept
                assert exp._parts(arm, want) == _parts_before(exp, arm, want)
    assert all(isinstance(k[1], frozenset) for k in exp.__dict__["_wanted_parts"])
    assert len(exp.__dict__["_wanted_parts"]) <= base.PARTS_ENTRIES


@pytest.mark.parametrize("case", ["markers", "tree lateral"])
def test_arm_blocks_without_compliance_zeros_are_the_earlier_ones(case):
    problem = _markers_problem() if case == "markers" else _tree_problem(case == "tree lateral")
    for exp in problem.experiments:
        every = exp.residual(problem.start, want=None, jq=True)
        with pytest.MonkeyPatch.context() as m:
            m.setattr(base, "arm_jacobians", _arm_jacobians_before)
            earlier = exp.residual(problem.start, want=None, jq=True)
        assert every.jac.keys() == earlier.jac.keys() and every.jq.keys() == earlier.jq.keys()
        for got, want in ((every.jac, earlier.jac), (every.jq, earlier.jq)):
            assert all(got[k].tobytes() == want[k].tobytes() for k in got)


def test_paired_shifted_turns_are_the_earlier_sums_bit_for_bit():
    rng = np.random.default_rng(3)
    q = rng.uniform(-7.0, 7.0, (40, 6))
    q[:5] = [0.0, -0.0, np.pi, -np.pi / 2, 1e-300, 3.0]
    for offsets in (rng.normal(0, 0.01, 6), np.zeros(6), -np.zeros(6)):
        want = _shifted_turns_before(np.cos(q), np.sin(q), offsets)
        for got in (fk.shifted_turns(np.cos(q), np.sin(q), offsets),
                    fk.paired_shifted_turns(np.stack([np.cos(q), np.sin(q)]), offsets)):
            assert all(g.tobytes() == w.tobytes() for g, w in zip(got, want))


# ------------------------------------------------------------------------------------------- whole solves


@pytest.mark.parametrize("case", ["markers", "pose", "socket", "clamp", "dual", "elastic"])
def test_calibrations_with_the_earlier_forms_are_the_same_bit_for_bit(monkeypatch, ur10_sets, case):
    run = _elastic if case == "elastic" else _cases(ur10_sets)[case]
    shipped = run()
    with monkeypatch.context() as m:
        _earlier_forms(m)
        earlier = run()
    if case == "elastic":
        assert shipped.held is not None  # the gauges held: the solve that differs most from the others
    _same(shipped, earlier)
    _same(run(), earlier)  # the structure seen before
