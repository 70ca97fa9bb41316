"""Staged against simultaneous solves: the table of docs/calibration.md "Staged solves".

Three problems, each simulated with several seeds from its built-in scenario (true robot, noise, validation):
- ``klimchik3r_loaded_markers``: the partial-pose paper's 3-DOF arm under 2500 N loads, three markers, an
  unknown tracker; final free set ``[kinematic, elastic]``; two steps: ``[tracker, markers]`` with the arm
  nominal, then ``[kinematic, elastic]`` with the tracker and markers held (the paper's Sec. III);
- ``ur10_tracker_markers``: the same kind of data on a 6-DOF arm without loads; final free set ``kinematic``;
- ``frida_dual_bracket``: Frida's arms clamped tool to tool; final free set ``kinematic``; two steps: the
  thesis' ``offsets``, then ``kinematic`` with the offsets held (thesis Sec. 3.4); also with the true robot's
  errors three times the thesis' (offsets up to 0.21 rad, twists up to 0.03 m and 7 deg): started far off.
Variants: simultaneous (one solve of the final free set); two-step (as above); the two steps alternated three
times (the paper: "these steps are repeated iteratively"); staged to the same free set (the first step, then the
final free set with nothing held). Columns, mean over seeds (max where said): chi^2 above the best of the four
variants on the same data (in whitened units: 1 is one standard deviation along one direction), the residual
variance factor, the held-out position RMS, the largest compliance error in reported standard deviations, outer
iterations and time.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python bench/staged_vs_simultaneous.py [--seeds N]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402
from dataclasses import fields, replace  # noqa: E402

import numpy as np  # noqa: E402

from kincal.estimation import Stage, calibrate  # noqa: E402
from kincal.io.datasets import load_scenario  # noqa: E402
from kincal.simulate.scenario import build_scenario, run  # noqa: E402

FRAMES = ["tracker", "markers"]
THESIS_STEPS = ("kinematic", Stage("offsets", name="offsets"), Stage("kinematic", fixed=["*.offset"],
                                                                     name="kinematics"))
PROBLEMS = {  # row label -> (scenario, error scale, final free set, first and second step of the two-step procedure)
    "klimchik3r_loaded_markers": ("klimchik3r_loaded_markers", 1.0, ["kinematic", "elastic"],
                                  Stage(FRAMES, name="base-and-tool"),
                                  Stage(["kinematic", "elastic"], fixed=FRAMES, name="geometry-and-compliance")),
    "ur10_tracker_markers": ("ur10_tracker_markers", 1.0, "kinematic", Stage(FRAMES, name="base-and-tool"),
                             Stage("kinematic", fixed=FRAMES, name="geometry")),
    "frida_dual_bracket": ("frida_dual_bracket", 1.0) + THESIS_STEPS,
    "frida_dual_bracket, errors x3": ("frida_dual_bracket", 3.0) + THESIS_STEPS,
}


def variants(free, first: Stage, second: Stage) -> dict[str, dict]:
    """calibrate keywords per variant."""
    return {"simultaneous": {"free": free},
            "two-step": {"stages": [first, second]},
            "two-step x3": {"stages": [first, second] * 3},
            "staged, same final set": {"stages": [first, Stage(free, name="final")]}}


def chi2(result) -> float:
    """Whitened chi^2 at the final state with the whitening of that state: with encoder noise the whitening
    depends on the state, and a solve holds it from its second linearization on (``Result.after``), so each
    variant's own chi^2 would be of a slightly different objective."""
    return float(sum(s.chi2 for s in result.problem.statistics(result.state)))


def compliance_error(result, true) -> float:
    """The largest |estimate - truth| / reported std over the compliances (nan without free compliances)."""
    out = [abs(e.value - true[e.name.split(".")[0]].compliance[int(e.name.split(".")[1][1:]) - 1]) / e.std
           for e in result.estimates if e.name.endswith(".compliance") and e.identifiable]
    return max(out) if out else float("nan")


def scenario(name: str, scale: float):
    """The built-in scenario with its true robot's errors (not the compliances) ``scale`` times larger."""
    sc = build_scenario(load_scenario(name))
    p = sc.perturbation
    return replace(sc, perturbation=replace(p, **{f.name: scale * getattr(p, f.name) for f in fields(p)
                                                   if f.name != "compliance"}))


def one_seed(name: str, seed: int) -> dict[str, dict]:
    scenario_name, scale, *steps = PROBLEMS[name]
    sc = scenario(scenario_name, scale)
    true, ds, _, validation = run(replace(sc, seed=seed))
    rows = {}
    for label, kw in variants(*steps).items():
        t = time.perf_counter()
        res = calibrate(sc.robot, [ds], validation=list(validation.values()), outliers="keep", **kw)
        rows[label] = {"chi2": chi2(res), "sigma2": res.sigma2, "status": res.status + ("" if res.trusted else
                                                                                       " (not trusted)"),
                       "validation_mm": 1e3 * float(np.sqrt(np.mean([v.after.position_rms**2
                                                                     for v in res.validation]))),
                       "compliance_sigmas": compliance_error(res, true), "iterations": res.iterations,
                       "seconds": time.perf_counter() - t}
    best = min(r["chi2"] for r in rows.values())
    for r in rows.values():
        r["excess"] = r["chi2"] - best
    return rows


def table(name: str, seeds: range) -> list[str]:
    runs = [one_seed(name, s) for s in seeds]
    lines = []
    for label in runs[0]:
        rs = [r[label] for r in runs]

        def mean(k):
            return float(np.mean([r[k] for r in rs]))
        comp = "-" if np.isnan(mean("compliance_sigmas")) else f"{max(r['compliance_sigmas'] for r in rs):.2g}"
        statuses = sorted({r["status"] for r in rs})
        lines.append(f"| {name} | {label} | {mean('excess'):.3g} (max {max(r['excess'] for r in rs):.3g}) | "
                     f"{mean('sigma2'):.3g} | {mean('validation_mm'):.3g} | {comp} | {mean('iterations'):.3g} | "
                     f"{mean('seconds'):.2g} | {', '.join(statuses)} |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--problems", nargs="*", default=list(PROBLEMS))
    args = parser.parse_args()
    print("| problem | variant | chi^2 above best | variance factor | held-out pos RMS mm | max compliance error "
          "(std) | outer iterations | s | status |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in args.problems:
        for line in table(name, range(1, args.seeds + 1)):
            print(line, flush=True)


if __name__ == "__main__":
    main()
