"""Session 12 (helper b): the residual and Jacobian kernel with fewer numpy calls, bit for bit.

The chain's revolute turns run on contiguous rows of transposed buffers (``fk.turn_pairs``): compared here byte
for byte with the base's column-turning kernels (fd4f6a3, copied below) on the UR10, on random exact screws
(revolute and prismatic, joints at zero) and on several batch shapes. (The prefix projections' turned the same
way until round 2 replaced them by ``jacobians._sample_projections``; fd4f6a3's ``_frame_projections`` below is
the reference test_fixed_overhead_s12_b2 holds that one to.)"""

from __future__ import annotations

import numpy as np
import pytest

from kincal.kinematics import fk
from kincal.kinematics import jacobians as jac
from kincal.lie import se3
from kincal.robots import load


def _turn_columns(x0, x1, c, s):
    a = c * x0
    a += s * x1
    b = c * x1
    b -= s * x0
    x0[...], x1[...] = a, b


def _frame_prefixes(screws, theta, base, turns):
    """fd4f6a3's ``fk._frame_prefixes``."""
    C, Ci, revolute, _, _ = se3.joint_frames(screws)
    n = theta.shape[-1]
    batch = theta.shape[:-1]
    flat = theta.reshape(-1, n)
    N = flat.shape[0]
    P = np.empty((n + 1, N, 4, 4))
    P[0] = np.broadcast_to(base, batch + (4, 4)).reshape(N, 4, 4)
    moves = flat.any(axis=0)
    cos, sin = (t.reshape(-1, n).T[:, :, None] for t in turns)
    X = np.empty((N, 4, 4))
    X2, P2 = X.reshape(4 * N, 4), P.reshape(n + 1, 4 * N, 4)
    x0, x1 = X[:, :3, 0], X[:, :3, 1]
    for i in range(n):
        if not moves[i]:
            P[i + 1] = P[i]
            continue
        np.matmul(P2[i], C[i], out=X2)
        if revolute[i]:
            _turn_columns(x0, x1, cos[i], sin[i])
        else:
            X[:, :3, 3] += flat[:, i, None] * X[:, :3, 2]
        np.matmul(X2, Ci[i], out=P2[i + 1])
    return np.moveaxis(P, 0, 1).reshape(batch + (n + 1, 4, 4))


def _frame_projections(kin, G):
    """fd4f6a3's ``jacobians._frame_projections``."""
    _, _, revolute, AdC, AdCi = se3.joint_frames(kin.screws)
    N, k = G.shape[:2]
    theta = kin.theta
    n = theta.shape[1]
    M = np.empty((n + 1, N * k, 6))
    P0 = kin.prefixes[:, 0]
    if (P0 == P0[:1]).all():
        M[0] = G.reshape(N * k, 6) @ se3.adjoint(P0[0])
    else:
        M[0] = jac._project_prefixes(G, kin.prefixes[:, :1])[0]
    moves = theta.any(axis=0)
    cos, sin = (t.T[:, :, None, None] for t in kin.turns)
    K2 = np.empty((N * k, 6))
    K = K2.reshape(N, k, 6)
    x0, x1 = K[..., 0::3], K[..., 1::3]
    for i in range(n):
        if not moves[i]:
            M[i + 1] = M[i]
            continue
        np.matmul(M[i], AdC[i], out=K2)
        if revolute[i]:
            _turn_columns(x0, x1, cos[i], sin[i])
        else:
            t = theta[:, i, None]
            K[..., 3] += t * K[..., 1]
            K[..., 4] -= t * K[..., 0]
        np.matmul(K2, AdCi[i], out=M[i + 1])
    return M


def _random_screws(rng, n):
    out = []
    for _ in range(n):
        if rng.random() < 0.3:  # prismatic
            v = rng.standard_normal(3)
            out.append(np.r_[v / np.linalg.norm(v), 0.0, 0.0, 0.0])
        else:
            w = rng.standard_normal(3)
            w /= np.linalg.norm(w)
            out.append(np.r_[-np.cross(w, rng.standard_normal(3)), w])
    return np.array(out)


