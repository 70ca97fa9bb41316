"""The unit plausibility check on a mounted arm (issue #14): its nominal tool spread is taken through its carriers
(the composite chain), so a data set of an arm on a torso in mm where the manifest says m (or the reverse) is
refused with one line naming the file and columns, in files and in memory, and a correct one passes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from kincal.errors import DataFormatError
from kincal.estimation.plausibility import implausible_units
from kincal.estimation.solver import calibrate
from kincal.io.datasets import load_dataset, write_dataset
from kincal.io.models import load_builtin
from kincal.kinematics.tree import tip_pose
from kincal.simulate.generators import generate_markers
from kincal.simulate.noise import Noise

KEY = "p_tracker_marker"


@pytest.fixture(scope="module")
def torso():
    robot = load_builtin("dual7_torso")
    ds, _, _ = generate_markers(robot, "left", n=30, rng=1, noise=Noise(position=1e-5, joint=1e-5),
                                known_markers=True, n_validation=5)
    assert robot.lineage("left") == ("torso", "left") and set(ds.q) == {"torso", "left"}
    assert np.ptp(ds.q["torso"], axis=0).min() > 0.1  # the torso moves in the data
    return robot, ds


def _manifest(tmp_path, robot, ds, length, stated):
    """``ds`` written in ``length`` with the manifest stating ``stated`` instead."""
    path = write_dataset(ds, tmp_path / f"{length}-as-{stated}.yaml", robot, model="dual7_torso", length=length)
    text = path.read_text()
    assert f"length: {length}" in text
    path.write_text(text.replace(f"length: {length}", f"length: {stated}"))
    return path


@pytest.mark.parametrize("length, stated, hint", [("mm", "m", "mm"), ("m", "mm", "m")])
def test_a_mounted_arm_in_the_wrong_length_unit_is_refused_in_one_line(torso, tmp_path, length, stated, hint):
    robot, ds = torso
    with pytest.raises(DataFormatError) as err:
        load_dataset(_manifest(tmp_path, robot, ds, length, stated))
    line = str(err.value)
    assert "\n" not in line
    assert "columns 'm1.x'..'m3.z'" in line and f"the measured {KEY} spread over" in line
    assert "not in the stated length unit" in line and f"check units.length ('{stated}')" in line
    assert f"are the columns in '{hint}'?" in line


def test_a_mounted_arm_in_the_stated_unit_passes(torso, tmp_path):
    robot, ds = torso
    for length in ("m", "mm"):
        back = load_dataset(_manifest(tmp_path, robot, ds, length, length))
        np.testing.assert_allclose(back.measured[KEY], ds.measured[KEY], atol=1e-12)
        assert implausible_units(robot, back) is None


def test_the_tool_spread_goes_through_the_carriers(torso):
    """The judged spread is the composite chain's (the torso's motion included), not the arm's own chain's."""
    robot, ds = torso
    bad = implausible_units(robot, replace(ds, measured={KEY: ds.measured[KEY] * 1e3}))
    assert bad is not None and bad.field == KEY and 900 < bad.value < 1100
    p = tip_pose(robot, "left", ds.q)[:, :3, 3]
    assert bad.tool == pytest.approx(np.sqrt(np.mean(np.sum((p - p.mean(0)) ** 2, -1))), rel=1e-12)


def test_solve_refuses_a_mounted_arm_in_mm_before_solving(torso):
    robot, ds = torso
    with pytest.raises(DataFormatError, match=rf"data set '{ds.name}' \(markers\): the measured {KEY} spread"):
        calibrate(robot, [replace(ds, measured={KEY: ds.measured[KEY] * 1e3})], "offsets")
