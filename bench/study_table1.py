"""Paper Table I (partial-pose calibration, seed 001) with ``kincal study``: the shipped study ``table1`` with
1000 repeats and two variants (approach 2, markers; approach 1, the pose fitted to them with its covariance) on
a local Dask cluster, timed from the call to the table (the cluster's start included). Prints kincal's
standard deviations next to the paper's and, with --profile, one klimchik3r calibration's cost with the
structure caches emptied before each call and remembered (docs/partial-pose.md "Speed").

After the study: the CPU time of all its processes (this one, the fork server with the Dask workers) and the
CPU the machine's other jobs used meanwhile, and when the local cluster was up with how many tasks this process
ran meanwhile (``kincal.workflow.parallel``'s log).

With --cpu N, first the CPU time of N repeats run in this process (no Dask, both variants): the per-repeat cost
without the cluster, steadier than the wall time on a shared machine (--repeats 0: that alone, no study).

Run: python bench/study_table1.py [--workers 2] [--repeats 1000] [--variants approach2,approach1] [--profile]
     [--cpu 200]
The target (issue #13): under 10 s on a 2-core machine for 1000 repeats and two variants.
"""

from __future__ import annotations

import argparse
import logging
import os
import time
from dataclasses import replace

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import psutil  # noqa: E402  (Dask's dependency)

from kincal import params  # noqa: E402
from kincal.analysis import symmetries  # noqa: E402
from kincal.estimation import plausibility  # noqa: E402
from kincal.lie import se3  # noqa: E402
from kincal.workflow import study as S  # noqa: E402

# Table I of the paper: standard deviations (dl in mm, dq in mdeg).
PAPER = {"approach1": {"dl1": 0.069, "dl2": 0.019, "dl3": 0.009, "dq1": 0.187, "dq2": 3.742, "dq3": 1.432},
         "approach2": {"dl1": 0.018, "dl2": 0.006, "dl3": 0.004, "dq1": 0.185, "dq2": 1.123, "dq3": 0.866}}


def profile_one(study: S.Study, n: int = 50) -> None:
    fixed = S.fixed_parts(study)
    ds = S.repeat_data(study, fixed.true, fixed, np.random.default_rng(0))
    v = study.variants[0]
    S.calibrate_variant(study, v, ds)  # imports, first-call costs
    for label, cold in (("structure caches emptied before each call", True), ("structure seen before", False)):
        spent = 0.0
        for _ in range(n):
            if cold:
                forget_structures()
            t = time.perf_counter()
            S.calibrate_variant(study, v, ds)
            spent += time.perf_counter() - t
        print(f"one klimchik3r calibration ({v.name}), {label}: {spent / n * 1e3:.1f} ms")


def cpu_per_repeat(study: S.Study, n: int) -> None:
    """CPU time per repeat (every variant) of ``n`` repeats in this process, after 5 warm-up repeats."""
    short = replace(study, repeats=n + 5)
    fixed = S.fixed_parts(short)
    S.run_chunk(short, fixed, range(5))
    c = time.process_time()
    S.run_chunk(short, fixed, range(5, n + 5))
    spent = (time.process_time() - c) / n
    print(f"in this process: {spent * 1e3:.1f} ms CPU per repeat ({len(study.variants)} variants), "
          f"{spent * 1000:.1f} s for Table I's 1000 repeats; load average {os.getloadavg()[0]:.1f}")


class ProcessCPU:
    """CPU time (user + system) this process and its child processes spent inside the block, read at its end:
    a child's own and that of the processes it reaped (the fork server reaps the Dask workers it forked). On a
    shared machine the wall time measures the other jobs too; this does not."""

    def __enter__(self):
        self.me = psutil.Process()
        self.start, self.machine = self._total(self.me, children=False), self._busy()
        return self

    def __exit__(self, *exc):
        self.client = self._total(self.me, children=False) - self.start
        self.children = [self._total(p) for p in self.me.children()]
        self.others = self._busy() - self.machine - self.client - sum(self.children)

    @staticmethod
    def _busy() -> float:
        """CPU seconds every process of the machine has used (all cores): with ours subtracted, the other jobs'."""
        t = psutil.cpu_times()
        return sum(t) - t.idle - getattr(t, "iowait", 0.0) - getattr(t, "guest", 0.0) - getattr(t, "guest_nice", 0.0)

    @staticmethod
    def _total(p, children=True) -> float:
        t = p.cpu_times()
        return t.user + t.system + (t.children_user + t.children_system if children else 0.0)

    def report(self) -> str:
        return (f"{self.client + sum(self.children):.2f} s in all: this process {self.client:.2f} s, its children "
                f"(the fork server with the workers it forked) {' + '.join(f'{c:.2f}' for c in self.children)} s; "
                f"other jobs on the machine meanwhile {max(self.others, 0.0):.2f} s")


def forget_structures() -> None:
    """Empty what calibrations remember per structure (an older kincal on PYTHONPATH may lack some caches)."""
    for module in (params, se3):
        getattr(module, "clear_caches", lambda: None)()
    symmetries.clear_structure_cache()
    getattr(plausibility, "clear_readings_cache", lambda: None)()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=1000)
    ap.add_argument("--variants", default="approach2,approach1")
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--cpu", type=int, default=0, help="CPU time of this many repeats in this process first")
    args = ap.parse_args()
    study = S.load("table1")
    wanted = args.variants.split(",")
    study = replace(study, repeats=args.repeats, variants=tuple(v for v in study.variants if v.name in wanted))
    if args.profile:
        profile_one(study)
    if args.cpu:
        cpu_per_repeat(study, args.cpu)
    if not study.repeats:  # --repeats 0: the timings above only
        return
    log = logging.getLogger("kincal.workflow.parallel")  # when the cluster was up, what this process ran
    log.addHandler(logging.StreamHandler())
    log.setLevel(logging.INFO)
    load = os.getloadavg()[0]
    with ProcessCPU() as cpu:
        t = time.perf_counter()
        result = S.run_study(study, workers=args.workers)
        wall = time.perf_counter() - t
    print(f"table1: {study.repeats} repeats x {len(study.variants)} variants on {args.workers} workers: {wall:.2f} s "
          f"(load average {load:.1f} before, {os.getloadavg()[0]:.1f} after)")
    print(f"CPU of the study's processes: {cpu.report()}")
    print(f"{'variant':22s} {'param':6s} {'kincal std':>11s} {'paper std':>10s} {'reported/MC':>12s} {'bias':>10s}")
    for r in result.rows:
        f, unit = (1e3, "mm") if r.unit == "m" else (np.degrees(1.0) * 1e3, "mdeg")
        paper = PAPER.get(r.variant, {}).get(r.quantity)
        print(f"{r.variant:22s} {r.quantity:6s} {r.std * f:8.4f} {unit:4s} {paper if paper else '':>8} "
              f"{r.ratio:10.3f} {r.bias * f:10.4f}")
    for v in result.validation:
        print(f"{v.variant}: validation RMS position error median {v.median * 1e3:.4f} mm, p95 {v.p95 * 1e3:.4f} mm; "
              f"{v.used} used, {v.not_converged} not converged, {v.failed} failed")


if __name__ == "__main__":  # Dask's worker processes import this file again
    main()
