"""A known distance between two frames (two sockets 50 mm apart): Jacobian, recovery, errors, job files."""

from dataclasses import replace

import numpy as np
import pytest
import yaml

from kincal import robots
from kincal.cli import main
from kincal.errors import DataFormatError, ModelError
from kincal.estimation import FrameDistance, calibrate
from kincal.estimation import Problem
from kincal.io.datasets import write_dataset
from kincal.io.jobs import load_job
from kincal.kinematics import forward_kinematics
from kincal.simulate import generate_socket, perturb_robot
from kincal.testing import numerical_jacobian

APART = 0.05


@pytest.fixture(scope="module")
def two_sockets():
    """A Panda with thesis-size errors, its tool ball held in two sockets 50 mm apart (noise-free)."""
    panda = robots.load("panda")
    true = perturb_robot(panda, "thesis", rng=1)
    ds1, t1, _ = generate_socket(true, n=40, rng=2)
    p2 = t1.values["p_world_socket"] + np.array([APART, 0.0, 0.0])
    ds2, _, _ = generate_socket(true, n=40, rng=3, p_world_socket=p2)
    return panda, true, [replace(ds1, name="s1"), replace(ds2, name="s2")]


def _pairwise(points):
    return np.linalg.norm(points[:, None] - points[None], axis=-1)


def test_constraint_jacobian_matches_differences(two_sockets, rng):
    panda, _, sets = two_sockets
    c = FrameDistance("s1.socket", "s2.socket", APART, 1e-4)
    problem = Problem.build(panda, sets, ["kinematic"], constraints=[c])
    W = problem.whiteners(problem.nominal)
    d0 = rng.normal(scale=1e-3, size=len(problem.free_idx))  # away from the linearization point
    r, J = problem.evaluate(problem.nominal, d0, W)
    num = numerical_jacobian(lambda d: problem.evaluate(problem.nominal, d, W, jac=False)[0], d0)
    np.testing.assert_allclose(J[-1], num[-1], atol=1e-6 * np.abs(num[-1]).max())
    assert abs(r[-1]) > 0  # the constraint row is there and not trivially satisfied


def test_two_sockets_at_a_known_distance_identify_the_arm_size(two_sockets):
    """Without the distance no length is measured: scale is held and reported. With it the arm's relative
    geometry, size included, is recovered exactly from joint readings alone."""
    panda, true, sets = two_sockets
    free = calibrate(panda, sets, "kinematic")
    assert free.identifiability.scale_unidentifiable
    res = calibrate(panda, sets, "kinematic", constraints=[FrameDistance("s1.socket", "s2.socket", APART, 1e-6)])
    assert res.status == "converged" and not res.identifiability.scale_unidentifiable
    assert not any(m.startswith("scale cannot") for m in res.messages)
    q = np.random.default_rng(0).uniform(-1, 1, (30, 7))
    pe = forward_kinematics(res.robot["arm"], q)[:, :3, 3]
    pt = forward_kinematics(true["arm"], q)[:, :3, 3]
    np.testing.assert_allclose(_pairwise(pe), _pairwise(pt), atol=1e-9)
    assert np.linalg.norm(res.extras["s1.socket"] - res.extras["s2.socket"]) == pytest.approx(APART, abs=1e-12)


def test_bad_constraints_are_named(two_sockets):
    panda, _, sets = two_sockets
    with pytest.raises(ModelError, match=r"'s3.socket' is no frame .* frames: s1.socket, s2.socket"):
        calibrate(panda, sets, "offsets", constraints=[FrameDistance("s1.socket", "s3.socket", APART, 1e-6)])
    with pytest.raises(ModelError, match="distance must be > 0"):
        calibrate(panda, sets, "offsets", constraints=[FrameDistance("s1.socket", "s2.socket", 0.0, 1e-6)])
    with pytest.raises(ModelError, match="expected two different frames"):
        calibrate(panda, sets, "offsets", constraints=[FrameDistance("s1.socket", "s1.socket", APART, 1e-6)])


def test_job_file_constraints(tmp_path, two_sockets):
    panda, true, sets = two_sockets
    for ds in sets:
        write_dataset(ds, tmp_path / f"{ds.name}.yaml", panda, model="panda")
    job = {"model": "panda", "data": ["s1.yaml", "s2.yaml"], "free": "kinematic",
           "constraints": [{"distance": ["s1.socket", "s2.socket"], "value_mm": 50, "sigma_mm": 0.001}]}
    (tmp_path / "job.yaml").write_text(yaml.safe_dump(job))
    (c,) = load_job(tmp_path / "job.yaml").constraints
    assert (c.a, c.b, c.distance, c.sigma) == ("s1.socket", "s2.socket", pytest.approx(APART), pytest.approx(1e-6))
    assert main(["calibrate", str(tmp_path / "job.yaml"), "-o", str(tmp_path / "out"), "--quiet"]) == 0
    for bad, message in (({"distance": ["s1.socket"], "value_mm": 50, "sigma_mm": 1}, "must name two frames"),
                         ({"distance": ["s1.socket", "s2.socket"], "value_mm": 50}, "expected value_<unit> and sigma"),
                         ({"distance": ["s1.socket", "s2.socket"], "value_mm": -1, "sigma_mm": 1}, "positive number"),
                         ({"distance": ["s1.socket", "s2.socket"], "value_furlong": 1, "sigma_mm": 1}, "furlong")):
        (tmp_path / "bad.yaml").write_text(yaml.safe_dump({**job, "constraints": [bad]}))
        with pytest.raises(DataFormatError) as err:
            load_job(tmp_path / "bad.yaml")
        assert "bad.yaml: constraints[0]" in str(err.value) and message in str(err.value)
