"""Session 12, round 2 (helper d2): the end of a calibration in fewer Python/numpy calls, bit for bit.

``ArmModel.replace``'s geometric path gives the model (and the errors) the full validation gives;
``values.arm_replace`` (used by ``retract_twists``) is ``dataclasses.replace`` of an ``ArmValues``; ``finalize._joint_sensitivity`` takes a
C-ordered Jacobian as it is where every row is of one quantity (the copy ``j[:, rows]`` made is the same)."""

from __future__ import annotations

import dataclasses
import importlib

import numpy as np
import pytest

from kincal.errors import ModelError
from kincal.estimation import calibrate
from kincal.kinematics import ArmModel
from kincal.noise import Noise
from test_structure_cache import ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)

model_module = importlib.import_module("kincal.kinematics.model")
values_module = importlib.import_module("kincal.params.values")
finalize_module = importlib.import_module("kincal.estimation.finalize")
NOISE = Noise(position=5e-5, orientation=1e-4, joint=0.0)


def _bits(x) -> bytes:
    return np.asarray(x, float).tobytes()


def _same_model(a: ArmModel, b: ArmModel) -> None:
    assert a.__dict__.keys() == b.__dict__.keys()
    for k, v in a.__dict__.items():
        w = b.__dict__[k]
        if isinstance(v, np.ndarray):
            assert v.dtype == w.dtype and _bits(v) == _bits(w) and v.flags.writeable == w.flags.writeable, k
        else:
            assert repr(v) == repr(w), k


def _changes(model: ArmModel, rng) -> dict:
    a = values_module.ArmValues.from_model(model)
    home = model.home.copy()
    home[:3, 3] += rng.normal(scale=1e-3, size=3)
    return dict(screws=model.screws + rng.normal(scale=1e-15, size=model.screws.shape), offsets=a.offsets + 1e-3,
                base=model.base, home=home, tool=model.tool.copy(), compliance=np.abs(rng.normal(size=model.dof)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_geometric_replace_is_the_full_validation(ur10_sets, seed):
    nominal = ur10_sets[0]
    model = nominal.arms["arm"]
    changes = _changes(model, np.random.default_rng(seed))
    got = model.replace(**changes)
    want = dataclasses.replace(model, **changes)
    _same_model(got, want)
    assert got.base is model.base  # the same bits: the checked frozen copy kept
    for key in ("screws", "offsets", "compliance", "home", "tool"):
        assert getattr(got, key) is not changes[key] and not getattr(got, key).flags.writeable
    # a field left out is this model's (checked with it), the compliance check too
    _same_model(model.replace(offsets=changes["offsets"]), dataclasses.replace(model, offsets=changes["offsets"]))


@pytest.mark.parametrize("key, bad", [("offsets", np.inf), ("offsets", np.nan), ("compliance", np.nan),
                                      ("compliance", -np.inf), ("compliance", -1e-12)])
def test_geometric_replace_refuses_what_the_full_validation_refuses(ur10_sets, key, bad):
    model = ur10_sets[0].arms["arm"]
    v = np.zeros(model.dof)
    v[3] = bad
    with pytest.raises(ModelError) as full:
        dataclasses.replace(model, **{key: v})
    with pytest.raises(ModelError) as fast:
        model.replace(**{key: v})
    assert str(fast.value) == str(full.value)


def test_negative_compliance_allowed_where_the_model_allows_it(ur10_sets):
    model = dataclasses.replace(ur10_sets[0].arms["arm"], allow_negative_compliance=True)
    k = -np.ones(model.dof) * 1e-6
    _same_model(model.replace(compliance=k), dataclasses.replace(model, compliance=k))
    assert model_module._all_finite(np.zeros(3)) and not model_module._all_finite(np.array([0.0, np.nan]))


def test_replaced_is_dataclasses_replace(ur10_sets):
    a = values_module.ArmValues.from_model(ur10_sets[0].arms["arm"])
    a.basis  # a cached property: never carried over to the copy
    changes = dict(screws=a.screws * 1.0, bases=None, generators=None, lateral_axes=None)
    got, want = values_module.arm_replace(a, **changes), dataclasses.replace(a, **changes)
    assert type(got) is values_module.ArmValues and "basis" not in got.__dict__
    assert got.__dict__.keys() == want.__dict__.keys()
    assert all(got.__dict__[k] is want.__dict__[k] for k in want.__dict__)
    with pytest.raises(dataclasses.FrozenInstanceError):
        got.screws = a.screws


def _sensitivity_reference(jq: dict, comps) -> dict:
    """Round 1's ``_joint_sensitivity`` body: the rows of each quantity copied out by a boolean mask."""
    out = {}
    for q in dict.fromkeys(comps):
        rows = np.array([c == q for c in comps], bool)
        means = [finalize_module._mean_square(j[:, rows]) for j in jq.values()]
        out[q] = float(np.sqrt(means[0] if len(means) == 1 else np.mean(means))) if jq else 0.0
    return out


@pytest.mark.parametrize("which", [1, 2])
def test_joint_sensitivity_of_any_layout_is_the_masked_copys(ur10_sets, which, monkeypatch):
    """Markers (position rows only: the Jacobian taken as it is) and pose (two quantities: masked), with C-ordered,
    Fortran-ordered and strided Jacobians."""
    nominal, *sets = ur10_sets
    res = calibrate(nominal, [sets[which - 1]], "kinematic", noise=NOISE)
    exp, state = res.problem.experiments[0], res.state
    comps = exp.components()
    j = next(iter(exp.residual(state, want=set(), jq=True).jq.values()))
    strided = np.repeat(j, 2, axis=0)[::2]
    for jq in ({"arm": j}, {"arm": np.asfortranarray(j)}, {"arm": strided, "b": 3 * j[::-1]}):
        monkeypatch.setattr(finalize_module, "offset_columns", lambda *a, jq=jq: jq)
        got = finalize_module._joint_sensitivity(exp, state, comps)
        want = _sensitivity_reference(jq, comps)
        assert {q: _bits(v) for q, v in got.items()} == {q: _bits(v) for q, v in want.items()}
