"""kincal's configuration selection against FIGAROH 1.0.2's (Detmax exchange, SOCP D-optimal relaxation) on the
same candidate pool: issue #11's tracker anchor (docs/design.md, "Against FIGAROH").

A UR10 (kincal's built-in ``ur10``) with one tracker marker, sigma 0.05 mm, tracker frame and marker unknown,
level ``kinematic``; a pool of 5000 random configurations within the limits. The pool is linearized once at the
nominal model: every candidate's 3 whitened rows on the identifiable subspace, ``X`` (N, 3, r). The same ``X``
goes to both tools: to ``kincal.analysis.design.select`` here, and through an .npz in a temporary directory to
FIGAROH's ``Detmax`` and ``SOCPOptimizer`` in FIGAROH's own virtualenv (bench/figaroh_select_worker.py), so
both optimize exactly the same information matrices. Compared for K = 10, 15, 30: the selection time, the log
det of the chosen configurations' information (identifiable part), and the validation RMS after calibrating the
chosen configurations measured on a perturbed ("fine") true robot, over ``--seeds`` noise seeds (true robot
and noise drawn per seed; the pool's configurations and every selection stay the same).

The SOCP relaxation runs at ``--socp-pool`` candidates (the pool's first ones; default 400); its memory is
measured at smaller pools first and projected; a pool whose projection exceeds ``--memory-gb`` is refused,
not run. Its K configurations are the K largest weights (FIGAROH's ``w_dict_sort`` order).

At K = 10 and 15 (30 and 45 equations for 27 identifiable parameters) kincal calibrates with low redundancy
(docs/calibration.md): the same least-squares estimate, with the stated noise as the floor of its standard
deviations.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python bench/design_figaroh.py [--seeds 20] \\
        [--figaroh-python /tmp/venv-figaroh/bin/python] [--socp-pool 400] [--memory-gb 18]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from kincal import robots  # noqa: E402
import kincal.estimation.iterate  # noqa: E402, F401 (patched below, by module path)
import kincal.estimation.solver  # noqa: E402, F401
from kincal.analysis.design import information, select  # noqa: E402
from kincal.estimation import Noise, Problem, SolverOptions, calibrate  # noqa: E402
from kincal.estimation.plan import identifiable_basis, plan  # noqa: E402
from kincal.simulate import Noise as SimNoise  # noqa: E402
from kincal.simulate import generate_markers, perturb_robot  # noqa: E402
from kincal.simulate.generators import random_markers, random_tracker_pose  # noqa: E402

SIGMA = 5e-5
POOL = 5000
POOL_SEED = 7
KS = (10, 15, 30)
REPEATS = 5  # kincal's selection timed as the median of this many runs
N_VALIDATION = 200
WORKER = Path(__file__).with_name("figaroh_select_worker.py")
PROBES = (200, 300, 400)  # SOCP pool sizes whose peak memory is measured before projecting


def setting(robot):
    """The tracker frame and the one marker (fixed for every seed)."""
    arm = next(iter(robot.arms))
    rng = np.random.default_rng(0)
    return arm, random_tracker_pose(robot, arm, rng), random_markers(1, rng)


def pool_on(robot, arm, T_wt, p_tm, n: int = POOL):
    """The pool's configurations measured noise-free on ``robot`` (the same configurations for any robot of the
    same limits), and noise-free validation configurations."""
    ds, _, val = generate_markers(robot, arm, n=n, rng=POOL_SEED, noise=SimNoise(), markers=p_tm,
                                  T_world_tracker=T_wt, n_validation=N_VALIDATION)
    return ds, val[arm]


def candidate_rows(robot, pool):
    """(X (N, 3, r), seconds): each candidate's whitened rows on the identifiable subspace, at the nominal."""
    t = time.perf_counter()
    problem = Problem.build(robot, [pool], "kinematic", noise=Noise(position=SIGMA))
    p = plan(problem, SolverOptions())
    V = identifiable_basis(problem, p.identifiability)
    X = (p.result.linearization.J[: pool.size * 3] @ V).reshape(pool.size, 3, V.shape[1])
    return X, time.perf_counter() - t