def _chains(rng):
    ur10 = load("ur10")["arm"]
    yield ur10.screws, ur10.base
    for n in (1, 3, 7):
        yield _random_screws(rng, n), se3.exp(rng.standard_normal(6))


def _angles(rng, batch, n, case):
    theta = rng.uniform(-3.5, 3.5, batch + (n,))
    if case == 1:
        theta[..., 0] = 0.0  # a joint at zero in every sample
    if case == 2:
        theta = np.where(rng.random(theta.shape) < 0.3, 0.0, theta)
    return theta


@pytest.mark.parametrize("N", [1, 2, 7, 50, 201])
def test_chain_prefixes_are_the_column_turning_ones_bit_for_bit(N):
    rng = np.random.default_rng(N)
    for screws, base in _chains(rng):
        for case in range(3):
            theta = _angles(rng, (N,), len(screws), case)
            turns = np.cos(theta), np.sin(theta)
            want = _frame_prefixes(screws, theta, base, turns)
            got, moves = fk._frame_prefixes(screws, theta, base, turns)
            assert got.shape == want.shape and got.tobytes() == want.tobytes()
            kin = fk.chain(screws, theta, base, np.eye(4), np.eye(4))
            assert kin.prefixes.tobytes() == want.tobytes()


def test_chain_prefixes_of_a_batch_grid_bit_for_bit():
    rng = np.random.default_rng(3)
    for screws, base in _chains(rng):
        theta = _angles(rng, (4, 5), len(screws), 0)
        turns = np.cos(theta), np.sin(theta)
        want = _frame_prefixes(screws, theta, base, turns)
        got, moves = fk._frame_prefixes(screws, theta, base, turns)
        assert got.shape == want.shape and got.tobytes() == want.tobytes()


def test_turn_pairs_is_turn_columns():
    rng = np.random.default_rng(5)
    X = rng.standard_normal((2, 40, 3))
    c, s = np.cos(rng.uniform(-4, 4, (40, 1))), np.sin(rng.uniform(-4, 4, (40, 1)))
    want = X.copy()
    _turn_columns(want[0], want[1], c, s)
    got = X.copy()
    c_rows, s_rows = (np.repeat(v, 3, axis=1).reshape(1, -1) for v in (c, s))
    fk.turn_pairs(got.reshape(2, -1), c_rows, s_rows * [[1.0], [-1.0]])
    assert got.tobytes() == want.tobytes()


def _point_jacobian(p):
    """fd4f6a3's ``_kernel.point_jacobian``."""
    from kincal.lie import so3
    out = np.zeros(p.shape[:-1] + (3, 6))
    out[..., :, :3] = np.eye(3)
    out[..., :, 3:] = -so3.hat(p)
    return out


@pytest.mark.parametrize("shape", [(3,), (1, 3), (50, 3), (50, 2, 3), (4, 5, 3)])
def test_point_jacobian_bit_for_bit(shape):
    from kincal.experiments._kernel import point_jacobian
    p = np.random.default_rng(len(shape)).standard_normal(shape)
    p.flat[0], p.flat[-1] = 0.0, -0.0
    got = point_jacobian(p)
    assert got.shape == shape[:-1] + (3, 6) and got.tobytes() == _point_jacobian(p).tobytes()


def test_chain_presets_are_the_properties_computed():
    """``chain`` sets ``moves`` and ``one_base``: what the cached properties compute from the kinematics."""
    rng = np.random.default_rng(8)
    for screws, base in _chains(rng):
        for batch in ((1,), (20,), (3, 4), ()):
            theta = _angles(rng, batch, len(screws), 1)
            kin = fk.chain(screws, theta, base, np.eye(4), np.eye(4))
            bare = fk.Kinematics(kin.theta, kin.screws, kin.prefixes, kin.flange, kin.tool)
            assert np.array_equal(kin.moves, bare.moves) and kin.moves.dtype == bare.moves.dtype
            assert kin.one_base.tobytes() == bare.one_base.tobytes() == base.tobytes()
    raw = fk.chain(rng.standard_normal((3, 6)), rng.standard_normal((5, 3)), np.eye(4), np.eye(4), np.eye(4))
    assert np.array_equal(raw.one_base, np.eye(4))
    per_sample = se3.exp(rng.standard_normal((5, 6)))
    theta = rng.standard_normal((5, 6))
    assert fk.chain(load("ur10")["arm"].screws, theta, per_sample, np.eye(4), np.eye(4)).one_base is None


