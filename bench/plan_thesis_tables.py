"""Thesis Tables 4.10 and 4.14 by kincal's planning tools: the tables of docs/planning.md.

Table 4.10: rank of the thesis' identification Jacobian for one Frida arm measured by the other (10 random
configurations), with the null vector in the thesis' terms. Table 4.14: how a clamp error of 1 cm / 0.1 rad
(the thesis' deviation) moves the dual-arm offsets, to first order (``analyze``) and by recalibrating with the
wrong clamp; then the same with the clamp estimated.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python bench/plan_thesis_tables.py
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from kincal import robots  # noqa: E402
from kincal.baselines.rank import thesis_rank  # noqa: E402
from kincal.data import Dataset  # noqa: E402
from kincal.estimation import Noise, calibrate  # noqa: E402
from kincal.lie import se3  # noqa: E402
from kincal.simulate import generate_dual  # noqa: E402
from kincal.workflow.analyze import analyze  # noqa: E402

FRIDA = robots.load("frida")
ERROR = np.array([0.01, 0.01, -0.01, -0.1, 0.1, 0.1])  # clamp v_x, v_y, v_z (m), w_x, w_y, w_z (rad)
NAMES = ("clamp.v_x", "clamp.v_y", "clamp.v_z", "clamp.w_x", "clamp.w_y", "clamp.w_z")


def table_4_10() -> None:
    print("| arm | parameters | Jacobian | rank (full) | null vector |")
    print("| --- | --- | --- | --- | --- |")
    rng = np.random.default_rng(0)
    for arm in ("left", "right"):
        m = FRIDA[arm]
        q = rng.uniform(np.maximum(m.lower, -3), np.minimum(m.upper, 3), (10, 7))
        for blocks, label in ((("twists", "home"), "xi + T_st"), (("twists", "offsets"), "xi + dq")):
            r = thesis_rank(m, q, blocks)
            vec = "; ".join(", ".join(f"{c:+.3g} {n}" for n, c in v) for v in r.null_vectors) or "-"
            print(f"| {arm} | {label} | {r.shape[0]} x {r.shape[1]} | {r.rank} ({r.full}) | {vec} |")


def _offsets(seed: int):
    rng = np.random.default_rng(seed)
    true = FRIDA
    for arm in ("left", "right"):
        true = true.replace_arm(arm, true[arm].replace(offsets=rng.uniform(-0.05, 0.05, 7)))
    return true


def table_4_14(seeds=range(5)) -> None:
    print("| seed | first order right / left (rad) | recalibrated with the wrong clamp right / left | status | "
          "tool change right / left (mm RMS) | clamp estimated: offset error right / left (rad) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for seed in seeds:
        true = _offsets(seed)
        ds, _, _ = generate_dual(true, n=60, rng=seed + 1, noise=Noise(joint=1e-5), known_clamp=True)
        an = analyze(FRIDA, [ds], "offsets", errors=dict(zip(NAMES, ERROR)), workspace=200)
        names = [e.name for e in an.plan.estimates]
        side = {a: np.array([n.startswith(a + ".") for n in names]) for a in ("right", "left")}
        base = calibrate(FRIDA, [ds], "offsets")
        T = se3.exp(ERROR) @ ds.known["T_toolA_toolB"]
        wrong = calibrate(FRIDA, [Dataset(ds.kind, ds.robot, ds.arms, ds.q, ds.measured, {"T_toolA_toolB": T},
                                          ds.name, ds.meta)], "offsets")
        moved = np.array([wrong.estimate(n).value - base.estimate(n).value for n in names])
        free_ds, _, _ = generate_dual(true, n=60, rng=seed + 1, noise=Noise(joint=1e-5), known_clamp=False)
        est = calibrate(FRIDA, [free_ds], "offsets", noise=Noise(joint=1e-5))
        err = {a: np.linalg.norm([est.estimate(f"{a}.j{j + 1}.offset").value - true[a].offsets[j]
                                  for j in range(7) if est.estimate(f"{a}.j{j + 1}.offset").identifiable])
               for a in ("right", "left")}
        print(f"| {seed} | {np.linalg.norm(an.shift[side['right']]):.3f} / {np.linalg.norm(an.shift[side['left']]):.3f}"
              f" | {np.linalg.norm(moved[side['right']]):.3f} / {np.linalg.norm(moved[side['left']]):.3f} | "
              f"{wrong.status} | {an.error_tool['right'].position_rms * 1e3:.2f} / "
              f"{an.error_tool['left'].position_rms * 1e3:.2f} | {err['right']:.1e} / {err['left']:.1e} |")


if __name__ == "__main__":
    table_4_10()
    print()
    table_4_14()