def timed_select(X, K: int):
    """kincal's D-optimal choice of K and its (wall, CPU) seconds: the median of ``REPEATS`` identical runs (the
    selection is deterministic; the machine is shared, so one run's time is noisy)."""
    times = []
    for _ in range(REPEATS):
        t, c = time.perf_counter(), time.process_time()
        idx = select(X, K, "D").indices
        times.append((time.perf_counter() - t, time.process_time() - c))
    return idx, tuple(np.median(np.array(times), axis=0))


def logdet(X, idx) -> float:
    return float(np.linalg.slogdet(information(X[np.asarray(idx)]))[1])


# ------------------------------------------------------------------------------------------------ FIGAROH


def figaroh(python: str, method: str, X, K: int = 0, seed: int = 0, memory_gb: float = 18.0) -> dict:
    """Run the worker in FIGAROH's venv on candidate rows X; its JSON answer (or {"error": ...})."""
    with tempfile.TemporaryDirectory(prefix="kincal-design-figaroh-") as tmp:
        np.savez(Path(tmp) / "pool.npz", X=X)
        limit = int(memory_gb * 2**30)

        def cap():  # the worker cannot take the machine down: address space capped
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

        cmd = [python, str(WORKER), method, str(Path(tmp) / "pool.npz"), str(Path(tmp) / "out.json"),
               "--k", str(K), "--seed", str(seed)]
        run = subprocess.run(cmd, capture_output=True, text=True, preexec_fn=cap)
        if run.returncode != 0:
            return {"error": (run.stderr.strip().splitlines() or ["exit %d" % run.returncode])[-1]}
        return json.loads((Path(tmp) / "out.json").read_text())


def socp_projection(python: str, X, memory_gb: float):
    """Peak memory (MB) and time of the SOCP at the probe sizes; power-law fits of the memory above the
    worker's own footprint and of the time, as functions of the pool size."""
    base = figaroh(python, "footprint", X[: PROBES[0]], memory_gb=memory_gb)["peak_rss_mb"]
    probes = []
    for n in PROBES:
        out = figaroh(python, "socp", X[:n], memory_gb=memory_gb)
        if "error" in out:
            raise RuntimeError(f"SOCP probe at {n} candidates failed: {out['error']}")
        probes.append((n, out["peak_rss_mb"], out["cpu_seconds"]))
    n, mb, s = (np.array(v, float) for v in zip(*probes))
    slope, icpt = np.polyfit(np.log(n), np.log(np.maximum(mb - base, 1.0)), 1)
    tslope, ticpt = np.polyfit(np.log(n), np.log(s), 1)
    return (base, probes, (lambda m: base + float(np.exp(icpt) * m**slope)),
            (lambda m: float(np.exp(ticpt) * m**tslope)), slope)


# ------------------------------------------------------------------------------------------------ calibrate


