"""Designed against random configurations, measured by calibrating and validating (issue #11's anchor).

A UR10 with one tracker marker (sigma 0.05 mm, tracker and marker unknown, level kinematic): a pool of 5000
random configurations measured on a perturbed true robot; K of them chosen by kincal's design (on the nominal
model) or at random; each calibrated and validated on 200 fresh configurations (tool point, tracker refitted).
Mean validation RMS over the seeds, and the selection time. First the speed targets: the time to choose 30 of
5000 and of 100,000 candidates for Frida's 7-DOF arm (3 markers, kinematic), next to the targets, the figures
before the branch-and-bound exchange and (``--reference``) the log det of the exhaustive exchange.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python bench/bench_design.py [--seeds 20] [--large]
        [--reference] [--speed-only]
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
from kincal.analysis.design import (D_GAIN, MAX_PASSES, RIDGE, _logdet_plus_identity, _LogDet,  # noqa: E402
                                    information, select)
from kincal.estimation import Problem, SolverOptions  # noqa: E402
from kincal.estimation.plan import identifiable_basis, plan  # noqa: E402
from kincal.workflow.design import _candidate_rows, candidate_pool, choose, design  # noqa: E402

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


# The speed targets (issue #11) and the figures of the implementation before the branch-and-bound exchange
# (commit 7a4b8cf: greedy and Fedorov exchange scoring the whole pool at every step), same pools, seed 0.
TARGETS = {5000: 2.0, 100_000: 30.0}
BEFORE = {5000: (2.4, 828.850), 100_000: (64.0, 829.378)}  # (seconds, log det) as measured then


def reference_exchange(X, K) -> float:
    """log det of the earlier method: the full greedy, then exchange passes scoring every candidate of the pool
    at every position (exhaustive; what the branch and bound must match or beat)."""
    sel = select(X, K, "D", exchange=False)
    N, _, r = X.shape
    M0 = RIDGE * np.trace(information(X)) / (N * r) * np.eye(r)
    chosen = list(sel.indices)
    st = _LogDet(X, M0 + information(X[chosen]))
    for _ in range(MAX_PASSES):
        changed = False
        for pos in range(K):
            Binv, logdet = st.removed(chosen[pos])
            gains = _logdet_plus_identity(st.gram(Binv))
            gains[chosen] = -np.inf
            j = int(np.argmax(gains))
            if logdet + gains[j] > st.logdet + D_GAIN:
                st.add(chosen[pos], -1.0)
                st.add(j)
                chosen[pos], changed = j, True
        st.reset(st.M)
        if not changed:
            break
    return st.logdet


def speed(large: bool, reference: bool) -> None:
    """Frida's right arm, 3 markers, level kinematic: 30 of 5000 (and 100,000) candidates, against the targets."""
    fr = robots.load("frida")
    print("| pool | rank | design() s (CPU s) | target s | selection s | log det | before: s, log det | exhaustive "
          "exchange log det |")
    print("| --- " * 8 + "|")
    for pool in (5000,) + ((100_000,) if large else ()):
        t, c = time.perf_counter(), time.process_time()
        d = design(fr, "markers", {"arm": "right", "markers": 3}, 30, free="kinematic", pool=pool,
                   noise=Noise(position=SIGMA))
        t1, c1 = time.perf_counter(), time.process_time()
        ds = candidate_pool(fr, "markers", {"arm": "right", "markers": 3}, pool, 0)
        problem = Problem.build(fr, [ds], "kinematic", noise=Noise(position=SIGMA))
        p = plan(problem, SolverOptions())
        X = _candidate_rows(problem, p, identifiable_basis(problem, p.identifiability))
        t2 = time.perf_counter()
        select(X, 30, "D")
        t3 = time.perf_counter()
        ref = f"{reference_exchange(X, 30):.3f}" if reference and pool <= 5000 else "-"
        print(f"| {pool} | {d.rank} | {t1 - t:.2f} ({c1 - c:.2f}) | {TARGETS[pool]:.0f} | {t3 - t2:.2f} | "
              f"{d.selection.value:.3f} | {BEFORE[pool][0]:.1f}, {BEFORE[pool][1]:.3f} | {ref} |")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--large", action="store_true", help="also 100,000 candidates")
    ap.add_argument("--reference", action="store_true", help="also the exhaustive exchange on 5000 (slow)")
    ap.add_argument("--speed-only", action="store_true", help="only the speed table")
    a = ap.parse_args()
    speed(a.large, a.reference)
    if not a.speed_only:
        anchor(a.seeds)
