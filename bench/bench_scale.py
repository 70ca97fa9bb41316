"""Scale (issue 15): Frida's dual arm at N = 1,000, 10,000 and 100,000 clamped configurations (1,000,000 with
``--huge``), solved by blocks (``kincal.estimation.blocks``), against the stacked solve at 10,000, and the import
time of ``import kincal; import kincal.estimation``.

Problem: the ``frida_dual_bracket`` scenario (thesis-level errors, joint noise 0.005 deg, backlash 0.01 deg)
with the clamp unknown; ``calibrate(frida, [ds], ["kinematic", "clamp"])``: both arms' full POE and the
clamp, 88 free coordinates, rank 55.

Each size runs in two fresh subprocesses: one simulates the data and pickles it to ``--cache`` (kept, so a
second run skips it), the other loads it and calibrates once and reports its own peak RSS
(``getrusage(RUSAGE_SELF)``: the parent's RUSAGE_CHILDREN would be the largest child so far, the simulations
included), so the peak is per size and the solve's. "RSS before" is that process's resident set after importing
kincal and loading the data; "per configuration" is (peak - before) / N, also
counted in copies of the whitened Jacobian (free columns, float64), which the block path never holds whole.
Wall and CPU are of ``calibrate`` alone (BLAS on one thread: threadpoolctl and OPENBLAS_NUM_THREADS=1).
At ``--stacked`` sizes (default 10,000) the same data are solved once more with every row in one block (the
stacked solve: ``memory.CHUNK_BYTES`` raised above the problem), and the largest relative difference of the
estimates is printed.

Import time: ``python -c "import kincal; import kincal.estimation"`` in ``--import-runs`` fresh subprocesses
(median, wall, timed inside the child), then one run with ``-X importtime`` for the modules with the largest
cumulative import times.

Run: python bench/bench_scale.py [--sizes 1000 10000 100000] [--huge] [--stacked 10000] [--cache DIR]
     [--import-runs 5]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads OpenBLAS

import argparse  # noqa: E402
import copyreg  # noqa: E402
import json  # noqa: E402
import pickle  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import types  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

from kincal.data import Dataset  # noqa: E402
from kincal.estimation import calibrate, memory  # noqa: E402
from kincal.io.datasets import load_scenario, scenario_path  # noqa: E402
from kincal.simulate.generators import GENERATORS  # noqa: E402
from kincal.simulate.perturb import perturb_robot  # noqa: E402
from kincal.simulate.scenario import build_scenario, run  # noqa: E402



def _read_only(d: dict) -> types.MappingProxyType:
    return types.MappingProxyType(d)


# Data sets hold read-only mappings (meta, noise): pickled as the dict they wrap, to hand data to a worker
# (which runs this script as __main__ too, so it finds ``_read_only``).
copyreg.pickle(types.MappingProxyType, lambda m: (_read_only, (dict(m),)))

SCENARIO = "frida_dual_bracket"
FREE = ["kinematic", "clamp"]
HUGE = 1_000_000
SIM_BLOCK = 100_000  # configurations simulated at a time
IMPORTS = "import kincal; import kincal.estimation"
MiB = 1024 * 1024


def simulate(n: int, path: Path) -> None:
    """The scenario with ``n`` configurations and the clamp unknown, pickled with its nominal robot. Above
    ``SIM_BLOCK`` configurations in blocks of that many, each from its own random stream with the same true
    robot (the scenario's robot stream, as ``run`` draws it), so the simulation's memory stays that of one
    block plus the joint readings."""
    scenario = build_scenario(load_scenario(scenario_path(SCENARIO)))
    scenario = replace(scenario, options=dict(scenario.options, n=min(n, SIM_BLOCK), known_clamp=False),
                       n_validation=1)
    ds = run(scenario)[1]
    if n > SIM_BLOCK:
        robot_rng = np.random.default_rng(np.random.SeedSequence(scenario.seed).spawn(2)[0])
        true = perturb_robot(scenario.robot, scenario.perturbation, robot_rng, arms=scenario.perturb_arms)
        more = [GENERATORS[scenario.kind](true, rng=np.random.default_rng([scenario.seed, 1 + j]), noise=scenario.noise,
                                          n_validation=1, **scenario.options)[0]
                for j in range((n - 1) // SIM_BLOCK)]
        ds = Dataset(ds.kind, ds.robot, ds.arms, {a: np.concatenate([d.q[a] for d in [ds] + more])[:n] for a in ds.q},
                     {k: np.concatenate([d.measured[k] for d in [ds] + more])[:n] for k in ds.measured}, ds.known,
                     ds.name, ds.meta, ds.frames)
    path.write_bytes(pickle.dumps((scenario.robot, ds)))


def tile(path: Path, n: int, out: Path) -> None:
    """The pickled data set repeated to ``n`` configurations (identical rows: the same least-squares minimum)."""
    robot, ds = pickle.loads(path.read_bytes())
    reps = -(-n // ds.size)
    ds = Dataset(ds.kind, ds.robot, ds.arms, {a: np.tile(v, (reps, 1))[:n] for a, v in ds.q.items()},
                 {k: np.tile(v, (reps,) + (1,) * (v.ndim - 1))[:n] for k, v in ds.measured.items()}, ds.known,
                 ds.name, ds.meta, ds.frames)
    out.write_bytes(pickle.dumps((robot, ds)))


def resident() -> int:
    """This process's resident set now (bytes)."""
    return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def solve(path: Path, stacked: bool = False) -> None:
    """Calibrate the pickled problem once (``stacked``: in one block); prints one JSON line (times, rank, RSS
    before the solve, estimates)."""
    robot, ds = pickle.loads(path.read_bytes())
    if stacked:
        memory.CHUNK_BYTES = 2**62
    before = resident()
    with threadpool_limits(limits=1, user_api="blas"):
        t0, c0 = time.perf_counter(), time.process_time()
        res = calibrate(robot, [ds], FREE)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    ana = res.identifiability
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # this process's peak: the solve's
    print(json.dumps({"n": ds.size, "wall": wall, "cpu": cpu, "before": before, "peak": peak,
                      "jacobian": 8 * len(res.linearization.r) * len(ana.names), "rank": ana.rank,
                      "free": len(ana.names), "status": res.status, "iterations": res.iterations,
                      "outliers": len(res.outliers), "blocked": res.problem.blocked,
                      "estimates": [e.value for e in res.estimates]}))


def child(*args: str) -> dict | None:
    """Run this script with ``args`` in a fresh process: its last JSON line, or None."""
    done = subprocess.run([sys.executable, str(Path(__file__).resolve()), *args], capture_output=True, text=True,
                          env=dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1"))
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(args)} failed:\n{done.stderr}")
    lines = done.stdout.strip().splitlines()
    return json.loads(lines[-1]) if lines else None


def scale_rows(sizes, cache: Path, stacked=(), tiled: bool = False):
    """One row per size: simulate (cached), then solve in a fresh process that reports its own peak RSS
    (``getrusage(RUSAGE_SELF)`` at its end: the parent's RUSAGE_CHILDREN is a maximum over every child, the
    simulations included); at ``stacked`` sizes also the stacked solve, its estimates compared. ``tiled``: N above
    ``SIM_BLOCK`` is the ``SIM_BLOCK`` set repeated (``tile``)."""
    rows = []
    for n in sorted(sizes):
        path = cache / f"{SCENARIO}-{n}.pkl"
        if tiled and n > SIM_BLOCK:
            path = cache / f"{SCENARIO}-{n}-tiled.pkl"
            tile(cache / f"{SCENARIO}-{SIM_BLOCK}.pkl", n, path)
        elif not path.exists():
            t0 = time.perf_counter()
            child("--simulate", str(n), str(path))
            print(f"simulated N = {n} in {time.perf_counter() - t0:.0f} s ({path})", flush=True)
        out = child("--solve", str(path))
        if n in stacked:
            ref = child("--solve", str(path), "--stacked-solve")
            a, b = np.array(out["estimates"]), np.array(ref["estimates"])
            out["stacked"] = dict(ref, difference=float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-300))))
        rows.append(out)
        print(f"N = {n}: {_brief(out)}", flush=True)
    return rows