def _fit_transform(src, dst):
    """fd4f6a3's ``_kernel.fit_transform``."""
    src, dst = np.broadcast_arrays(src, dst)
    cs, cd = src.mean(axis=-2), dst.mean(axis=-2)
    U, _, Vt = np.linalg.svd(np.swapaxes(dst - cd[..., None, :], -1, -2) @ (src - cs[..., None, :]))
    U[..., :, 2] *= np.sign(np.linalg.det(U @ Vt))[..., None]
    R = U @ Vt
    return se3.make(R, cd - np.einsum("...ij,...j->...i", R, cs))


@pytest.mark.parametrize("K", [3, 4, 50, 1001])
def test_fit_transform_bit_for_bit(K):
    from kincal.experiments._kernel import fit_transform
    rng = np.random.default_rng(K)
    for t in range(9):
        src = rng.standard_normal((K, 3))
        dst = se3.transform_points(se3.exp(rng.standard_normal(6)), src) + 1e-3 * rng.standard_normal((K, 3))
        if t % 3 == 1:
            dst = dst * [1.0, 1.0, -1.0]  # a reflected best fit
        for a, b in ((src, dst), (src[None].repeat(4, 0), dst[None]), (src, np.stack([dst, 2 * dst]))):
            got, want = fit_transform(a, b), _fit_transform(a, b)
            assert got.shape == want.shape and got.tobytes() == want.tobytes()


def test_markers_initial_is_the_mean_of_the_marker_in_the_tool():
    """``MarkersExperiment.initial``: the tracker by ``fit_transform``, the marker as ``np.mean`` gives it."""
    from kincal.estimation import Problem
    from kincal.simulate import Noise, generate_markers
    robot = load("ur10")
    ds, _, _ = generate_markers(robot, "arm", n=30, rng=4, noise=Noise(position=5e-5), markers=2, n_validation=1)
    problem = Problem.build(robot, [ds], "kinematic")
    exp = problem.experiments[0]
    F = exp._fk(problem.nominal, "arm")
    y = ds.measured["p_tracker_marker"]
    W = _fit_transform(y.reshape(-1, 3), se3.transform_points(F[:, None], np.zeros(y.shape[1:])).reshape(-1, 3))
    x = np.mean(se3.transform_points(se3.inverse(F)[:, None], se3.transform_points(W, y)), axis=0)
    assert problem.nominal.extras[exp.frames["tracker"]].tobytes() == W.tobytes()
    assert np.asarray(problem.nominal.extras[exp.frames["markers"]]).tobytes() == x.tobytes()


def test_remembered_single_pose_inverse_and_adjoint():
    """``se3.remembered``: the function's value bit for bit, read-only, keyed by the function and the pose's bytes
    (another pose or function misses), forgotten by ``se3.clear_caches``; batches are computed."""
    rng = np.random.default_rng(12)
    se3.clear_caches()
    T = se3.exp(rng.standard_normal(6))
    for fn in (se3.inverse, se3.adjoint):
        got = se3.remembered(fn, T)
        assert got.tobytes() == fn(T).tobytes() and not got.flags.writeable
        assert se3.remembered(fn, T.copy()) is got
    assert se3.remembered(se3.inverse, T).shape == (4, 4) and se3.remembered(se3.adjoint, T).shape == (6, 6)
    U = T.copy()
    U[0, 3] = np.nextafter(U[0, 3], 1.0)  # one ulp away: a miss
    assert se3.remembered(se3.inverse, U).tobytes() == se3.inverse(U).tobytes()
    assert se3.remembered(se3.inverse, U).tobytes() != se3.remembered(se3.inverse, T).tobytes()
    batch = se3.exp(rng.standard_normal((3, 6)))
    assert se3.remembered(se3.inverse, batch).tobytes() == se3.inverse(batch).tobytes()
    kept = se3.remembered(se3.adjoint, T)
    se3.clear_caches()
    assert se3.remembered(se3.adjoint, T) is not kept


