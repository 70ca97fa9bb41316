"""kincal against FIGAROH: tracker calibration of a UR10 from one marker position (issue 4, bench (b)).

One true robot (nominal ``ur10`` with ``"fine"`` kinematic errors), an unknown tracker frame 2.5 m away and
one unknown marker on the tool; the tracker measures the marker position with 0.02 mm noise at N random
configurations within the limits. Both tools get the same joint readings and marker positions (FIGAROH
through its CSV, URDF and YAML files, written to a temporary directory) and estimate every geometric
parameter plus the tracker frame and the marker offset. Validation: 1000 fresh configurations, error of
the predicted marker position in the tracker frame against the noise-free truth.

Run (FIGAROH lives in its own virtualenv, with kincal installed there in editable mode)::

    python3 -m venv /tmp/venv-figaroh
    /tmp/venv-figaroh/bin/pip install figaroh && /tmp/venv-figaroh/bin/pip install -e .
    /tmp/venv-figaroh/bin/python bench/bench_figaroh.py [--sizes 1000 5000] [--seed 0] [--profile]

Without figaroh importable only the kincal half runs. Times are wall times of one run. BLAS runs
single-threaded unless OPENBLAS_NUM_THREADS is set: on a shared 2-core machine OpenBLAS threads spin against
other processes and made kincal's times vary 10x (0.4 to 4.4 s for the same solve).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads OpenBLAS (see the docstring)

import argparse  # noqa: E402
import contextlib  # noqa: E402
import csv  # noqa: E402
import io  # noqa: E402
import logging  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

from kincal.estimation import Noise as StatedNoise  # noqa: E402
from kincal.estimation import calibrate  # noqa: E402
from kincal.kinematics import ArmModel, forward_kinematics  # noqa: E402
from kincal.io.urdf import to_urdf  # noqa: E402
from kincal.lie import se3  # noqa: E402
from kincal.robots import load  # noqa: E402
from kincal.simulate import Noise, generate_markers, perturb_robot, random_configurations  # noqa: E402
from kincal.simulate.generators import random_markers, random_tracker_pose  # noqa: E402

SIGMA_M = 2e-5  # tracker noise per axis (0.02 mm)
N_VALIDATION = 1000
ARM = "arm"


@dataclass
class Run:
    tool: str
    n: int
    select_s: float  # parameter selection outside the solve (FIGAROH: structural QR + absorbed-parameter test)
    solve_s: float
    iterations: str
    parameters: str
    status: str
    rms_mm: float
    max_mm: float
    cpu_s: float = float("nan")  # process CPU time of select + solve (all threads): robust to other users' load
    notes: dict = field(default_factory=dict)

    @property
    def total_s(self) -> float:
        return self.select_s + self.solve_s


# ------------------------------------------------------------------------------------------------- data


def make_data(seed: int, sizes, sigma: float = SIGMA_M):
    """True robot, tracker, marker; one calibration set per size (``sigma``: tracker noise per axis, m);
    validation readings and true positions."""
    rng = np.random.default_rng(seed)
    nominal = load("ur10")
    true = perturb_robot(nominal, "fine", rng=rng)
    T_world_tracker = random_tracker_pose(true, ARM, rng)
    p_tool_marker = random_markers(1, rng)
    sets = {}
    for n in sizes:
        ds, truth, _ = generate_markers(
            true, ARM, n=n, rng=rng, noise=Noise(position=sigma), markers=p_tool_marker,
            T_world_tracker=T_world_tracker, n_validation=1,
        )
        sets[n] = ds
    q_val = random_configurations(true[ARM], N_VALIDATION, rng, margin=0.05)
    y_val = marker_in_tracker(true[ARM], T_world_tracker, p_tool_marker, q_val)
    return nominal, sets, q_val, y_val


def marker_in_tracker(model: ArmModel, T_world_tracker, p_tool_marker, q) -> np.ndarray:
    """Predicted marker positions in the tracker frame, (N, 3)."""
    T_tracker_tool = se3.inverse(T_world_tracker) @ forward_kinematics(model, q)
    return se3.transform_points(T_tracker_tool, np.asarray(p_tool_marker).reshape(3))


def errors_mm(pred, truth) -> tuple[float, float]:
    e = np.linalg.norm(pred - truth, axis=-1) * 1e3
    return float(np.sqrt(np.mean(e**2))), float(np.max(e))


# ------------------------------------------------------------------------------------------------ kincal


def nominal_errors(nominal, ds, q_val, y_val):
    """Validation error of the nominal model with only the tracker frame and marker fitted (same for both)."""
    res = calibrate(nominal, [ds], free=[], noise=StatedNoise(position=SIGMA_M, joint=0.0))
    return errors_mm(marker_in_tracker(nominal[ARM], res.extras["tracker"], res.extras["markers"], q_val), y_val)


def run_kincal(nominal, ds, q_val, y_val, profile: bool = False) -> Run:
    noise = StatedNoise(position=SIGMA_M, joint=0.0)
    prof = None
    if profile:
        import cProfile

        prof = cProfile.Profile()
        prof.enable()
    t0, c0 = time.perf_counter(), time.process_time()
    res = calibrate(nominal, [ds], "kinematic", noise=noise)
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    if prof is not None:
        prof.disable()
    pred = marker_in_tracker(res.robot[ARM], res.extras["tracker"], res.extras["markers"], q_val)
    rms, mx = errors_mm(pred, y_val)
    ident = res.identifiability
    run = Run("kincal", ds.size, 0.0, dt, f"{res.iterations} outer / {res.evaluations} evals",
              f"{ident.rank} of {len(ident.names)}", res.status, rms, mx, cpu)
    run.notes["fit_rms_mm"] = res.after[0].position_rms * 1e3
    if prof is not None:
        run.notes["profile"] = prof
    return run


# ----------------------------------------------------------------------------------------------- FIGAROH


def figaroh_available() -> bool:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pinocchio/ndcurves converter warnings at import
            import figaroh.calibration  # noqa: F401
    except ImportError:
        return False
    return True


def write_figaroh_inputs(folder: Path, model: ArmModel, ds, method: str) -> Path:
    """URDF of the nominal arm, CSV of readings and marker positions, unified YAML config; returns the config."""
    (folder / "arm.urdf").write_text(to_urdf(model))
    names = list(model.joint_names)
    q = ds.q[ARM]
    y = ds.measured["p_tracker_marker"][:, 0]
    with open(folder / "calibration.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["x1", "y1", "z1"] + names)
        w.writerows(np.concatenate([y, q], axis=1).tolist())  # repr round-trips float64
    config = {
        "robot": {"name": model.name, "properties": {"joints": {"active_joints": names}}},
        "tasks": {"calibration": {
            "enabled": True,
            "parameters": {"calibration_level": "full_params", "include_non_geometric": False,
                           "estimation": {"method": method}},
            "kinematics": {"base_frame": "universe", "tool_frame": "tool"},
            "measurements": {
                "markers": [{"name": "marker", "reference_joint": names[-1],
                             "measurable_dof": [True, True, True, False, False, False]}],
                "poses": {"base_pose": [0.0] * 6, "tool_pose": [0.0] * 6},
            },
            "data": {"source_file": str(folder / "calibration.csv"), "number_of_samples": int(ds.size)},
        }},
    }
    path = folder / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def figaroh_class():
    from figaroh.calibration import BaseCalibration
    from figaroh.calibration.calibration_tools import calc_updated_fkm

    class TrackerCalibration(BaseCalibration):
        """Unweighted position residuals of the one marker (FIGAROH's UR10 example without its weights)."""

        evaluations = 0
        lm_seconds = 0.0

        def cost_function(self, var):
            self.evaluations += 1
            return self.PEE_measured - calc_updated_fkm(self.model, self.data, var, self.q_measured, self.calib_config)

        def _optimize_with_outlier_removal(self, *args, **kwargs):
            t0 = time.perf_counter()
            out = super()._optimize_with_outlier_removal(*args, **kwargs)
            self.lm_seconds += time.perf_counter() - t0
            return out

    return TrackerCalibration, calc_updated_fkm


def run_figaroh(nominal, ds, q_val, y_val, method: str) -> Run:
    from figaroh.tools.load_robot import load_robot

    TrackerCalibration, calc_updated_fkm = figaroh_class()
    with tempfile.TemporaryDirectory(prefix="kincal-bench-figaroh-") as tmp:
        config = write_figaroh_inputs(Path(tmp), nominal[ARM], ds, method)
        robot = load_robot(str(Path(tmp) / "arm.urdf"), load_by_urdf=True)
        calib = TrackerCalibration(robot, str(config))
        calib.calib_config["known_baseframe"] = False  # tracker frame unknown
        calib.calib_config["known_tipframe"] = False  # marker offset unknown
        calib.load_data_set()  # reading the CSV: not timed
        console = io.StringIO()
        with contextlib.redirect_stdout(console):
            t0, c0 = time.perf_counter(), time.process_time()
            calib.create_param_list()
            t1 = time.perf_counter()
            selection_evals = calib.evaluations
            result = calib.solve(enable_logging=False)
            t2, c2 = time.perf_counter(), time.process_time()
    cfg = dict(calib.calib_config, NbSample=len(q_val))
    pred = calc_updated_fkm(calib.model, calib.data, result.x, q_val, cfg).reshape(3, -1).T
    rms, mx = errors_mm(pred, y_val)
    fit = np.linalg.norm((calib.PEE_measured - calc_updated_fkm(
        calib.model, calib.data, result.x, calib.q_measured, calib.calib_config)).reshape(3, -1), axis=0)
    evals = f"{selection_evals} + {calib.evaluations - selection_evals} evals (FD)"
    run = Run(f"FIGAROH {method}", ds.size, t1 - t0, t2 - t1, evals, f"{len(calib.calib_config['param_name'])} base",
              "converged" if result.success else "failed", rms, mx, c2 - c0)
    run.notes.update(lm_s=calib.lm_seconds, fit_rms_mm=float(np.sqrt(np.mean(fit**2)) * 1e3),
                     params=list(calib.calib_config["param_name"]),
                     absorbed=list(calib.calib_config.get("absorbed_param_name", [])))
    return run


# ------------------------------------------------------------------------------------------------ report


def table(runs, before) -> str:
    head = ("tool", "N", "select s", "solve s", "total s", "CPU s", "iterations", "params", "status",
            "val RMS mm", "val max mm", "fit RMS mm")
    rows = [head]
    for n, (rms, mx) in before.items():
        rows.append(("nominal", str(n), "", "", "", "", "", "", "frames fitted", f"{rms:.3f}", f"{mx:.3f}", ""))
    for r in runs:
        rows.append((r.tool, str(r.n), f"{r.select_s:.3f}", f"{r.solve_s:.3f}", f"{r.total_s:.3f}", f"{r.cpu_s:.2f}",
                     r.iterations, r.parameters, r.status, f"{r.rms_mm:.4f}", f"{r.max_mm:.4f}",
                     f"{r.notes['fit_rms_mm']:.4f}"))
    widths = [max(len(row[i]) for row in rows) for i in range(len(head))]
    fmt = lambda row: "| " + " | ".join(c.ljust(w) for c, w in zip(row, widths)) + " |"  # noqa: E731
    lines = [fmt(rows[0]), "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    return "\n".join(lines + [fmt(r) for r in rows[1:]])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 5000])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--figaroh-methods", nargs="+", default=["structural", "excitation"],
                        help="FIGAROH parameter selection (calib_config estimation.method) to run")
    parser.add_argument("--profile", action="store_true", help="cProfile kincal's solve at the largest size")
    parser.add_argument("--no-figaroh", action="store_true", help="run the kincal half only")
    args = parser.parse_args()
    logging.getLogger("figaroh").setLevel(logging.WARNING)

    have_figaroh = not args.no_figaroh and figaroh_available()
    if not have_figaroh:
        print("FIGAROH skipped: " + ("--no-figaroh given" if args.no_figaroh else "figaroh is not importable"))
    nominal, sets, q_val, y_val = make_data(args.seed, args.sizes)
    runs, before = [], {}
    for n, ds in sets.items():
        before[n] = nominal_errors(nominal, ds, q_val, y_val)
        runs.append(run_kincal(nominal, ds, q_val, y_val, profile=args.profile and n == max(args.sizes)))
        for method in args.figaroh_methods if have_figaroh else ():
            runs.append(run_figaroh(nominal, ds, q_val, y_val, method))
    print(f"BLAS threads: OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")
    print(f"UR10, 'fine' errors, unknown tracker frame and marker, sigma {SIGMA_M * 1e3:.2f} mm, "
          f"validation on {N_VALIDATION} fresh configurations (marker position in the tracker frame)")
    print(table(runs, before))
    for r in runs:
        if not r.tool.startswith("FIGAROH"):
            continue
        k = next(x for x in runs if x.tool == "kincal" and x.n == r.n)
        print(f"N={r.n}, {r.tool}: FIGAROH / kincal total time {r.total_s / k.total_s:.2f}x "
              f"(FIGAROH least squares alone {r.notes['lm_s']:.2f} s); {len(r.notes['params'])} parameters: "
              f"{', '.join(r.notes['params'])}; dropped as dependent: {', '.join(r.notes['absorbed']) or 'none'}")
    for r in runs:
        if "profile" in r.notes:
            import pstats

            print(f"\nkincal profile, N={r.n} (cumulative, top 25; then own time, top 15):")
            pstats.Stats(r.notes["profile"]).sort_stats("cumulative").print_stats(25)
            pstats.Stats(r.notes["profile"]).sort_stats("tottime").print_stats(15)


if __name__ == "__main__":
    main()
