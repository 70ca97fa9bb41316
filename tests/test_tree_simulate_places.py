"""Simulating a tree (issue #14): a default tracker or camera is placed from a mounted arm's base in the world
(through its carriers), and ``kincal simulate`` lists the carriers' joint spread beside the arms'."""

from __future__ import annotations

import numpy as np

from kincal.cli import main
from kincal.io.models import load_builtin
from kincal.kinematics.tree import tip_pose
from kincal.simulate.generators import random_tracker_pose

TORSO_SCENARIO = """\
format: kincal-scenario
version: 1
name: tiny-torso
model: dual7_torso
seed: 3
units: {length: m, angle: deg}
truth: {level: thesis}
experiment:
  kind: dual
  arms: [left, right]
  n: 12
  known_clamp: true
  clamp: {xyz: [0.10, 0.0, 0.10], rpy: [0, -90, 0]}
noise: {joint_deg: 0.005}
"""


def test_a_default_tracker_looks_at_a_mounted_arm_from_its_world_base():
    robot = load_builtin("dual7_torso")
    assert robot.lineage("left") == ("torso", "left")
    base = (tip_pose(robot, "torso", {"torso": np.zeros((1, robot["torso"].dof))})[0] @ robot["left"].base)[:3, 3]
    assert np.linalg.norm(base - robot["left"].base[:3, 3]) > 0.3  # the mount frame is not the world
    for seed in range(5):
        T = random_tracker_pose(robot, "left", np.random.default_rng(seed))
        d = base - T[:3, 3]
        assert abs(np.hypot(d[0], d[1]) - 2.5) < 1e-9 and -0.2 <= -d[2] <= 0.5  # 2.5 m away, about level
        assert np.degrees(np.arccos(T[:3, 2] @ d / np.linalg.norm(d))) < 20  # looking at it
    single = load_builtin("ur10")
    T = random_tracker_pose(single, "arm", np.random.default_rng(0))
    assert abs(np.hypot(*(T[:2, 3] - single["arm"].base[:2, 3])) - 2.5) < 1e-9


def test_cli_simulate_lists_the_carriers_joint_spread(tmp_path, capsys):
    (tmp_path / "s.yaml").write_text(TORSO_SCENARIO)
    assert main(["simulate", str(tmp_path / "s.yaml"), "-o", str(tmp_path / "o")]) == 0
    text = capsys.readouterr().out
    assert "joint spread, arm torso" in text and "t2" in text
    assert text.index("arm torso") < text.index("arm left") < text.index("arm right")
