"""Derived quantities of a mounted arm (issue #14): its tool pose at the nominal zero in the world, through its
carriers at their zero readings (with the carriers' uncertainty), beside the pose in the carrier's tool frame
(which trades against the carrier's tool, so it is not identifiable)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kincal import robots
from kincal.estimation import Noise, calibrate
from kincal.kinematics import forward_kinematics
from kincal.kinematics.tree import tip_pose
from kincal.simulate import generate_pose, perturb_robot

NOISE = Noise(position=2e-5, orientation=2e-5)
TRACKER = np.array([[1.0, 0, 0, 2.0], [0, 1, 0, 0], [0, 0, 1, 0.5], [0, 0, 0, 1]])


def test_a_mounted_arms_tool_at_zero_is_given_in_the_world_and_in_its_mount():
    nominal = robots.load("dual7_torso")
    true = perturb_robot(nominal, "fine", rng=4)
    data = [replace(generate_pose(true, a, n=40, rng=4 + i, noise=NOISE, known_tracker=True,
                                  T_world_tracker=TRACKER)[0], name=f"pose-{a}")
            for i, a in enumerate(("left", "right"))]
    res = calibrate(nominal, data, "kinematic", noise=NOISE)
    found = {d.name: d for d in res.derived}
    zeros = {a: np.zeros((1, nominal[a].dof)) for a in nominal.arms}
    for arm in ("left", "right"):
        world = np.array([found[f"{arm}.tool_at_zero.world.{c}"].value for c in "xyz"])
        mount = np.array([found[f"{arm}.tool_at_zero.mount.{c}"].value for c in "xyz"])
        np.testing.assert_allclose(world, tip_pose(res.robot, arm, zeros)[0, :3, 3], atol=1e-12)
        # the pose on the mount trades against the torso's tool (a gauge): it is evaluated at the min-change
        # representative of the estimate, microns from the returned model's, and is not identifiable
        np.testing.assert_allclose(mount, forward_kinematics(res.robot[arm], zeros[arm])[0, :3, 3], atol=1e-5)
        assert not any(found[f"{arm}.tool_at_zero.mount.{c}"].identifiable for c in "xyz")
        truth = tip_pose(true, arm, zeros)[0, :3, 3]
        for k, c in enumerate("xyz"):
            d = found[f"{arm}.tool_at_zero.world.{c}"]
            assert d.identifiable and abs(d.value - truth[k]) < 4 * d.std, (arm, c, d.value, truth[k], d.std)
            assert d.std < 2e-5  # the torso's uncertainty included: about 7 um