def _brief(row: dict) -> dict:
    return {k: (_brief(v) if isinstance(v, dict) else v) for k, v in row.items() if k != "estimates"}


def import_times(runs: int):
    """(median wall s of the imports in fresh processes, [(cumulative s, module)] of one -X importtime run)."""
    code = f"import time; t = time.perf_counter(); {IMPORTS}; print(time.perf_counter() - t)"
    walls = [float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout)
             for _ in range(runs)]
    err = subprocess.run([sys.executable, "-X", "importtime", "-c", IMPORTS], capture_output=True, text=True,
                         check=True).stderr
    mods = []
    for line in err.splitlines()[1:]:
        parts = line.split("|")
        if len(parts) == 3 and parts[1].strip().isdigit():
            mods.append((int(parts[1]) * 1e-6, parts[2].rstrip()))
    return float(np.median(walls)), mods


def markdown(head, rows) -> str:
    rows = [tuple(head)] + [tuple(r) for r in rows]
    widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
    fmt = lambda r: "| " + " | ".join(c.ljust(w) for c, w in zip(r, widths)) + " |"  # noqa: E731
    return "\n".join([fmt(rows[0]), "|" + "|".join("-" * (w + 2) for w in widths) + "|"] + [fmt(r) for r in rows[1:]])


