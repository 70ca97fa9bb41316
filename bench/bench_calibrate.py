"""Calibrate Frida's two clamped arms from 1000 configurations: both arms' full POE (offsets, twists, home) and
the clamp. Reports wall time, iterations, and the speed ratio of the analytic Jacobian against scipy's
finite-difference Jacobian on the same inner solve (same start, same gauge, same tolerances).

Run: python bench/bench_calibrate.py [--n 1000]

(b), a 6-DOF arm against FIGAROH, is bench/bench_figaroh.py.
"""

from __future__ import annotations

import argparse
import os
import time

# Single-threaded BLAS unless asked otherwise: on a small shared machine OpenBLAS threads spin against each
# other on these small matrices and make timings (of both solves) slower and erratic.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from scipy.optimize import least_squares

from kincal.analysis import analyse
from kincal.estimation import calibrate
from kincal.estimation.solver import _problem
from kincal.robots import load
from kincal.simulate.generators import generate_dual
from kincal.simulate.perturb import perturb_robot


def inner_solve(problem, jac: str):
    """One inner least-squares solve from the nominal state, restricted to the identifiable subspace."""
    state = problem.nominal
    p = len(problem.free_idx)
    W = problem.whiteners(state)
    _, J0 = problem.evaluate(state, np.zeros(p), W)
    V = analyse(J0, problem.free_names).range_space
    fun = lambda z: problem.evaluate(state, V @ z, W, jac=False)[0]  # noqa: E731
    kw = dict(method="lm", x_scale=1.0, ftol=1e-10, xtol=1e-10, gtol=1e-10)  # as the solver
    t0 = time.perf_counter()
    if jac == "analytic":
        sol = least_squares(fun, np.zeros(V.shape[1]), jac=lambda z: problem.evaluate(state, V @ z, W)[1] @ V, **kw)
    else:
        sol = least_squares(fun, np.zeros(V.shape[1]), jac="2-point", **kw)
    return time.perf_counter() - t0, sol


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1000)
    args = ap.parse_args()
    frida = load("frida")
    true = perturb_robot(frida, "thesis", 1)
    t0 = time.perf_counter()
    ds, truth, _ = generate_dual(true, n=args.n, rng=2, known_clamp=False)
    print(f"simulated {ds.size} clamped configurations in {time.perf_counter() - t0:.1f} s")

    free = ["kinematic", "clamp"]
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        res = calibrate(frida, [ds], free)
        times.append(time.perf_counter() - t0)
    ana = res.identifiability
    print(f"kincal calibrate: {len(ana.names)} free parameters, rank {ana.rank}, status {res.status}, "
          f"{res.iterations} outer iterations, {res.evaluations} residual evaluations; "
          f"wall time best {min(times):.3f} s, median {np.median(times):.3f} s")
    closure = max(s["position_max"] for s in res.after)
    print(f"  max closure after calibration: {closure * 1e3:.2e} mm")

    problem, _ = _problem(frida, [ds], free, (), None, None)
    print(f"BLAS threads: OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")
    ta, sa = min((inner_solve(problem, "analytic") for _ in range(3)), key=lambda t: t[0])
    tf, sf = inner_solve(problem, "2-point")
    print(f"inner solve, analytic Jacobian: {ta:.3f} s ({sa.nfev} evaluations, cost {sa.cost:.3e})")
    print(f"inner solve, scipy 2-point Jacobian: {tf:.3f} s ({sf.nfev} evaluations, cost {sf.cost:.3e})")
    print(f"speed ratio (finite differences / analytic): {tf / ta:.1f}x")


if __name__ == "__main__":
    main()
