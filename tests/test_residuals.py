"""Every experiment kind: residual is zero at the truth, analytic Jacobians match central differences."""

import numpy as np
import pytest

from kincal import experiments
from kincal.data import Dataset
from kincal.errors import DataFormatError, DegenerateExperimentError
from kincal.experiments._kernel import pose_gap
from kincal.kinematics import Robot, forward_kinematics, loaded_forward_kinematics
from kincal.lie import se3, so3
from kincal.params import State, build_layout, retract
from kincal.testing import numerical_jacobian, random_arm, random_pose


def _robot(rng, prismatic=(), compliance=0.0):
    a = random_arm(rng, 6, prismatic, name="a")
    a = a.replace(compliance=rng.uniform(0, compliance, a.dof))
    return Robot("r", {"a": a, "b": random_arm(rng, 7, name="b")})


LOADED = ("pose+wrench", "markers+wrench")


def _case(kind, rng, robot):
    """A data set of ``kind`` that is exactly consistent with ``robot`` (no inverse kinematics needed);
    ``<kind>+wrench``: random loads on the tool deflect arm a's compliant joints."""
    if kind in LOADED:
        kind = kind.split("+")[0]
        q = rng.uniform(-2, 2, (5, robot["a"].dof))
        w = rng.normal(size=(5, 6))
        T = loaded_forward_kinematics(robot["a"], q, w)
        plain = _case(kind, rng, Robot("r", {"a": robot["a"].replace(compliance=None), "b": robot["b"]}))
        W = plain.known["T_world_tracker"]
        if kind == "pose":
            measured = {"T_tracker_tool": se3.inverse(W) @ T, "wrench_tool": w}
        else:
            x = plain.known["p_tool_marker"]
            measured = {"p_tracker_marker": se3.transform_points(se3.inverse(W), se3.transform_points(T[:, None], x)),
                        "wrench_tool": w}
        return Dataset(kind, "r", ("a",), {"a": q}, measured, dict(plain.known))
    a, b = robot["a"], robot["b"]
    qa = lambda n: rng.uniform(-2, 2, (n, a.dof))  # noqa: E731
    qb = lambda n: rng.uniform(-2, 2, (n, b.dof))  # noqa: E731
    W = random_pose(rng)
    if kind == "pose":
        q = qa(5)
        return Dataset("pose", "r", ("a",), {"a": q}, {"T_tracker_tool": se3.inverse(W) @ forward_kinematics(a, q)},
                       {"T_world_tracker": W})
    if kind == "markers":
        q, x = qa(5), rng.uniform(-0.1, 0.1, (3, 3))
        y = se3.transform_points(se3.inverse(W), se3.transform_points(forward_kinematics(a, q)[:, None], x))
        return Dataset("markers", "r", ("a",), {"a": q}, {"p_tracker_marker": y},
                       {"T_world_tracker": W, "p_tool_marker": x})
    if kind == "clamp":
        q = qa(1)
        return Dataset("clamp", "r", ("a",), {"a": q}, known={"T_world_fixture": forward_kinematics(a, q)[0]})
    if kind == "plate":
        q = qa(4)
        X = se3.inverse(W) @ forward_kinematics(a, q)
        return Dataset("plate", "r", ("a",), {"a": q}, {"fixture": np.arange(4)},
                       {"T_plate_fixture": X, "T_world_plate": W})
    if kind == "dual":
        q1, q2 = qa(1), qb(1)
        C = se3.inverse(forward_kinematics(a, q1)) @ forward_kinematics(b, q2)
        return Dataset("dual", "r", ("a", "b"), {"a": q1, "b": q2}, known={"T_toolA_toolB": C[0]})
    if kind == "socket":
        q = qa(1)
        return Dataset("socket", "r", ("a",), {"a": q}, known={"p_world_socket": forward_kinematics(a, q)[0, :3, 3]})
    if kind == "distance":
        q1, q2 = qa(1), qb(1)
        d = np.linalg.norm(forward_kinematics(a, q1)[0, :3, 3] - forward_kinematics(b, q2)[0, :3, 3])
        return Dataset("distance", "r", ("a", "b"), {"a": q1, "b": q2}, known={"distance": d})
    if kind == "plane":
        q = qa(3)
        p = forward_kinematics(a, q)[:, :3, 3]
        n = np.cross(p[1] - p[0], p[2] - p[0])
        n /= np.linalg.norm(n)
        return Dataset("plane", "r", ("a",), {"a": q}, known={"plane_world": np.append(n, n @ p[0])})
    raise AssertionError(kind)


def _assemble(res, layout, N):
    k = res.r.shape[1]
    J = np.zeros((N, k, layout.size))
    for b in layout.blocks:
        if b.name in res.jac:
            J[:, :, b.start: b.stop] = res.jac[b.name]
    return J


# the kinds this file builds consistent data sets of; a kind added later checks itself in tests/test_<kind>.py
CASES = ("clamp", "distance", "dual", "markers", "plane", "plate", "pose", "socket")