def calibrated_rms(nominal, pool_true, val, noise_rng, designs: dict) -> dict:
    """Validation RMS (m) of every design (name -> indices) calibrated on the pool measured with noise."""
    y = pool_true.measured["p_tracker_marker"]
    noisy = replace(pool_true, measured={"p_tracker_marker": y + noise_rng.normal(0.0, SIGMA, y.shape)})
    out = {}
    for name, idx in designs.items():
        res = calibrate(nominal, [noisy.subset(np.unique(idx))], "kinematic", noise=Noise(position=SIGMA),
                        validation=[val])
        out[name] = res.validation[0].after.position_rms
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--figaroh-python", default="/tmp/venv-figaroh/bin/python")
    ap.add_argument("--socp-pool", type=int, default=400)
    ap.add_argument("--memory-gb", type=float, default=18.0, help="refuse a SOCP projected to need more")
    ap.add_argument("--detmax-seed", type=int, default=0)
    a = ap.parse_args()
    ur = robots.load("ur10")
    arm, T_wt, p_tm = setting(ur)
    pool, _ = pool_on(ur, arm, T_wt, p_tm)
    X, lin_s = candidate_rows(ur, pool)
    print(f"UR10, one marker, sigma {SIGMA * 1e3:.2f} mm, level kinematic: pool {len(X)}, rank {X.shape[2]}, "
          f"rows per candidate {X.shape[1]}; kincal linearization of the pool {lin_s:.2f} s")
    print("load average (1, 5, 15 min): %.2f %.2f %.2f" % os.getloadavg())
    designs, rows = {}, []
    for K in KS:
        designs[("kincal D", K)], kt = timed_select(X, K)
        dm = figaroh(a.figaroh_python, "detmax", X * SIGMA, K, a.detmax_seed, a.memory_gb)
        if "error" in dm:
            sys.exit(f"FIGAROH Detmax failed: {dm['error']}")
        designs[("FIGAROH Detmax", K)] = np.array(dm["indices"])
        check = np.exp(logdet(X * SIGMA, dm["indices"]) / X.shape[2])
        rows.append((K, kt, dm, check))
        print(f"K = {K}: kincal {kt[0]:.3f} s, Detmax {dm['seconds']:.1f} s ({len(dm['critD'])} exchanges, "
              f"{len(set(dm['indices']))} distinct), Detmax criterion {dm['critD'][-1]:.6g} = {check:.6g} recomputed",
              flush=True)
    socp = run_socp(a, X, designs)
    rms, randoms = validate(a.seeds, ur, arm, T_wt, p_tm, pool, designs)
    report(X, designs, randoms, rows, socp, rms, a)


def run_socp(a, X, designs) -> dict:
    """SOCP at the probe sizes (memory, time), projected to the full pool and run at ``--socp-pool`` if the
    projection allows; kincal's selection on the same smaller pool for comparison."""
    base, probes, mb, sec, slope = socp_projection(a.figaroh_python, X * SIGMA, a.memory_gb)
    print(f"FIGAROH worker footprint {base:.0f} MB")
    for n, m, s in probes:
        print(f"SOCP probe: {n} candidates, peak {m:.0f} MB, {s:.1f} s CPU")
    out = {"base": base, "probes": probes, "slope": slope,
           "projected": {n: (mb(n), sec(n)) for n in (a.socp_pool, len(X))}}
    for n in (a.socp_pool, len(X)):
        need = mb(n) / 1024
        if need > a.memory_gb:
            out.setdefault("refused", []).append((n, need))
            print(f"SOCP at {n} candidates: projected {need:.0f} GB > {a.memory_gb:.0f} GB allowed: refused, not run")
            continue
        res = figaroh(a.figaroh_python, "socp", X[:n] * SIGMA, memory_gb=a.memory_gb)
        if "error" in res:
            out.setdefault("failed", []).append((n, res["error"]))
            print(f"SOCP at {n} candidates failed: {res['error']}")
            continue
        out.setdefault("ran", []).append((n, res["seconds"], res["cpu_seconds"], res["peak_rss_mb"]))
        print(f"SOCP at {n} candidates: {res['seconds']:.1f} s ({res['cpu_seconds']:.1f} s CPU), peak "
              f"{res['peak_rss_mb']:.0f} MB", flush=True)
        for K in KS:
            designs[(f"FIGAROH SOCP top-K (pool {n})", K)] = np.array(res["indices"][:K])
            designs[(f"kincal D (pool {n})", K)], out[("kincal", n, K)] = timed_select(X[:n], K)
    return out