def _markers_residual(exp, state, want, jq):
    """fd4f6a3's ``MarkersExperiment.residual`` (with the base's point Jacobian and inverse)."""
    arm = exp.arms[0]
    W = state.extras[exp.frames["tracker"]]
    x = np.asarray(state.extras[exp.frames["markers"]])
    y = exp.dataset.measured["p_tracker_marker"]
    N, m = y.shape[:2]
    kin = exp._kin(state, arm)
    F = kin.tool
    pA = se3.transform_points(F[:, None], x)
    Rt = W[:3, :3].T
    GA = Rt @ _point_jacobian(pA)
    jac, jqs = {}, {}
    exp._arm_jac(state, arm, kin, GA.reshape(N, 3 * m, 6), want, jq, jac, jqs)
    if exp._wanted("markers", want):
        Jx = np.zeros((N, m, 3, m, 3))
        RtR = Rt @ F[:, :3, :3]
        for j in range(m):
            Jx[:, j, :, j, :] = RtR
        jac[exp.frames["markers"]] = Jx.reshape(N, 3 * m, 3 * m)
    if exp._wanted("tracker", want):
        jac[exp.frames["tracker"]] = -GA.reshape(N, 3 * m, 6)
    r = se3.transform_points(se3.inverse(W), pA) - y
    return r.reshape(N, 3 * m), jac, jqs


@pytest.mark.parametrize("markers", [1, 3])
def test_markers_residual_is_the_base_one_bit_for_bit(markers):
    """Every block, the readings' derivative and the residual (also asked alone) as the base computed them."""
    from kincal.estimation import Problem
    from kincal.simulate import Noise, generate_markers
    robot = load("ur10")
    ds, _, _ = generate_markers(robot, "arm", n=25, rng=markers, noise=Noise(position=5e-5), markers=markers,
                                n_validation=1)
    problem = Problem.build(robot, [ds], "kinematic")
    exp, state = problem.experiments[0], problem.start
    for want, jq in ((None, True), (problem.want, False), (set(), False), ({"tracker"}, False), (set(), True)):
        got = exp.residual(state, want=want, jq=jq)
        r, jac, jqs = _markers_residual(exp, state, want, jq)
        assert got.r.tobytes() == r.tobytes()
        assert set(got.jac) == set(jac) and set(got.jq) == set(jqs)
        for name, J in jac.items():
            assert got.jac[name].shape == J.shape and got.jac[name].tobytes() == J.tobytes(), name
        for name, J in jqs.items():
            assert got.jq[name].tobytes() == J.tobytes()


def test_frame_shapes_read_the_sizes_once_with_the_same_shapes():
    from kincal.estimation import Problem
    from kincal.simulate import Noise, generate_markers
    ds, _, _ = generate_markers(load("ur10"), "arm", n=10, rng=2, noise=Noise(position=5e-5), markers=3,
                                n_validation=1)
    exp = Problem.build(load("ur10"), [ds], "kinematic").experiments[0]
    assert exp.frame_shapes() == {"tracker": (4, 4), "markers": (3, 3)}
    assert all(exp.frame_shape(r) == s for r, s in exp.frame_shapes().items())


@pytest.mark.parametrize("kind", ["pose", "markers", "socket"])
def test_residual_alone_is_the_full_residual_bit_for_bit(kind):
    """Asked for no Jacobian (``want=set()``, no readings), a residual gives the r of the full evaluation, with
    no blocks (pose and markers stop before their Jacobians)."""
    from kincal import simulate
    from kincal.estimation import Problem
    robot = load("ur10")
    make = getattr(simulate, f"generate_{kind}")
    ds = make(robot, "arm", n=20, rng=5, noise=simulate.Noise(position=5e-5, orientation=1e-4))[0]
    problem = Problem.build(robot, [ds], "kinematic")
    exp, state = problem.experiments[0], problem.start
    alone, full = exp.residual(state, want=set(), jq=False), exp.residual(state, want=None, jq=True)
    assert alone.r.tobytes() == full.r.tobytes() and not alone.jac and not alone.jq
    assert full.jac and full.jq
