"""Parameter names, levels, globs, status, retraction and displacement."""

import numpy as np
import pytest

from kincal.errors import ModelError
from kincal.kinematics import Robot
from kincal.params import POINTS, POSE, Prior, State, build_layout, displacement, recentre, retract, scale_direction
from kincal.testing import random_arm, random_pose


@pytest.fixture
def state(rng):
    robot = Robot("r", {"right": random_arm(rng, 7, name="right"), "left": random_arm(rng, 3, (1,), name="left")})
    return State.from_robot(robot, {"clamp": random_pose(rng), "markers": rng.normal(size=(2, 3))},
                            {"clamp": POSE, "markers": POINTS})


def test_stable_names_and_units(state):
    lay = build_layout(state, "offsets")
    for name in ("right.j3.offset", "right.j2.xi.shift_1", "right.j2.xi.tilt_2", "right.home.w_z", "left.base.v_x",
                 "left.tool.w_y", "clamp.w_z", "markers.m2.x", "left.j2.xi.tilt_1"):
        assert name in lay.names
    assert "left.j2.xi.shift_1" not in lay.names  # prismatic: 2 tilt coordinates only
    assert lay.units[lay.index("left.j2.offset")] == "m" and lay.units[lay.index("right.j2.offset")] == "rad"
    assert lay.units[lay.index("left.j2.compliance")] == "m/N" and lay.units[lay.index("right.j2.compliance")] == "rad/Nm"
    assert lay.size == 7 + 28 + 18 + 3 + 10 + 18 + 6 + 6 + 10  # ... + one compliance per joint
    ela = build_layout(state, ["kinematic", "elastic"], free_extras=[])
    assert set(ela.free_names) - set(build_layout(state, "kinematic", free_extras=[]).free_names) == {
        f"{a}.{j}.compliance" for a, n in (("right", 7), ("left", 3)) for j in [f"j{i}" for i in range(1, n + 1)]}


def test_levels_globs_and_status(state):
    off = build_layout(state, "offsets", free_extras=[])
    assert off.free_names == [f"right.j{i}.offset" for i in range(1, 8)] + [f"left.j{i}.offset" for i in range(1, 4)]
    kin = build_layout(state, "kinematic", free_extras=[])
    assert "right.j4.xi.tilt_1" in kin.free_names and "right.home.v_y" in kin.free_names
    assert "right.base.v_x" not in kin.free_names
    lay = build_layout(state, ["right.j*.offset", "left.j2.xi.v_x", "clamp"], fixed=["right.j1.*"], free_extras=[])
    assert "right.j1.offset" not in lay.free_names and "right.j2.offset" in lay.free_names
    assert {"left.j2.xi.tilt_1", "left.j2.xi.tilt_2"} <= set(lay.free_names)  # a joint's twist moves as a whole
    assert {f"clamp.{c}" for c in ("v_x", "w_z")} <= set(lay.free_names)
    lay = build_layout(state, [], priors={"right.j3.offset": Prior(0.01, 0.002)}, free_extras=[])
    i = lay.index("right.j3.offset")
    assert lay.free_names == ["right.j3.offset"] and lay.prior_sigma[i] == 0.01 and lay.prior_mean[i] == 0.002
    with pytest.raises(ModelError, match="matches no parameter"):
        build_layout(state, ["right.j9.offset"])
    with pytest.raises(ModelError, match="unknown level"):
        level = "geometry"
        build_layout(state, level)


def test_retract_recentre_and_displacement(state, rng):
    lay = build_layout(state, ["right.*", "left.*", "clamp", "markers"])
    d = rng.normal(scale=1e-3, size=lay.size)
    moved = retract(state, lay, d)
    disp, _ = displacement(moved, state, lay)
    twist = np.zeros(lay.size, bool)
    for b in lay.blocks:
        if b.part == "twists":
            twist[b.start: b.stop] = True
    np.testing.assert_allclose(disp[~twist], d[~twist], atol=1e-12)
    # twists: the report chart (projection on the tangent basis) agrees with the exact retraction to second order
    np.testing.assert_allclose(disp[twist], d[twist], atol=1e-5)
    again = recentre(moved)
    w = again.arms["right"].screws[:, 3:]
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(np.sum(w * again.arms["right"].screws[:, :3], axis=1), 0.0, atol=1e-15)
    disp2, _ = displacement(again, state, lay)
    np.testing.assert_allclose(disp2, d, atol=1e-5)  # conformation moves twists at second order only


