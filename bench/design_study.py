"""Designed against random configurations for every experiment kind: the tables and plots of docs/design.md.

For each experiment (a scenario's experiment on the nominal robot, candidates from its generator): the predicted
tool position error (RMS over a workspace sample, from the information of the chosen configurations and the
stated noise) of K = 15 D-optimal and I-optimal configurations, and how many random configurations give the
same (median over 20 random draws per size): "designed K = 15 is worth n random". Then, for the tracker, the
criterion against K and a predicted accuracy map (plots in docs/img/).

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python bench/design_study.py [--pool 600] [--plots]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from kincal.analysis.design import information, select  # noqa: E402
from kincal.estimation import Problem, SolverOptions  # noqa: E402
from kincal.estimation.plan import plan  # noqa: E402
from kincal.io.datasets import load_scenario, scenario_path  # noqa: E402
from kincal.simulate.scenario import build_scenario  # noqa: E402
from kincal.estimation.plan import identifiable_basis  # noqa: E402
from kincal.workflow.design import _candidate_rows, _tool_error, _workspace_rows, candidate_pool  # noqa: E402

CASES = (("ur10_tracker_markers", "kinematic"), ("frida_clamp_one", "offsets"), ("frida_plate4", "offsets"),
         ("frida_dual_bracket", "offsets"))
K = 15
DRAWS = 20


def rows(name: str, free: str, pool: int, seed: int = 0):
    sc = build_scenario(load_scenario(scenario_path(name)))
    ds = candidate_pool(sc.robot, sc.kind, sc.options, pool, seed)
    problem = Problem.build(sc.robot, [ds], free, noise=sc.noise)
    p = plan(problem, SolverOptions())
    V = identifiable_basis(problem, p.identifiability)
    return sc, _candidate_rows(problem, p, V), _workspace_rows(sc.robot, p, V, 100, seed), p.rank


def random_curve(X, W, sizes, rng) -> np.ndarray:
    """Median predicted tool RMS (m) of random designs per size."""
    return np.array([np.median([_tool_error(information(X[rng.choice(len(X), n, replace=False)]), W)[0]
                                for _ in range(DRAWS)]) for n in sizes])


def worth(value: float, sizes, curve) -> str:
    hit = [n for n, c in zip(sizes, curve) if c <= value]
    return str(hit[0]) if hit else f"> {sizes[-1]}"


def table(pool: int) -> None:
    print(f"| experiment | free | rank | rows per configuration | random K = {K} (mm) | D-optimal (mm) | worth random "
          f"| I-optimal (mm) | worth random | select s (D) |")
    print("| --- " * 10 + "|")
    for name, free in CASES:
        sc, X, W, rank = rows(name, free, pool)
        rng = np.random.default_rng(1)
        sizes = list(range(K, 8 * K + 1, 3))
        curve = random_curve(X, W, sizes, rng)
        cells = []
        t = time.perf_counter()
        for crit in ("D", "I"):
            sel = select(X, K, crit, workspace=W)
            if crit == "D":
                t = time.perf_counter() - t
            v = _tool_error(information(X[sel.indices]), W)[0]
            cells += [f"{v * 1e3:.4f}", worth(v, sizes, curve)]
        print(f"| {name} ({sc.kind}) | {free} | {rank} | {X.shape[1]} | {curve[0] * 1e3:.4f} | " + " | ".join(cells)
              + f" | {t:.2f} |")


def plots(pool: int, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sc, X, W, rank = rows("ur10_tracker_markers", "kinematic", pool)
    sizes = list(range(10, 61, 5))
    rng = np.random.default_rng(1)
    rand = random_curve(X, W, sizes, rng)
    des = {c: [_tool_error(information(X[select(X, n, c, workspace=W).indices]), W)[0] for n in sizes]
           for c in ("D", "I")}
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(sizes, rand * 1e3, "k.-", label="random (median of 20)")
    for c, v in des.items():
        ax.plot(sizes, np.array(v) * 1e3, ".-", label=f"{c}-optimal")
    ax.set_xlabel("configurations K")
    ax.set_ylabel("predicted tool position std, RMS (mm)")
    ax.set_yscale("log")
    ax.set_title(f"scenario ur10_tracker_markers, level kinematic (rank {rank})")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "design_criterion_vs_k.png", dpi=110)
    _map(plt, X, W, rank, out)


def _map(plt, X, W, rank, out: Path) -> None:
    """Predicted std per workspace configuration: D-optimal against a random design of the same size."""
    sel = select(X, 20, "D").indices
    rnd = np.random.default_rng(3).choice(len(X), 20, replace=False)
    fig, ax = plt.subplots(figsize=(6, 4))
    for idx, label in ((rnd, "random 20"), (sel, "D-optimal 20")):
        Minv = np.linalg.inv(information(X[idx]))
        std = np.sqrt(np.einsum("wcr,rs,wcs->w", W, Minv, W))
        ax.hist(std * 1e3, bins=30, alpha=0.6, label=f"{label}: RMS {np.sqrt(np.mean(std**2)) * 1e3:.3f} mm")
    ax.set_xlabel("predicted tool position std at a workspace configuration (mm)")
    ax.set_ylabel("configurations of the workspace sample")
    ax.set_title("accuracy over 100 random workspace configurations")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "design_accuracy_map.png", dpi=110)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--pool", type=int, default=600)
    ap.add_argument("--plots", action="store_true")
    a = ap.parse_args()
    table(a.pool)
    if a.plots:
        out = Path(__file__).resolve().parents[1] / "docs" / "img"
        out.mkdir(exist_ok=True)
        plots(a.pool, out)
