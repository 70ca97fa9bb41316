"""How many random configurations a designed K = 15 is worth, calibrated and validated, for every experiment
kind (issue #11; docs/design.md, "Worth random").

For each built-in scenario (tracker, Frida one clamp, Frida plate, Frida dual clamp) and each size of true-robot
errors: one true robot (the scenario's seed) and one candidate pool drawn noise-free on it by the experiment's
generator; its last 40 candidates are held out for validation, and K = 15 configurations are chosen from the
rest on the nominal model (``kincal.workflow.design.choose``, criteria D and I). Then, per noise seed, the
pool's readings get the scenario's stated noise (joint readings, tracker positions), and the designed
configurations and random subsets of N = 15 ... 100 configurations are calibrated and validated on the held-out
configurations, noise-free: the experiment's own position residual with its unknown frames (tracker and markers,
clamp, plate, fixture) refitted. Not the scenario's tool-pose validation: one clamp cannot identify joint 1
about its axis nor the tool, so the tool's world position keeps millimetres of error whatever is measured.
Per seed, the random curve (median of ``--draws`` subsets per N, made non-increasing in N) is interpolated
log-log at the designed error: "worth" N random. Reported: the median over the seeds.

Error sizes: ``thesis`` (0.01 m, 2.4 deg twists and home, 0.07 rad offsets) and ``fine`` (1 mm, 0.1 deg,
0.01 rad), ``kincal.simulate.perturb``. The dual clamp calibrates offsets only (at level kinematic it has 61
identifiable parameters, more than 15 configurations of 6 equations can calibrate), so its true robot gets
offset errors only, of the same two sizes (0.07 and 0.01 rad): twist errors would be model error that no
choice of configurations removes.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python bench/design_worth.py [--seeds 20] [--pool 250]
        [--draws 3] [--cases ur10_tracker_markers frida_clamp_one ...]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402

from kincal.estimation import calibrate  # noqa: E402
from kincal.io.datasets import load_scenario, scenario_path  # noqa: E402
from kincal.simulate import Noise as SimNoise  # noqa: E402
from kincal.simulate.noise import joint_readings, tracker_points  # noqa: E402
from kincal.simulate.perturb import perturbation  # noqa: E402
from kincal.simulate.scenario import build_scenario, run  # noqa: E402
from kincal.workflow.design import choose  # noqa: E402

K = 15
GRID = (15, 20, 30, 45, 65, 100)
HELD_OUT = 40  # the pool's last candidates: validation configurations, never chosen
CASES = {"ur10_tracker_markers": "kinematic", "frida_clamp_one": "kinematic", "frida_plate4": "kinematic",
         "frida_dual_bracket": "offsets"}
LEVELS = ("thesis", "fine")
TRACKER_FIELDS = ("p_tracker_marker", "T_tracker_tool")


def scenario(name: str, level: str, pool: int):
    """The built-in scenario with ``pool`` noise-free candidates and true-robot errors of size ``level``."""
    sc = build_scenario(load_scenario(scenario_path(name)))
    p = perturbation(level)
    if CASES[name] == "offsets":
        p = perturbation(None, offset_rad=p.offset_rad)
    return replace(sc, options={**sc.options, "n": pool}, perturbation=p), sc.noise


def noisy(ds, noise, rng):
    """The pool's noise-free readings with the scenario's noise drawn again."""
    q = {a: joint_readings(v, noise, rng) for a, v in ds.q.items()}
    measured = {k: tracker_points(v, noise, rng) if k in TRACKER_FIELDS else v for k, v in ds.measured.items()}
    return replace(ds, q=q, measured=measured)


def error(robot, ds, free, noise, validation) -> float:
    """Validation position RMS (m) over every validated arm after calibrating ``ds``."""
    res = calibrate(robot, [ds], free, noise=noise, validation=validation)
    return float(np.sqrt(np.mean([v.after.position_rms ** 2 for v in res.validation])))


def worth(value: float, curve) -> float:
    """The N at which the non-increasing random curve reaches ``value`` (log-log interpolation)."""
    e = np.minimum.accumulate(np.asarray(curve))
    if value > e[0]:
        return 0.0  # worse than 15 random
    hit = np.flatnonzero(e <= value)
    if not len(hit):
        return float("inf")
    j = hit[0]
    x0, x1, y0, y1 = np.log(GRID[j - 1]), np.log(GRID[j]), np.log(e[j - 1]), np.log(e[j])
    return float(np.exp(x0 + (np.log(value) - y0) * (x1 - x0) / (y1 - y0)))


def study(name: str, level: str, seeds: int, pool: int, draws: int) -> dict:
    free = CASES[name]
    sc, noise = scenario(name, level, pool)
    t = time.perf_counter()
    clean_sc = replace(sc, noise=SimNoise())
    true, ds, _, _ = run(replace(clean_sc, n_validation=2))
    validation = [ds.subset(np.arange(ds.size - HELD_OUT, ds.size))]
    ds = ds.subset(np.arange(ds.size - HELD_OUT))
    gen_s = time.perf_counter() - t
    t = time.perf_counter()
    chosen = {c: choose(sc.robot, ds, K, free=free, criterion=c, noise=noise).selection.indices for c in "DI"}
    sel_s = time.perf_counter() - t
    out = {"D": [], "I": [], "random15": [], "worth D": [], "worth I": [], "gen_s": gen_s, "sel_s": sel_s}
    for s in range(seeds):
        rng = np.random.default_rng(10_000 + s)
        data = noisy(ds, noise, rng)
        curve = [np.median([error(sc.robot, data.subset(np.sort(rng.choice(ds.size, n, replace=False))), free,
                                  noise, validation) for _ in range(draws)]) for n in GRID]
        out["random15"].append(curve[0])
        for c, idx in chosen.items():
            e = error(sc.robot, data.subset(idx), free, noise, validation)
            out[c].append(e)
            out[f"worth {c}"].append(worth(e, curve))
        print(f"{name} {level} seed {s}: random15 {curve[0] * 1e3:.4f} mm, D {out['D'][-1] * 1e3:.4f} "
              f"(worth {out['worth D'][-1]:.0f}), I {out['I'][-1] * 1e3:.4f} (worth {out['worth I'][-1]:.0f})",
              flush=True)
    out["rank_free"] = free
    return out


def fmt_worth(v) -> str:
    m = np.median(v)
    return "> 100" if np.isinf(m) else "< 15" if m < GRID[0] else f"{m:.0f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--pool", type=int, default=160, help="candidates, the last 40 of them held out")
    ap.add_argument("--draws", type=int, default=3, help="random subsets per N and seed (their median)")
    ap.add_argument("--cases", nargs="+", default=list(CASES))
    ap.add_argument("--levels", nargs="+", default=list(LEVELS))
    a = ap.parse_args()
    rows = []
    for name in a.cases:
        for level in a.levels:
            r = study(name, level, a.seeds, a.pool, a.draws)
            rows.append((name, level, r))
    print(f"\n{a.seeds} noise seeds, pool {a.pool} ({HELD_OUT} held out), {a.draws} random draws per N; medians "
          "over the seeds")
    print("| experiment | free | true errors | random K = 15 (mm) | D K = 15 (mm) | D worth random | I K = 15 (mm) "
          "| I worth random | pool drawn s | select s (D + I) |")
    print("| --- " * 10 + "|")
    for name, level, r in rows:
        med = {k: np.median(r[k]) * 1e3 for k in ("random15", "D", "I")}
        print(f"| {name} | {r['rank_free']} | {level} | {med['random15']:.4f} | {med['D']:.4f} | "
              f"{fmt_worth(np.array(r['worth D']))} | {med['I']:.4f} | {fmt_worth(np.array(r['worth I']))} | "
              f"{r['gen_s']:.0f} | {r['sel_s']:.1f} |")


if __name__ == "__main__":
    main()
