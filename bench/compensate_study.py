"""Compensated targets against the true robot: the table of docs/deploy.md.

For each arm: a true robot with "fine" errors (1 mm, 0.1 deg, 0.01 rad), a full-pose tracker calibration from
150 configurations (0.02 mm, 0.02 mrad noise, tracker known), then a program of 10,000 random configurations
written for the nominal model. Errors of the tool point under the true robot against the intended (nominal)
pose: uncompensated (the program as written) and compensated (kincal compensate on the calibrated model), next
to the calibration's predicted error, and the compensation time.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python bench/compensate_study.py
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import time  # noqa: E402

import numpy as np  # noqa: E402

from kincal import robots  # noqa: E402
from kincal.estimation import Noise, calibrate  # noqa: E402
from kincal.kinematics import forward_kinematics  # noqa: E402
from kincal.simulate import generate_pose, perturb_robot, random_configurations  # noqa: E402
from kincal.workflow.compensate import compensate_joints  # noqa: E402

NOISE = Noise(position=2e-5, orientation=2e-5)
CASES = (("ur10", "arm"), ("panda", "arm"), ("frida", "right"))


def row(name: str, arm: str, seed: int = 5, n: int = 10_000) -> str:
    nominal = robots.load(name)
    true = perturb_robot(nominal, "fine", rng=seed)
    ds, _, _ = generate_pose(true, arm, n=150, rng=seed + 1, noise=NOISE, known_tracker=True)
    res = calibrate(nominal, [ds], "kinematic", noise=NOISE)
    q = random_configurations(nominal[arm], n, np.random.default_rng(seed), 0.1)
    t = time.perf_counter()
    comp = compensate_joints(nominal, res.robot, {arm: q})
    took = time.perf_counter() - t
    ok = comp.status[arm] == "ok"
    intended = forward_kinematics(nominal[arm], q)[:, :3, 3]
    before = np.linalg.norm(forward_kinematics(true[arm], q)[:, :3, 3] - intended, axis=1)
    after = np.linalg.norm(forward_kinematics(true[arm], comp.q[arm])[:, :3, 3] - intended, axis=1)
    pred = res.predict(q[ok][:1000], arm, register=False).position_rms_predicted
    counts = {s: int(np.sum(comp.status[arm] == s)) for s in ("ok", "unreachable", "branch changed", "limit")}
    rms = lambda x: np.sqrt(np.mean(x**2)) * 1e3  # noqa: E731
    return (f"| {name} ({arm}) | {rms(before[ok]):.3f} / {before[ok].max() * 1e3:.3f} | {rms(after[ok]):.4f} / "
            f"{after[ok].max() * 1e3:.4f} | {pred * 1e3:.4f} | {counts['ok']} / {counts['unreachable']} / "
            f"{counts['branch changed']} / {counts['limit']} | {took:.2f} |")


if __name__ == "__main__":
    print("| arm | uncompensated RMS / max (mm) | compensated RMS / max (mm) | predicted RMS (mm) | ok / unreachable "
          "/ branch changed / limit | compensate 10,000 s |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name, arm in CASES:
        print(row(name, arm))
