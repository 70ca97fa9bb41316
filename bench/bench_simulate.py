"""Time to generate 1000 dual-arm closed-chain configurations of Frida (bracket clamp, thesis perturbation).

Run: python bench/bench_simulate.py
"""

from __future__ import annotations

import time

import numpy as np

from kincal.robots import load
from kincal.simulate import BRACKET_90, closure_error, generate_dual, perturb_robot


def main() -> None:
    true = perturb_robot(load("frida"), "thesis", rng=0)
    for label, workspace in (("free", None), ("clamp kept in front of the body",
                                              (np.array([0.25, -0.3, 0.05]), np.array([0.65, 0.3, 0.6])))):
        times = []
        for seed in range(3):
            t0 = time.perf_counter()
            ds, truth, _ = generate_dual(true, n=1000, rng=seed, workspace=workspace, n_validation=1)
            times.append(time.perf_counter() - t0)
        pos, rot = closure_error(true["left"], true["right"], BRACKET_90, truth.q["left"], truth.q["right"])
        print(f"dual arm, Frida, 1000 closed-chain configurations ({label}): best {min(times):.2f} s, "
              f"median {float(np.median(times)):.2f} s; max closure {pos.max():.1e} m, {rot.max():.1e} rad; "
              f"IK starts rejected {truth.meta['ik_starts_rejected']}/{truth.meta['ik_starts']}")


if __name__ == "__main__":
    main()