def scale_table(rows) -> str:
    out = []
    for r in rows:
        for x in [r] + ([r["stacked"]] if "stacked" in r else []):
            how = "blocks" if x["blocked"] else "stacked"
            per = (x["peak"] - x["before"]) / x["n"]
            same = f"{r['stacked']['difference']:.1e}" if "stacked" in r and x is r else ""
            out.append([f"{x['n']:,}", how, f"{x['wall']:.2f} s", f"{x['cpu']:.2f} s", f"{x['peak'] / MiB:.0f} MiB",
                        f"{x['before'] / MiB:.0f} MiB", f"{per / 1024:.1f} KiB", f"{per * x['n'] / x['jacobian']:.2f}",
                        f"{x['rank']} of {x['free']}", f"{x['status']}, {x['iterations']} outer, "
                        f"{x['outliers']} outliers", same])
    head = ["N", "solve", "wall", "CPU", "peak RSS", "RSS before", "per configuration", "in whitened Jacobians",
            "rank", "status", "max relative difference to stacked"]
    return markdown(head, out)


def import_table(median: float, mods, top: int) -> str:
    """The slowest imports by cumulative time, with their nesting depth as -X importtime prints it."""
    rows = [[str((len(name) - len(name.lstrip())) // 2), name.strip(), f"{t * 1e3:.0f} ms"]
            for t, name in sorted(mods, key=lambda m: -m[0])[:top]]
    return (f"`{IMPORTS}`: {median * 1e3:.0f} ms (median of fresh processes)\n"
            + markdown(["depth", "module", "cumulative"], rows))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 10_000, 100_000])
    ap.add_argument("--huge", action="store_true", help=f"also N = {HUGE:,} (simulation and solve: minutes)")
    ap.add_argument("--tiled", action="store_true",
                    help=f"with --huge: the {SIM_BLOCK:,} set repeated instead of a fresh simulation (which takes long)")
    ap.add_argument("--stacked", type=int, nargs="*", default=[10_000], help="sizes also solved stacked")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "kincal-bench-scale")
    ap.add_argument("--import-runs", type=int, default=5)
    ap.add_argument("--top", type=int, default=15, help="rows of the import table")
    ap.add_argument("--simulate", nargs=2, help=argparse.SUPPRESS)
    ap.add_argument("--solve", help=argparse.SUPPRESS)
    ap.add_argument("--stacked-solve", dest="solve_stacked", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.simulate:
        return simulate(int(args.simulate[0]), Path(args.simulate[1]))
    if args.solve:
        return solve(Path(args.solve), stacked=args.solve_stacked)
    args.cache.mkdir(parents=True, exist_ok=True)
    median, mods = import_times(args.import_runs)
    rows = scale_rows(args.sizes + ([HUGE] if args.huge else []), args.cache, set(args.stacked), args.tiled)
    print(f"\nFrida dual arm, {SCENARIO}, clamp unknown, free {FREE}; BLAS on one thread; one call per size; "
          f"load average {os.getloadavg()[0]:.1f}")
    print(scale_table(rows))
    print()
    print(import_table(median, mods, args.top))


if __name__ == "__main__":
    main()