def test_scale_direction_scales_translations(state):
    lay = build_layout(state, "offsets")
    s = scale_direction(state, lay)
    b = lay.block("clamp")
    np.testing.assert_allclose(s[b.start: b.start + 3], state.extras["clamp"][:3, 3])
    np.testing.assert_allclose(s[b.start + 3: b.stop], 0.0)


def test_twist_retraction_is_exact_and_its_basis_matches_differences(state, rng):
    """Large tangent steps keep every joint screw valid; the basis at the step is d screw / d step."""
    from kincal.testing import numerical_jacobian

    lay = build_layout(state, "kinematic", free_extras=[])
    b = next(x for x in lay.blocks if x.arm == "right" and x.part == "twists")
    d = np.zeros(lay.size)
    d[b.start: b.stop] = rng.normal(scale=0.2, size=b.stop - b.start)
    a = retract(state, lay, d).arms["right"]
    v, w = a.screws[:, :3], a.screws[:, 3:]
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-14)
    np.testing.assert_allclose(np.sum(v * w, axis=1), 0.0, atol=1e-14)

    def screws_at(x):
        full = d.copy()
        full[b.start: b.stop] = x
        return retract(state, lay, full).arms["right"].screws.ravel()

    num = numerical_jacobian(screws_at, d[b.start: b.stop])
    np.testing.assert_allclose(a.basis, num, atol=1e-8)


@pytest.mark.parametrize("kind", ["pose", "point", "points", "plane"])
def test_frame_kinds_retract_displace_and_turn_with_the_world(kind, rng):
    """Each frame kind: displacement inverts retraction (first order), and ``world_motion`` is the local
    displacement of the frame turned with the world by exp(e xi) (finite differences)."""
    from kincal.lie import se3
    from kincal.params import FRAME_KINDS, Plane
    from kincal.testing import numerical_jacobian

    k = FRAME_KINDS[kind]
    raw = {"pose": random_pose(rng), "point": rng.normal(size=3), "points": rng.normal(size=(3, 3)),
           "plane": np.append(rng.normal(size=3), 0.4)}[kind]
    value = k.from_raw(raw)
    names, units = k.coordinates("f", value)
    assert len(names) == len(units) == len(set(names))
    d = rng.normal(scale=1e-6, size=len(names))
    disp, D = k.displacement(k.retract(value, d), value)
    np.testing.assert_allclose(disp, d, atol=1e-11)
    xi, eps = rng.normal(size=6), 1e-6
    T = se3.exp(eps * xi)
    if kind == "pose":
        turned = T @ value
    elif kind == "plane":
        n = T[:3, :3] @ value.normal
        turned = Plane.from_array(np.append(n, value.d + n @ T[:3, 3]))
    else:
        turned = se3.transform_points(T, value)
    np.testing.assert_allclose(k.displacement(turned, value)[0] / eps, k.world_motion(value, xi), atol=1e-5)
    if k.origin(value) is not None:  # a frame's origin and its derivative (distance constraints)
        num = numerical_jacobian(lambda x: k.origin(k.retract(value, x)), np.zeros(len(names)))
        np.testing.assert_allclose(k.origin_jacobian(value), num, atol=1e-7)
    else:
        assert kind in ("points", "plane")


def test_kinds_are_compared_by_identity_never_by_string():
    from kincal.params import POSE

    with pytest.raises(TypeError, match="compare parameter kinds by identity"):
        POSE == "pose"  # noqa: B015 - a leftover string comparison must fail loudly
