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


def test_shapes_come_from_the_kinds_schema(rng):
    q = {"arm": rng.normal(size=(4, 6))}
    with pytest.raises(ShapeError, match=r"measured 'T_tracker_tool' must have shape \(N, 4, 4\), got \(4, 3, 4\)"):
        Dataset("pose", "ur10", ("arm",), q, measured={"T_tracker_tool": np.zeros((4, 3, 4))})
    with pytest.raises(ShapeError, match=r"measured 'wrench_tool' must have shape \(N, 6\), got \(4, 3\)"):
        Dataset("pose", "ur10", ("arm",), q, measured={"T_tracker_tool": np.zeros((4, 4, 4)),
                                                       "wrench_tool": np.zeros((4, 3))})
    # a size the data choose (markers m) must agree between the entries using it
    with pytest.raises(ShapeError, match=r"known 'p_tool_marker' has m = 2, 'p_tracker_marker' has m = 3"):
        Dataset("markers", "ur10", ("arm",), q, {"p_tracker_marker": np.zeros((4, 3, 3))},
                {"p_tool_marker": np.zeros((2, 3))})
    with pytest.raises(ShapeError, match=r"known 'p_world_socket' must have shape \(3,\), got \(4,\)"):
        Dataset("socket", "ur10", ("arm",), q, known={"p_world_socket": np.zeros(4)})


def test_a_registered_schema_is_all_a_new_kind_needs_in_the_data_layer(rng, monkeypatch):
    from kincal import schema as schemas
    from kincal.schema import LENGTH, TOOL, Field, Role, Schema, register, schema_of

    monkeypatch.setattr(schemas, "_REGISTRY", dict(schemas._REGISTRY))  # the probe kind stays in this test

    schema = Schema("test-probe", arms=1, measured=(Field("depth", "vector", LENGTH, size=1, columns=("depth",)),),
                    known=(Field("p_tool_tip", "vector", LENGTH, required=False, size=3),),
                    roles=(Role("tip", "p_tool_tip", TOOL, "point"),))
    register(schema)
    assert schema_of("test-probe") is schema and schema.role_keys == {"tip": "p_tool_tip"}
    ds = Dataset("test-probe", "ur10", ("arm",), {"arm": rng.normal(size=(3, 6))}, {"depth": np.zeros((3, 1))},
                 frames={"tip": "probe_tip"})
    assert ds.size == 3
    with pytest.raises(ShapeError, match=r"frames\.probe: expected a role of kind 'test-probe' \(tip\)"):
        Dataset("test-probe", "ur10", ("arm",), {"arm": rng.normal(size=(3, 6))}, {"depth": np.zeros((3, 1))},
                frames={"probe": "x"})
    with pytest.raises(ValueError, match="registered twice with different schemas"):
        register(Schema("test-probe", arms=2))
