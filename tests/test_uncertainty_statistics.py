"""With encoder noise (1e-5 rad), estimate errors divided by their reported standard deviations have unit spread.

200 seeded repetitions each of two rows of the issue's table (offsets level): one clamp of known pose, and the
dual arm with a known clamp. The configurations are simulated once; each repetition draws new joint noise.
"""

import numpy as np
import pytest

from kincal.data import Dataset
from kincal.estimation import Noise, calibrate
from kincal.kinematics import Robot
from kincal.robots import load
from kincal.simulate.generators import generate_clamp, generate_dual
from kincal.simulate.noise import Noise as SimNoise
from kincal.simulate.noise import joint_readings
from kincal.simulate.perturb import perturb_robot

SIGMA_Q = 1e-5
REPS = 200


@pytest.fixture(scope="module")
def truth():
    frida = load("frida")
    true = perturb_robot(frida, "thesis", 11)
    return frida, Robot(frida.name, {k: frida[k].replace(offsets=true[k].offsets) for k in frida.arms})


def _z_scores(frida, true, ds, arms, seed):
    rng = np.random.default_rng(seed)
    sim = SimNoise(joint=SIGMA_Q)
    z = []
    for _ in range(REPS):
        q = {a: joint_readings(ds.q[a], sim, rng) for a in ds.arms}
        noisy = Dataset(ds.kind, ds.robot, ds.arms, q, ds.measured, ds.known, ds.name)
        res = calibrate(frida, [noisy], "offsets", noise=Noise(position=0.0, orientation=0.0,
                                                               joint=SIGMA_Q))
        assert res.status == "converged"
        for a in arms:
            for i in range(7):
                e = res.estimate(f"{a}.j{i + 1}.offset")
                z.append((e.value - true[a].offsets[i]) / e.std)
    return np.array(z)


def test_clamp_known_pose_errors_match_reported_std(truth):
    frida, true = truth
    ds, _, _ = generate_clamp(true, "right", n=12, rng=21, known_fixture=True)
    z = _z_scores(frida, true, ds, ["right"], 1)
    assert 0.8 <= np.std(z) <= 1.25
    assert abs(np.mean(z)) < 0.2


def test_dual_known_clamp_errors_match_reported_std(truth):
    frida, true = truth
    ds, _, _ = generate_dual(true, n=12, rng=22, known_clamp=True)
    z = _z_scores(frida, true, ds, ["left", "right"], 2)
    assert 0.8 <= np.std(z) <= 1.25
    assert abs(np.mean(z)) < 0.2