def validate(seeds: int, ur, arm, T_wt, p_tm, pool, designs) -> dict:
    """name, K -> validation RMS (m) per seed; random designs drawn per seed."""
    rms: dict = {}
    randoms: dict = {}
    for s in range(seeds):
        true = perturb_robot(ur, "fine", rng=100 + s)
        pool_true, val = pool_on(true, arm, T_wt, p_tm)
        assert np.array_equal(pool_true.q[arm], pool.q[arm]), "the pool's configurations differ between robots"
        rng = np.random.default_rng(1000 + s)
        these = dict(designs)
        for K in KS:
            these[("random", K)] = rng.choice(pool.size, K, replace=False)
            randoms.setdefault(K, []).append(these[("random", K)])
        for key, v in calibrated_rms(ur, pool_true, val, np.random.default_rng(2000 + s), these).items():
            rms.setdefault(key, []).append(v)
        print(f"seed {s} done", flush=True)
    return rms, randoms


def report(X, designs, randoms, rows, socp, rms, a) -> None:
    print(f"\n| K | selection | pool | select s | select CPU s | log det M | validation RMS (mm), {a.seeds} seeds |")
    print("| --- " * 6 + "|")
    times = {("kincal D", K): kt for K, kt, _, _ in rows}
    times.update({("FIGAROH Detmax", K): (dm["seconds"], dm["cpu_seconds"]) for K, _, dm, _ in rows})
    n_socp = [r[0] for r in socp.get("ran", [])]
    for n, wall, cpu, _ in socp.get("ran", []):
        times.update({(f"FIGAROH SOCP top-K (pool {n})", K): (wall, cpu) for K in KS})
        times.update({(f"kincal D (pool {n})", K): socp[("kincal", n, K)] for K in KS})
    for K in KS:
        ld = np.median([logdet(X, r) for r in randoms[K]])
        cells = [("random", len(X), "", "", f"{ld:.1f} (median)", rms[("random", K)])]
        for name in ["kincal D", "FIGAROH Detmax"] + [f"{w} (pool {n})" for n in n_socp
                                                     for w in ("kincal D", "FIGAROH SOCP top-K")]:
            idx = designs[(name, K)]
            wall, cpu = times[(name, K)]
            pool = n_socp[0] if "pool" in name else len(X)
            cells.append((name.split(" (pool")[0], pool, f"{wall:.3f}", f"{cpu:.3f}", f"{logdet(X, idx):.1f}",
                          rms[(name, K)]))
        for name, pool, wall, cpu, ld, r in cells:
            r = np.array(r) * 1e3
            print(f"| {K} | {name} | {pool} | {wall} | {cpu} | {ld} | {r.mean():.3f} +- {r.std():.3f} |")
    for K, kt, dm, _ in rows:
        print(f"K = {K}: FIGAROH Detmax / kincal select: {dm['seconds'] / kt[0]:.0f}x wall, "
              f"{dm['cpu_seconds'] / kt[1]:.0f}x CPU")
    for K in KS:  # paired: the same true robot and noise per seed
        diff = (np.array(rms[("kincal D", K)]) - np.array(rms[("FIGAROH Detmax", K)])) * 1e3
        se = diff.std(ddof=1) / np.sqrt(len(diff)) if len(diff) > 1 else float("nan")
        print(f"K = {K}: validation RMS kincal D - Detmax, paired over {len(diff)} seeds: {diff.mean():+.4f} +- "
              f"{se:.4f} mm (standard error); kincal lower in {int((diff < 0).sum())} of {len(diff)}")
    for n, (mb, sec) in socp["projected"].items():
        print(f"SOCP projected at {n} candidates: {mb / 1024:.1f} GB peak memory, {sec:.0f} s CPU "
              f"(memory ~ n^{socp['slope']:.2f} above the {socp['base']:.0f} MB footprint)")
    for n, need in socp.get("refused", []):
        print(f"SOCP at {n} candidates refused: {need:.0f} GB projected, {a.memory_gb:.0f} GB allowed")
    print("load average at the end (1, 5, 15 min): %.2f %.2f %.2f" % os.getloadavg())


if __name__ == "__main__":
    main()
