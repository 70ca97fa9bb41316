"""FIGAROH 1.0.2's configuration selection on a pool given as regressor rows (run by bench/design_figaroh.py).

Runs in FIGAROH's own virtualenv and imports neither kincal nor anything of this repository. Input: an .npz
with ``X`` (N, k, r), the candidates' whitened residual rows on the identifiable subspace. Each candidate's
information matrix ``X_i^T X_i`` goes to FIGAROH in the form its ``BaseOptimalCalibration.sub_info_matrix``
produces (a dict index -> (r, r) array), and then to one of:

- ``detmax``: ``figaroh.optimal.base_optimal_calibration.Detmax(pool, K).main_algo()`` (its exchange method,
  random start from Python's ``random``, seeded here). ``main_algo`` returns only the criterion history; the
  chosen set is the argument of its last ``get_critD`` call (the set after the final exchange), which a
  subclass records without changing anything else.
- ``socp``: ``SOCPOptimizer(pool, {"NbSample": N}).solve()`` (picos + cvxopt, max det(sum w_i X_i)^(1/r) with
  sum w <= 1, w >= 0); output the weights' order (FIGAROH's ``w_dict_sort``) and the weights.
- ``footprint``: neither; the process's own memory with FIGAROH imported and the pool built (subtracted from
  the SOCP's peak memory before projecting it to larger pools).

Output: a JSON file with the chosen indices, the wall and CPU time of the call, the peak resident memory
of this process (``ru_maxrss``) and FIGAROH's own figures (criterion history, weights).

    /tmp/venv-figaroh/bin/python bench/figaroh_select_worker.py detmax|socp|footprint IN.npz OUT.json [--k K] [--seed S]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import random  # noqa: E402
import resource  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402

with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # pinocchio/ndcurves converter warnings at import
    from figaroh.optimal.base_optimal_calibration import Detmax, SOCPOptimizer  # noqa: E402


class RecordingDetmax(Detmax):
    """FIGAROH's Detmax; remembers the set of its last criterion evaluation (the final design)."""

    last: list = []

    def get_critD(self, set):  # noqa: A002 (FIGAROH's signature)
        self.last = list(set)
        return super().get_critD(set)


def info_pool(X: np.ndarray) -> dict:
    """Per-candidate information matrices, FIGAROH's ``subX_dict`` layout."""
    return {i: X[i].T @ X[i] for i in range(len(X))}


def run_detmax(pool: dict, K: int, seed: int) -> dict:
    random.seed(seed)
    d = RecordingDetmax(pool, K)
    history = d.main_algo()
    return {"indices": [int(i) for i in d.last], "critD": [float(c) for c in history]}


def run_socp(pool: dict, N: int) -> dict:
    w_list, w_sorted = SOCPOptimizer(pool, {"NbSample": N}).solve()
    return {"indices": [int(i) for i in w_sorted], "weights": [float(w) for w in w_list]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("method", choices=("detmax", "socp", "footprint"))
    ap.add_argument("inp")
    ap.add_argument("out")
    ap.add_argument("--k", type=int, default=15)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    logging.getLogger("figaroh").setLevel(logging.WARNING)
    X = np.load(a.inp)["X"]
    pool = info_pool(X)  # not timed: FIGAROH's sub_info_matrix step
    t0, c0 = time.perf_counter(), time.process_time()
    if a.method == "detmax":
        out = run_detmax(pool, a.k, a.seed)
    else:
        out = run_socp(pool, len(X)) if a.method == "socp" else {"indices": []}
    out.update(seconds=time.perf_counter() - t0, cpu_seconds=time.process_time() - c0,
               peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, n=len(X), k=a.k)
    with open(a.out, "w") as f:
        json.dump(out, f)


if __name__ == "__main__":
    main()
