"""Time one evaluation of a tree robot's calibration problem under gravity: the whitened residual alone and the
residual with its Jacobian (``Problem.evaluate``, as the inner solver calls it: ``estimation.steps``), median
of several runs, BLAS on one thread.

Cases: DLR Agile Justin (``../shared/datasets``, skipped when absent; both hands, 500 poses each, the mass
model) at ``[kinematic, elastic]`` and with ``lateral`` too, and a simulated tree (``dual7_torso`` with link
masses on a tilted pedestal, as tests/test_tree_gravity.py) at the same two levels, which runs without data.
Each is evaluated at a non-trivial state: every free coordinate moved (geometry by about 1e-3, compliances by
about 1e-5 rad/(N m)), so every compliance term is live.

``--save FILE`` keeps the residuals and Jacobians; ``--check FILE`` asserts the current code gives the same to
1e-12 relative (per Jacobian column, against the column's largest entry). To compare against an older
version of the package, save with it first::

    git archive <old commit> src | tar -x -C /tmp/kincal-old
    OPENBLAS_NUM_THREADS=1 PYTHONPATH=/tmp/kincal-old/src .venv/bin/python bench/bench_tree_eval.py --save /tmp/ref.npz
    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_tree_eval.py --check /tmp/ref.npz [--profile]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads OpenBLAS

import argparse  # noqa: E402
import cProfile  # noqa: E402
import pstats  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import realdata as rd  # noqa: E402

from kincal.estimation import Problem  # noqa: E402
from kincal.io.models import load_builtin  # noqa: E402
from kincal.kinematics import Robot  # noqa: E402
from kincal.lie import se3, so3  # noqa: E402
from kincal.noise import Noise  # noqa: E402
from kincal.simulate.generators import generate_markers  # noqa: E402

LEVELS = {"elastic": ["kinematic", "elastic"], "lateral": ["kinematic", "elastic", "lateral"]}
STEP = {"rad": 1e-3, "m": 1e-3, "rad/Nm": 1e-5, "m/N": 1e-7}  # the size of the state's departure per unit


def justin(level: str):
    path = rd.folder(rd.JUSTIN)
    robot, sets, _ = rd.justin_elastic_case(path, "lateral compliances" if level == "lateral" else "joint compliances")
    return Problem.build(robot, sets, LEVELS[level], fixed=["torso.t1.compliance"], noise=rd.JUSTIN_NOISE)


def sim_tree(level: str):
    """dual7_torso with masses on a tilted pedestal (tests/test_tree_gravity.py), 200 poses per hand."""
    nom = load_builtin("dual7_torso")
    rng = np.random.default_rng(0)
    tilt = se3.make(so3.exp(np.array([0.5, 0.0, 0.0])), [0.0, 0.0, 0.3])
    arms = {"torso": nom["torso"].replace(base=tilt @ nom["torso"].base, link_masses=[20.0, 15.0],
                                          link_coms=[[0, 0, 0.2], [0.05, 0, 0.5]], gravity=[0, 0, -9.81])}
    for a in ("left", "right"):
        arms[a] = nom[a].replace(link_masses=np.linspace(4, 0.5, 7), link_coms=rng.uniform(-0.3, 0.3, (7, 3)),
                                 payload_mass=2.0, payload_com=[0.0, 0.0, 0.05])
    if level == "lateral":
        arms = {a: m.replace(lateral=np.zeros((m.dof, 2))) for a, m in arms.items()}
    robot = Robot(nom.name, arms, mounts=nom.mounts)
    sets = []
    for seed, arm in ((1, "left"), (2, "right")):
        ds, _, _ = generate_markers(robot, arm, n=200, rng=seed, markers=3, noise=Noise(position=2e-5))
        sets.append(ds.__class__(**{**ds.__dict__, "name": f"{arm}-hand"}))
    return Problem.build(robot, sets, LEVELS[level])


def point(problem: Problem) -> tuple:
    """(state, delta, whiteners): a departure of every free coordinate, seeded."""
    rng = np.random.default_rng(7)
    units = np.array(problem.layout.units)[problem.free_idx]
    delta = np.array([STEP.get(u, 1e-3) for u in units]) * rng.uniform(0.5, 1.0, len(units))
    delta *= rng.choice([-1.0, 1.0], len(units))
    state = problem.start
    return state, delta, problem.whiteners(state)


def median_ms(fn, repeat: int) -> tuple[float, float]:
    """Median wall and CPU (this process) milliseconds: on a shared machine the CPU time is the steadier."""
    fn()  # warm caches
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return float(np.median(wall)) * 1e3, float(np.median(cpu)) * 1e3


def check(name: str, r, J, ref) -> str:
    r0, J0 = ref[f"{name}/r"], ref[f"{name}/J"]
    assert r.shape == r0.shape and J.shape == J0.shape, (name, r.shape, r0.shape, J.shape, J0.shape)
    er = np.max(np.abs(r - r0)) / np.max(np.abs(r0))
    scale = np.max(np.abs(J0), axis=0)
    scale[scale == 0] = 1.0
    eJ = np.max(np.abs(J - J0) / scale)
    assert er <= 1e-12 and eJ <= 1e-12, (name, er, eJ)
    return f"same as saved: r {er:.1e}, J {eJ:.1e} (relative)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--save", type=Path)
    ap.add_argument("--check", type=Path)
    ap.add_argument("--profile", action="store_true", help="cProfile one residual+Jacobian of each case")
    ap.add_argument("--only", choices=["justin", "sim"])
    args = ap.parse_args()
    ref = np.load(args.check) if args.check else None
    saved = {}
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}")
    for name, build in (("justin", justin), ("sim", sim_tree)):
        if args.only and args.only != name:
            continue
        for level in LEVELS:
            try:
                problem = build(level)
            except rd.DataMissing as e:
                print(f"{name} {level}: skipped ({e})")
                continue
            state, delta, W = point(problem)
            r, J = problem.evaluate(state, delta, W, jac=True)
            key = f"{name}-{level}"
            saved[f"{key}/r"], saved[f"{key}/J"] = r, J
            t_r = median_ms(lambda: problem.evaluate(state, delta, W, jac=False), args.repeat)
            t_j = median_ms(lambda: problem.evaluate(state, delta, W, jac=True), args.repeat)
            note = check(key, r, J, ref) if ref is not None and f"{key}/r" in ref else ""
            print(f"{key:16s} rows {J.shape[0]:5d} free {J.shape[1]:4d}: residual {t_r[0]:7.2f} ms (cpu "
                  f"{t_r[1]:7.2f}), residual+Jacobian {t_j[0]:7.2f} ms (cpu {t_j[1]:7.2f})  {note}")
            if args.profile:
                prof = cProfile.Profile(time.process_time)
                prof.runcall(lambda: [problem.evaluate(state, delta, W, jac=True) for _ in range(5)])
                pstats.Stats(prof).sort_stats("tottime").print_stats(15)
    if args.save:
        np.savez(args.save, **saved)
        print(f"saved {args.save}")
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}")


if __name__ == "__main__":
    main()
