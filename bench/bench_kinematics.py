"""Time forward kinematics (100,000 configurations) and the identification Jacobian (10,000) of a 7-DOF arm.

Run: python bench/bench_kinematics.py
"""

from __future__ import annotations

import time

import numpy as np

from kincal.baselines.identification import identification_jacobian
from kincal.kinematics import forward_kinematics
from kincal.testing import random_arm


def best_of(fn, repeat=5):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times), float(np.median(times))


def main() -> None:
    rng = np.random.default_rng(0)
    arm = random_arm(rng, 7)
    q_fk = rng.uniform(-np.pi, np.pi, (100_000, 7))
    q_id = rng.uniform(-np.pi, np.pi, (10_000, 7))
    best, med = best_of(lambda: forward_kinematics(arm, q_fk))
    print(f"FK, 7-DOF, 100000 configurations: best {best * 1e3:.1f} ms, median {med * 1e3:.1f} ms "
          f"({best / 1e5 * 1e6:.2f} us/config)")
    best, med = best_of(lambda: identification_jacobian(arm, q_id))
    print(f"identification Jacobian (all blocks, 6 x 67), 7-DOF, 10000 configurations: best {best * 1e3:.1f} ms, "
          f"median {med * 1e3:.1f} ms ({best / 1e4 * 1e6:.2f} us/config)")


if __name__ == "__main__":
    main()
