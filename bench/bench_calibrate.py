"""Calibrate Frida's two clamped arms from 1000 configurations: both arms' full POE (offsets, twists, home) and
the clamp. Reports wall time, iterations, and the speed ratio against the same solve with scipy's
finite-difference Jacobian (issue 4, bench (a)). All runs start from the nominal model on the same data.

* kincal: ``calibrate`` as users call it (rank analysis, Gauss-Newton re-linearizations with least_squares
  as the fallback, covariance, identifiability report), analytic Jacobians.
* scipy FD: the same least-squares problem (same whitened residual function, the same free coordinates,
  the same start) handed to ``scipy.optimize.least_squares`` with ``jac="2-point"`` (methods lm and trf).
  That is what a user gets without analytic Jacobians; it has no rank analysis or gauge.
* kincal FD: ``calibrate`` itself with every Jacobian it needs taken by scipy's 2-point differences
  (``approx_derivative`` for the linearizations, ``jac="2-point"`` in the inner ``least_squares``). With the
  default rank tolerance the differences' truncation error hides the 33 gauge directions (rank 88, not 55)
  and the solve takes another path; with ``rank_rtol=1e-7`` it takes kincal's path, which isolates the
  Jacobians' share of the time.
* per Jacobian: one analytic linearization (every column) against 2-point differences of the free columns.

Run: python bench/bench_calibrate.py [--n 1000] [--repeat 3] [--quick]

(b), a 6-DOF arm against FIGAROH, is bench/bench_figaroh.py.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
import time

# Single-threaded BLAS unless asked otherwise: on a small shared machine OpenBLAS threads spin against each
# other on these small matrices and make timings (of both solves) slower and erratic.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402
from scipy.optimize._numdiff import approx_derivative  # noqa: E402

from kincal.estimation import calibrate, steps  # noqa: E402
from kincal.estimation.problem import Problem  # noqa: E402
from kincal.params import retract  # noqa: E402
from kincal.robots import load  # noqa: E402
from kincal.simulate.generators import generate_dual  # noqa: E402
from kincal.simulate.perturb import perturb_robot  # noqa: E402


def _fd_linearize(self: Problem, state, whiteners=None, cols=None):
    """Problem.linearize with the parameter Jacobian by 2-point differences (the whitening, which propagates
    encoder noise through J_q, is the same in both runs)."""
    W = self.whiteners(state) if whiteners is None else whiteners
    cols = self.free_idx if cols is None else np.asarray(cols)

    def f(d):
        full = np.zeros(self.layout.size)
        full[cols] = d
        s = retract(state, self.layout, full)
        return self._stack(s, [e.residual(s, want=set(), jq=False) for e in self.experiments], W, None, {})[0]

    r = f(np.zeros(len(cols)))
    raw = [res.r for res in self.residuals(state)]
    return r, approx_derivative(f, np.zeros(len(cols)), method="2-point", f0=r), W, raw


@contextlib.contextmanager
def finite_differences():
    """Every Jacobian of ``calibrate`` by scipy's finite differences."""
    saved = Problem.linearize, steps.inner_solve
    Problem.linearize = _fd_linearize
    steps.inner_solve = functools.partial(saved[1], jac="2-point")
    try:
        yield
    finally:
        Problem.linearize, steps.inner_solve = saved


def timed(fn, repeat: int):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def plain_fd(problem, method: str):
    """scipy's least_squares with 2-point differences on kincal's whitened residual over the free coordinates."""
    W = problem.whiteners(problem.nominal)
    p = len(problem.free_idx)
    fun = lambda d: problem.evaluate(problem.nominal, d, W, jac=False)[0]  # noqa: E731
    sol = least_squares(fun, np.zeros(p), jac="2-point", method=method, ftol=1e-10, xtol=1e-10, gtol=1e-10)
    return sol


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=3, help="best of this many runs (analytic)")
    ap.add_argument("--quick", action="store_true", help="skip the slow scipy FD solves")
    args = ap.parse_args()
    frida = load("frida")
    true = perturb_robot(frida, "thesis", 1)
    t0 = time.perf_counter()
    ds, truth, _ = generate_dual(true, n=args.n, rng=2, known_clamp=False)
    print(f"simulated {ds.size} clamped configurations in {time.perf_counter() - t0:.1f} s")
    print(f"BLAS threads: OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")
    free = ["kinematic", "clamp"]

    def line(label, t, res):
        ana = res.identifiability
        closure = max(s.position_max for s in res.after)
        return (f"{label}: {t:.3f} s; rank {ana.rank} of {len(ana.names)}, {res.status}, {res.iterations} outer "
                f"iterations, {res.evaluations} inner evaluations, max closure {closure * 1e3:.2e} mm")

    ta, res = timed(functools.partial(calibrate, frida, [ds], free), args.repeat)
    print(line("kincal, analytic Jacobians", ta, res))
    problem = Problem.build(frida, [ds], free)
    if not args.quick:
        for method in ("lm", "trf"):
            tf, sol = timed(functools.partial(plain_fd, problem, method), 1)
            print(f"scipy least_squares {method}, jac='2-point', {len(problem.free_idx)} free coordinates: "
                  f"{tf:.3f} s; {sol.nfev} evaluations, cost {sol.cost:.3e}, status {sol.status}; "
                  f"ratio {tf / ta:.1f}x")
        for rtol in (1e-9, 1e-7):
            with finite_differences():
                tk, rk = timed(functools.partial(calibrate, frida, [ds], free, rank_rtol=rtol), 1)
            print(line(f"kincal, finite-difference Jacobians, rank_rtol {rtol:g}", tk, rk) + f"; ratio {tk / ta:.1f}x")
    every = np.arange(problem.layout.size)
    tj, _ = timed(lambda: problem.linearize(problem.nominal, None, every), args.repeat)
    W = problem.whiteners(problem.nominal)
    fun = lambda d: problem.evaluate(problem.nominal, d, W, jac=False)[0]  # noqa: E731
    z = np.zeros(len(problem.free_idx))
    td, _ = timed(lambda: approx_derivative(fun, z, method="2-point", f0=fun(z)), 1)
    print(f"one Jacobian: analytic, all {len(every)} columns {tj * 1e3:.1f} ms; 2-point differences, "
          f"{len(z)} free columns {td * 1e3:.1f} ms; ratio {td / tj:.1f}x")


if __name__ == "__main__":
    main()