def test_every_kind_has_a_jacobian_check():
    from pathlib import Path

    here = Path(__file__).parent
    for kind in experiments.KINDS:
        own = here / f"test_{kind}.py"
        assert kind in CASES or (own.exists() and "check_residual(" in own.read_text()), kind


@pytest.mark.parametrize("kind", CASES + LOADED)
@pytest.mark.parametrize("prismatic", [(), (2,)])
def test_residual_zero_at_truth_and_jacobian_matches_differences(rng, kind, prismatic):
    """Loaded kinds (random wrenches, compliant joints) check the compliance block and the load torques'
    dependence on every other block, the joint readings included."""
    robot = _robot(rng, prismatic, compliance=0.02 if kind in LOADED else 0.0)
    ds = _case(kind, rng, robot)
    vary = {"fixture": np.array([0, 2, 1])} if ds.kind == "plate" else {}
    check_residual(rng, robot, ds, vary)


def check_residual(rng, robot, ds, vary=None):
    """Zero residual at the truth (``ds`` exactly consistent with ``robot``, frames known), then away from it,
    at 3 new configurations with the first sample's measurements (``vary``: measured entries to use instead),
    analytic Jacobians of every block and of the joint readings equal central differences."""
    kind = ds.kind
    state = State.from_robot(robot)
    exps, extras, unknown = experiments.build([ds], state)
    assert unknown == []
    state = State(state.arms, extras, experiments.frame_kinds(exps))
    exp = exps[0]
    np.testing.assert_allclose(exp.residual(state).r, 0.0, atol=1e-12)

    # Away from the truth (non-zero residual), with more samples and every parameter block.
    layout = build_layout(state, [f"{a}.*" for a in ds.arms] + list(extras))
    state = retract(state, layout, rng.normal(scale=0.05, size=layout.size))
    n = 3
    q = {arm: rng.uniform(-2, 2, (n, state.arms[arm].dof)) for arm in ds.arms}
    measured = {k: np.repeat(v[:1], n, axis=0) for k, v in ds.measured.items()}
    measured.update(vary or {})
    if "wrench_tool" in measured:
        measured["wrench_tool"] = rng.normal(size=(n, 6))
    exp = type(exp)(Dataset(kind, "r", ds.arms, q, measured, dict(ds.known), ds.name), exp.frames)
    res = exp.residual(state)
    J = _assemble(res, layout, n)
    num = numerical_jacobian(lambda d: exp.residual(retract(state, layout, d)).r, np.zeros(layout.size))
    np.testing.assert_allclose(J, num, atol=1e-7, rtol=1e-6)
    assert set(res.jac) == {b.name for b in layout.blocks if b.arm in ds.arms or b.name in extras}

    for arm in ds.arms:
        def f(x, arm=arm):
            qq = dict(q)
            qq[arm] = x.reshape(q[arm].shape)
            return type(exp)(Dataset(kind, "r", ds.arms, qq, measured, dict(ds.known), ds.name), exp.frames).residual(
                state).r
        num_q = numerical_jacobian(f, q[arm].ravel()).reshape(res.r.shape + q[arm].shape)
        # d r_i / d q_i only: take each sample's own block
        num_q = np.stack([num_q[i, :, i, :] for i in range(n)])
        np.testing.assert_allclose(res.jq[arm], num_q, atol=1e-7, rtol=1e-6)


def test_only_wanted_blocks_are_computed(rng):
    robot = _robot(rng)
    state = State.from_robot(robot)
    exps, extras, _ = experiments.build([_case("dual", rng, robot)], state)
    res = exps[0].residual(State(state.arms, extras, experiments.frame_kinds(exps)), want={"a.offsets"})
    assert set(res.jac) == {"a.offsets"}


def test_pose_gap_is_position_then_rotation(rng):
    TA, TB = random_pose(rng, (4,)), random_pose(rng, (4,))
    r, _, _ = pose_gap(TA, TB)
    np.testing.assert_allclose(r[:, :3], TA[:, :3, 3] - TB[:, :3, 3])
    np.testing.assert_allclose(se3.exp(se3.join(np.zeros(3), r[:, 3:]))[:, :3, :3] @ TB[:, :3, :3], TA[:, :3, :3],
                               atol=1e-12)


def test_bad_data_sets_are_named(rng):
    robot = _robot(rng)
    state = State.from_robot(robot)
    ds = Dataset("clamp", "r", ("a",), {"a": rng.normal(size=(5, 7))})
    with pytest.raises(DataFormatError, match=r"data set 'experiment': field q\[a\] has 7 joints per sample, expected 6"):
        experiments.build([ds], state)
    ds = Dataset("clamp", "r", ("z",), {"z": rng.normal(size=(5, 6))})
    with pytest.raises(DataFormatError, match="arm 'z' is not in the model"):
        experiments.build([ds], state)
    ds = Dataset("plate", "r", ("a",), {"a": rng.normal(size=(3, 6))}, {"fixture": np.array([0, 1, 5])},
                 {"T_plate_fixture": np.stack([np.eye(4)] * 2)})
    with pytest.raises(DegenerateExperimentError, match="sample 2 field 'fixture' is 5"):
        experiments.build([ds], state)



