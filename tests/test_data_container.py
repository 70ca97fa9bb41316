"""The in-memory Dataset container validates its contents."""

import numpy as np
import pytest

from kincal.data import Dataset
from kincal.errors import DegenerateExperimentError, ShapeError


def test_dual_dataset_and_subset(rng):
    q = {"left": rng.normal(size=(5, 7)), "right": rng.normal(size=(5, 7))}
    ds = Dataset("dual", "frida", ("left", "right"), q, known={"T_toolA_toolB": np.eye(4)})
    assert ds.size == 5
    sub = ds.subset(slice(1, 3))
    assert sub.size == 2 and np.array_equal(sub.q["right"], q["right"][1:3])
    with pytest.raises(ValueError):
        ds.q["left"][0, 0] = 1.0


def test_dataset_errors(rng):
    q = {"arm": rng.normal(size=(4, 6))}
    with pytest.raises(ShapeError, match="unknown kind"):
        Dataset("laser", "ur10", ("arm",), q)
    with pytest.raises(ShapeError, match="needs 2 arm"):
        Dataset("dual", "ur10", ("arm",), q)
    with pytest.raises(ShapeError, match="needs measured 'T_tracker_tool'"):
        Dataset("pose", "ur10", ("arm",), q)
    with pytest.raises(ShapeError, match="unexpected known entry 'T_world_plate'"):
        Dataset("clamp", "ur10", ("arm",), q, known={"T_world_plate": np.eye(4)})
    with pytest.raises(ShapeError, match="has \\(3,\\) samples"):
        Dataset("pose", "ur10", ("arm",), q, measured={"T_tracker_tool": np.zeros((3, 4, 4))})
    bad = q["arm"].copy()
    bad[2, 4] = np.nan
    with pytest.raises(ShapeError, match="sample 2 joint 4 is nan"):
        Dataset("clamp", "ur10", ("arm",), {"arm": bad})
    with pytest.raises(DegenerateExperimentError, match="no samples"):
        Dataset("clamp", "ur10", ("arm",), {"arm": np.zeros((0, 6))})
    with pytest.raises(ShapeError, match="different sample counts"):
        Dataset("dual", "frida", ("a", "b"), {"a": np.zeros((3, 7)), "b": np.zeros((4, 7))})
