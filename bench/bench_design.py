"""Designed against random configurations, measured by calibrating and validating (issue #11's anchor).

A UR10 with one tracker marker (sigma 0.05 mm, tracker and marker unknown, level kinematic): a pool of 5000
random configurations measured on a perturbed true robot; K of them chosen by kincal's design (on the nominal
model) or at random; each calibrated and validated on 200 fresh configurations (tool point, tracker refitted).
Mean validation RMS over the seeds, and the selection time. Also the time to choose 30 of 5000 and of 100,000
candidates for Frida's 7-DOF arm (3 markers, kinematic).

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python bench/bench_design.py [--seeds 20] [--large]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from kincal import robots  # noqa: E402
from kincal.estimation import Noise, calibrate  # noqa: E402
from kincal.simulate import generate_markers, perturb_robot  # noqa: E402
from kincal.workflow.design import choose, design  # noqa: E402

SIGMA = 5e-5


def validation_rms(nominal, chosen, validation) -> float:
    res = calibrate(nominal, [chosen], "kinematic", noise=Noise(position=SIGMA), validation=[validation])
    return res.validation[0].after.position_rms


def anchor(seeds: int, Ks=(18, 24, 30), criteria=("D", "I")) -> None:
    ur = robots.load("ur10")
    arm = next(iter(ur.arms))
    rows = {(K, c): [] for K in Ks for c in ("random",) + tuple(criteria)}
    times = {(K, c): [] for K in Ks for c in criteria}
    for s in range(seeds):
        true = perturb_robot(ur, "fine", rng=100 + s)
        pool, _, val = generate_markers(true, arm, n=5000, rng=s, noise=Noise(position=SIGMA), markers=1)
        rng = np.random.default_rng(1000 + s)
        for K in Ks:
            rows[(K, "random")].append(validation_rms(ur, pool.subset(rng.choice(pool.size, K, replace=False)),
                                                      val[arm]))
            for c in criteria:
                t = time.perf_counter()
                d = choose(ur, pool, K, free="kinematic", criterion=c, noise=Noise(position=SIGMA), seed=s)
                times[(K, c)].append(time.perf_counter() - t)
                rows[(K, c)].append(validation_rms(ur, d.dataset, val[arm]))
    print(f"| K | random (mm) | " + " | ".join(f"{c}-optimal (mm) | {c} select s" for c in criteria) + " |")
    print("| --- " * (2 + 2 * len(criteria)) + "|")
    for K in Ks:
        r = np.array(rows[(K, "random")]) * 1e3
        cells = [f"{r.mean():.3f} +- {r.std():.3f}"]
        for c in criteria:
            d = np.array(rows[(K, c)]) * 1e3
            cells += [f"{d.mean():.3f} +- {d.std():.3f}", f"{np.median(times[(K, c)]):.2f}"]
        print(f"| {K} | " + " | ".join(cells) + " |")


def speed(large: bool) -> None:
    fr = robots.load("frida")
    for pool in (5000,) + ((100_000,) if large else ()):
        t = time.perf_counter()
        d = design(fr, "markers", {"arm": "right", "markers": 3}, 30, free="kinematic", pool=pool,
                   noise=Noise(position=SIGMA))
        print(f"Frida right arm, 3 markers, kinematic (rank {d.rank}): 30 of {pool} in "
              f"{time.perf_counter() - t:.2f} s (pool, linearization and selection)")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--large", action="store_true", help="also 100,000 candidates")
    a = ap.parse_args()
    speed(a.large)
    anchor(a.seeds)