def test_closed_form_twist_block_equals_general_left_jacobian(rng):
    """theta J_l(theta xi) in closed form (exact screws) equals the general series; unconformed is not exact."""
    arm = random_arm(rng, 5, prismatic=(3,))
    theta = rng.uniform(-4, 4, (7, 5))
    f1, f2 = (f[..., None, None] for f in se3.joint_screw_jacobian_coeffs(arm.screws, theta))
    X = se3.ad(arm.screws)
    closed = theta[..., None, None] * np.eye(6) + f1 * X + f2 * (X @ X)
    general = theta[..., None, None] * se3.left_jacobian(arm.screws * theta[..., None])
    np.testing.assert_allclose(closed, general, atol=1e-12)
    bent = arm.screws.copy()
    bent[0, 3:] *= 1.001
    assert se3.exact_joint_screws(arm.screws) and not se3.exact_joint_screws(bent)


def test_twist_block_generator_identity(rng):
    """The kernel's twist block rests on theta J_l(theta xi) (-ad(xi) G) = G - Ad(exp(theta xi)) G for any
    twist (exact or not), and on the tangent basis being -ad(xi) G for the axis generators G."""
    from kincal.kinematics import tangent_basis, tangent_generators

    arm = random_arm(rng, 5, prismatic=(3,))
    for xi, kind in zip(arm.screws, arm.joint_types):
        np.testing.assert_allclose(-se3.ad(xi) @ tangent_generators(xi, kind), tangent_basis(xi, kind), atol=1e-14)
    theta = rng.uniform(-4, 4, (7, 5))
    for xi in list(arm.screws) + [arm.screws[0] * 1.01 + 0.02]:  # the last one is no exact joint screw
        G = rng.normal(size=(6, 4))
        lhs = theta[..., None, None] * se3.left_jacobian(xi * theta[..., None]) @ (-se3.ad(xi) @ G)
        rhs = G - se3.adjoint(se3.exp(xi * theta[..., None])) @ G
        np.testing.assert_allclose(lhs, rhs, atol=1e-11)


def test_loaded_joint_reading_derivative_alone(rng):
    """With no parameter block asked for, J_q of a loaded data set still includes the load torques' change."""
    robot = _robot(rng, compliance=0.02)
    ds = _case("markers+wrench", rng, robot)
    state = State.from_robot(robot)
    exps, extras, _ = experiments.build([ds], state)
    state = State(state.arms, extras, experiments.frame_kinds(exps))
    np.testing.assert_array_equal(exps[0].residual(state, want=set()).jq["a"], exps[0].residual(state).jq["a"])


def test_hand_eye_recovers_the_tool_error_or_says_it_cannot(rng):
    from kincal.experiments.handeye import hand_eye

    F, X, W = random_pose(rng, (20,)), random_pose(rng), random_pose(rng)
    np.testing.assert_allclose(hand_eye(F, se3.inverse(W) @ F @ X), X, atol=1e-10)
    # motions about one axis only leave the rotation about it undetermined
    turn = se3.exp(np.concatenate([np.zeros((20, 3)), np.outer(rng.uniform(0.3, 2.0, 20), [0, 0, 1.0])], axis=1))
    F1 = F[0] @ turn
    assert hand_eye(F1, se3.inverse(W) @ F1 @ X) is None


def test_pose_kind_starts_from_the_hand_eye_tool_when_the_tool_is_far_off():
    """Full-pose data, unknown tracker, a tool turned 120 deg from nominal: the pose kind's ``start`` hook gives
    the tool's error (hand-eye) and the solve starts there; without it the local steps end in a minimum."""
    from kincal.estimation import calibrate
    from kincal.experiments.pose import PoseExperiment
    from kincal.noise import Noise
    from kincal.robots import load
    from kincal.simulate.generators import generate_pose

    ur = load("ur10")
    X = se3.make(so3.exp(np.array([np.radians(120.0), 0.0, 0.0])), np.array([0.0, 0.02, 0.05]))
    true = Robot("ur10", {"arm": ur["arm"].replace(tool=ur["arm"].tool @ X)})
    ds, _, val = generate_pose(true, n=40, rng=3)
    exp, = experiments.build([ds], State.from_robot(ur))[0]
    free = ("arm.tool", "arm.home")
    np.testing.assert_allclose(exp.start(State.from_robot(ur), free, {"tracker"})["arm.tool"], X, atol=1e-8)
    assert exp.start(State.from_robot(ur), free, set()) == {}  # a known tracker: nothing to correct from
    assert isinstance(exp, PoseExperiment)
    res = calibrate(ur, [ds], ["arm.tool"], noise=Noise(position=1e-5, orientation=1e-5, joint=1e-5),
                    validation=list(val.values()))
    assert res.status == "converged" and res.validation[0].after.position_max < 1e-9
