"""Session 11 (helper d): a small calibration's costs outside the outer loop, cut without changing a result.

``_check_joint_screws`` tests an arm's screws on Python floats (the numpy sums' verdicts, the same messages);
``params.ops.displacement`` finds the blocks holding the wanted indices in one pass (``Layout.holding``): the
same displacement and Jacobian as the mask tested block by block."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from kincal.errors import ModelError
from kincal.estimation import Problem
from kincal.params.ops import displacement
from test_structure_cache import NOISE, ur10_sets  # noqa: F401  (the UR10 data sets, a fixture)

model = importlib.import_module("kincal.kinematics.model")


def _numpy_verdict(screws, types) -> bool:
    """The vectorized test ``_check_joint_screws`` ran before (True: every joint passes)."""
    v, w = screws[:, :3], screws[:, 3:]
    nw, nv, pitch = np.linalg.norm(w, axis=1), np.linalg.norm(v, axis=1), np.abs(np.einsum("ij,ij->i", w, v))
    rev = np.array([t == "revolute" for t in types])
    tol = model._UNIT_TOL
    bad_rev = rev & ((np.abs(nw - 1) > tol) | (pitch > tol))
    bad_pri = ~rev & ((nw > tol) | (np.abs(nv - 1) > tol))
    return not (bad_rev.any() or bad_pri.any())


def _screws(rng, types, err):
    """Unit zero-pitch revolute and unit prismatic screws, each entry moved by up to ``err``."""
    out = []
    for t in types:
        u = rng.standard_normal(3)
        u /= np.linalg.norm(u)
        p = rng.standard_normal(3)
        out.append(np.r_[np.cross(p, u), u] if t == "revolute" else np.r_[u, 0.0, 0.0, 0.0])
    return np.array(out) + err * rng.uniform(-1, 1, (len(types), 6))


@pytest.mark.parametrize("err", [0.0, 1e-11, 3e-10, 1e-9, 3e-9, 1e-6])
def test_joint_screw_check_gives_the_numpy_verdict(err):
    rng = np.random.default_rng(int(err * 1e12) + 3)
    types = ["revolute", "prismatic", "revolute", "revolute", "prismatic", "revolute"]
    names = [f"j{i}" for i in range(len(types))]
    for _ in range(200):
        S = _screws(rng, types, err)
        want = _numpy_verdict(S, types)
        try:
            model._check_joint_screws(S, types, names, "arm")
            got = True
        except ModelError:
            got = False
        assert got == want


def test_joint_screw_check_names_the_first_bad_joint():
    rng = np.random.default_rng(4)
    types = ["revolute", "prismatic", "revolute"]
    names = ["a", "b", "c"]
    S = _screws(rng, types, 0.0)
    tilted = S.copy()
    tilted[2, 3:] *= 1.01
    with pytest.raises(ModelError, match="joint c is revolute and needs a unit axis"):
        model._check_joint_screws(tilted, types, names, "arm")
    turned = tilted.copy()
    turned[1, 5] = 0.5
    with pytest.raises(ModelError, match="joint b is prismatic and needs w = 0"):
        model._check_joint_screws(turned, types, names, "arm")
    assert model._joint_screw_ok(S[0].tolist(), True) and not model._joint_screw_ok(S[0].tolist(), False)


def _masked_displacement(state, nominal, layout, only, jacobian=True):
    """``displacement`` as it was: a mask of the wanted indices tested block by block."""
    wanted = np.zeros(layout.size, bool)
    wanted[np.asarray(only, dtype=int)] = True
    disp, D = displacement(state, nominal, layout, None, jacobian)
    for b in layout.blocks:
        if not wanted[b.slice].any():
            disp[b.slice] = 0.0
            if D is not None:
                D[b.slice, b.slice] = 0.0
    return disp, D


def test_displacement_of_some_blocks_as_the_mask_gave(ur10_sets):
    from kincal.estimation import calibrate

    nominal, markers, pose = ur10_sets
    res = calibrate(nominal, [markers, pose], "kinematic", noise=NOISE)
    problem, layout = res.problem, res.layout
    rng = np.random.default_rng(8)
    cases = [problem.free_idx, np.arange(layout.size), np.zeros(0, int), [-1], [0, 0, 5], [layout.size - 1, 3]]
    cases += [rng.choice(layout.size, k, replace=False) for k in (1, 4, 20)]
    for only in cases:
        for jac in (True, False):
            got = displacement(res.state, problem.nominal, layout, only, jac)
            want = _masked_displacement(res.state, problem.nominal, layout, only, jac)
            assert got[0].tobytes() == want[0].tobytes()
            assert (got[1] is None) == (not jac) and (got[1] is None or got[1].tobytes() == want[1].tobytes())
    held = layout.holding([layout.size - 1, 0])
    assert held == [layout.blocks[0], layout.blocks[-1]]
    with pytest.raises(IndexError):
        displacement(res.state, problem.nominal, layout, [layout.size])
    assert isinstance(problem, Problem)
