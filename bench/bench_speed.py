"""Speed on small and medium problems (issue 15): kincal against a minimal solver and FIGAROH, and kincal's
fixed cost per call split by phase.

Problem (the issue's): the built-in ``ur10`` with ``"fine"`` kinematic errors, an unknown tracker frame 2.5 m
away and one unknown marker on the tool, marker positions with 0.05 mm noise per axis, N = 50, 200, 1000 and
5000 random configurations; every identifiable parameter estimated (kincal: ``"kinematic"``, rank 27).

* kincal: ``calibrate(nominal, [ds], "kinematic", noise=Noise(position=5e-5, joint=0))``, the whole call.
* minimal: bench/reference_solver.py (vectorised NumPy, analytic Jacobian, 27 parameters: 18 modified-DH and
  Hayati link parameters, the tracker frame and the marker), from the same start rule, on the same data.
* FIGAROH 1.0.2 (both parameter selections) through bench/bench_figaroh.py's ``run_figaroh`` in its own
  virtualenv (``--figaroh-python``, default /tmp/venv-figaroh/bin/python, run with this checkout's kincal on
  PYTHONPATH and the same data); skipped with a note when that interpreter or figaroh is missing.

Times are process CPU times, medians of ``--repeat`` calls after one warm-up call, kincal's and the minimal
solver's calls alternating (``paired_medians``: the noise of a shared machine falls on both), FIGAROH's
``--figaroh-repeat`` (default 1: its time is Python loops and steady), BLAS pinned to one thread (threadpoolctl). Validation: 1000
fresh configurations, marker position in the tracker frame against the noise-free truth.

The phase table times kincal at N = 50 (and the sizes in ``--phases``) with a timer around each function
listed in ``PHASES``: time inside a listed function counts for the innermost one, the rest of ``calibrate`` is
"other". LAPACK's QR, SVD and lstsq are rows of their own wherever they are called.

"kincal CPU, caches emptied" is the same call with kincal's structure caches emptied before each call (the cost
of the first calibration of a structure); the other kincal columns are calls of a structure seen before (a
Monte Carlo repeat, a batch), as after the warm-up call. "kincal CPU, report read" is the call with its
``messages`` read after it: the final identifiability report named (a solve names it only when read, as the
start's report), what a caller that prints or saves the result pays.

The fixed overhead per call is kincal's CPU time above the minimal solver's at the smallest N (the issue's goal:
under 3 ms at N = 50); the intercepts of a straight-line fit of each solver's time over N are printed beside it.

Run: python bench/bench_speed.py [--sizes 50 200 1000 5000] [--repeat 5] [--no-figaroh] [--phases 50 5000]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads OpenBLAS

import argparse  # noqa: E402
import copyreg  # noqa: E402
import importlib  # noqa: E402
import json  # noqa: E402
import pickle  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import types  # noqa: E402
from contextlib import contextmanager  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

try:  # a kincal dependency, possibly missing from an older FIGAROH virtualenv (its worker pins BLAS by env)
    from threadpoolctl import threadpool_limits
except ImportError:  # pragma: no cover
    threadpool_limits = None

import bench_figaroh  # noqa: E402
import reference_solver  # noqa: E402
from kincal.estimation import Noise as StatedNoise  # noqa: E402
from kincal.estimation import calibrate  # noqa: E402



def _read_only(d: dict) -> types.MappingProxyType:
    return types.MappingProxyType(d)


# Data sets hold read-only mappings (meta, noise): pickled as the dict they wrap, to hand data to a worker
# (which runs this script as __main__ too, so it finds ``_read_only``).
copyreg.pickle(types.MappingProxyType, lambda m: (_read_only, (dict(m),)))

SIGMA_M = 5e-5  # tracker noise per axis (0.05 mm)
N_VALIDATION = bench_figaroh.N_VALIDATION
ARM = bench_figaroh.ARM
HERE = Path(__file__).resolve().parent
FIGAROH_PYTHON = "/tmp/venv-figaroh/bin/python"

# (label, "module:attribute" or "module:Class.method"): the phases of kincal's fixed cost.
PHASES = (
    ("problem set-up (layout, start values)", "kincal.estimation.problem:Problem.build"),
    ("rank analysis (identify, analyse)", "kincal.analysis.identifiability:identify"),
    ("rank analysis (identify, analyse)", "kincal.analysis.identifiability:analyse"),
    ("gauge symmetries (consistent nulls, readings)", "kincal.analysis.symmetries:consistent_nulls"),
    ("gauge symmetries (consistent nulls, readings)", "kincal.analysis.symmetries:scale_null"),
    ("gauge symmetries (consistent nulls, readings)", "kincal.analysis.symmetries:rotation_nulls"),
    ("naming null directions", "kincal.analysis.identifiability:_directions"),
    ("naming null directions", "kincal.analysis.identifiability:degenerate"),
    ("retraction (twists, frames)", "kincal.params.ops:retract"),
    ("re-centring (conform twists, tangent bases)", "kincal.params.ops:recentre"),
    ("FK (chain, joint-screw exponentials)", "kincal.kinematics.fk:chain"),
    ("FK (chain, joint-screw exponentials)", "kincal.kinematics.fk:sample_chain"),
    ("tool Jacobian (prefix projection)", "kincal.kinematics.jacobians:tool_jacobians"),
    ("marker residual (rest)", "kincal.experiments.markers:MarkersExperiment.residual"),
    ("stack and whiten (rest)", "kincal.estimation.problem:Problem.linearize"),
    ("stack and whiten (rest)", "kincal.estimation.problem:Problem.evaluate"),
    ("residual statistics", "kincal.estimation.problem:Problem.statistics"),
    ("gauge basis, Gauss-Newton step", "kincal.estimation.gauge:gauge_basis"),
    ("gauge basis, Gauss-Newton step", "kincal.estimation.steps:gauss_newton"),
    ("covariance, estimates, result (finalize rest)", "kincal.estimation.finalize:finalize"),
    ("collapse test (joint sensitivity)", "kincal.estimation.finalize:_lost_joint_sensitivity"),
    ("unit plausibility check", "kincal.estimation.plausibility:implausible_units"),
    ("outlier check", "kincal.estimation.outliers:any_beyond"),
    ("LAPACK QR", "numpy.linalg:qr"),
    ("LAPACK QR", "kincal.estimation.problem:triangular_factor"),
    ("LAPACK SVD", "numpy.linalg:svd"),
    ("LAPACK SVD", "kincal.analysis.linalg:thin_svd"),
    ("LAPACK QR", "kincal.analysis.linalg:complete_q"),
    ("LAPACK lstsq", "numpy.linalg:lstsq"),
)


# ------------------------------------------------------------------------------------------------- data


def make_data(seed: int, sizes):
    """Nominal robot, {N: Dataset}, validation readings and their noise-free marker positions (bench_figaroh's
    data at this bench's noise)."""
    return bench_figaroh.make_data(seed, sizes, SIGMA_M)


def rms_mm(pred, truth) -> float:
    return bench_figaroh.errors_mm(pred, truth)[0]


# ----------------------------------------------------------------------------------------------- solvers


def kincal_fit(nominal, ds):
    return calibrate(nominal, [ds], "kinematic", noise=StatedNoise(position=SIGMA_M, joint=0.0))


def kincal_val(res, q_val):
    return bench_figaroh.marker_in_tracker(res.robot[ARM], res.extras["tracker"], res.extras["markers"], q_val)


def minimal_fit(ds):
    return reference_solver.solve(reference_solver.ur10(), ds.q[ARM], ds.measured["p_tracker_marker"][:, 0])


def forget_structures() -> None:
    """Empty kincal's structure caches (what a calibration remembers between calls of the same structure:
    arm values per model, layout selections, joint-screw terms, the identifiability structure); a tree
    without them (an older kincal on PYTHONPATH) has nothing to empty."""
    for module in ("kincal.params", "kincal.lie.se3"):
        getattr(importlib.import_module(module), "clear_caches", lambda: None)()
    importlib.import_module("kincal.analysis.symmetries").clear_structure_cache()


def cpu_median(fn, repeat: int, before=None):
    """(median CPU s, median wall s, last output) of ``repeat`` calls after one warm-up call; ``before``: run
    before each call, untimed."""
    out, cpu, wall = fn(), [], []
    for _ in range(repeat):
        if before:
            before()
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - t0)
    return float(np.median(cpu)), float(np.median(wall)), out


def paired_medians(f, g, repeat: int):
    """``cpu_median`` of f and of g with their calls alternating (f, g, f, g, ...): a neighbour's load or a clock
    change falls on both alike, so the ratio of the two medians is steadier than from two runs one after the
    other."""
    outs, cpu, wall = [f(), g()], ([], []), ([], [])
    for _ in range(repeat):
        for k, fn in enumerate((f, g)):
            t0, c0 = time.perf_counter(), time.process_time()
            outs[k] = fn()
            cpu[k].append(time.process_time() - c0)
            wall[k].append(time.perf_counter() - t0)
    return tuple((float(np.median(cpu[k])), float(np.median(wall[k])), outs[k]) for k in (0, 1))


def measure(nominal, sets, q_val, y_val, repeat: int) -> dict:
    """Per N: CPU and wall medians, iterations and validation RMS of kincal and the minimal solver (their calls
    alternating: ``paired_medians``)."""
    rows = {}
    for n, ds in sets.items():
        (kc, kw, res), (mc, mw, fit) = paired_medians(lambda: kincal_fit(nominal, ds), lambda: minimal_fit(ds),
                                                      repeat)
        cold = cpu_median(lambda: kincal_fit(nominal, ds), repeat, before=forget_structures)[0]
        read = cpu_median(lambda: kincal_fit(nominal, ds).messages, repeat)[0]  # the final report named too
        rows[n] = {"kincal": (kc, kw), "kincal_cold": cold, "kincal_read": read, "minimal": (mc, mw),
                   "kincal_rms": rms_mm(kincal_val(res, q_val), y_val),
                   "minimal_rms": rms_mm(reference_solver.predict(fit.model, q_val), y_val),
                   "kincal_it": f"{res.iterations} outer, rank {res.identifiability.rank}",
                   "minimal_it": f"{fit.iterations} GN, {fit.model.size} parameters"}
    return rows


# ------------------------------------------------------------------------------------------------ FIGAROH


def figaroh(data, sizes, repeat: int, python: str) -> tuple[dict, str]:
    """{(N, method): (median CPU s, validation RMS mm)} from a worker in FIGAROH's interpreter, and a note."""
    if not Path(python).exists():
        return {}, f"FIGAROH skipped: {python} does not exist"
    with tempfile.TemporaryDirectory(prefix="kincal-bench-speed-") as tmp:
        path = Path(tmp) / "data.pkl"
        path.write_bytes(pickle.dumps(data))
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
                   PYTHONPATH=os.pathsep.join([str(HERE.parent / "src"), str(HERE)]))
        cmd = [python, str(Path(__file__).resolve()), "--figaroh-worker", str(path), "--figaroh-repeat", str(repeat),
               "--sizes", *map(str, sizes)]
        done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        return {}, f"FIGAROH skipped: its worker failed ({done.stderr.strip().splitlines()[-1:]})"
    out = json.loads(done.stdout.strip().splitlines()[-1])
    if "skipped" in out:
        return {}, out["skipped"]
    return {(int(n), m): tuple(v) for n, m, *v in out["runs"]}, f"FIGAROH run by {python}"


def figaroh_worker(path: str, sizes, repeat: int) -> None:
    """In FIGAROH's interpreter: both selections at every size; prints one JSON line."""
    if not bench_figaroh.figaroh_available():
        print(json.dumps({"skipped": "FIGAROH skipped: figaroh is not importable in its interpreter"}))
        return
    nominal, sets, q_val, y_val = pickle.loads(Path(path).read_bytes())
    runs = []
    for n in sizes:
        for method in ("structural", "excitation"):
            got = [bench_figaroh.run_figaroh(nominal, sets[n], q_val, y_val, method) for _ in range(repeat)]
            runs.append((n, method, float(np.median([r.cpu_s for r in got])), got[-1].rms_mm))
    print(json.dumps({"runs": runs}))


# ------------------------------------------------------------------------------------------------- phases


def _resolve(target: str):
    """(owner, attribute name, original) of "module:attr" or "module:Class.method"."""
    module, _, path = target.partition(":")
    owner = importlib.import_module(module)
    *classes, name = path.split(".")
    for c in classes:
        owner = getattr(owner, c)
    return owner, name, owner.__dict__[name] if classes else getattr(owner, name)


class PhaseTimer:
    """Exclusive CPU time per phase: a call's time counts for the innermost timed function it is in."""

    def __init__(self):
        self.totals: dict[str, float] = {}
        self.stack: list[list[float]] = []

    def wrap(self, label: str, fn):
        def timed(*args, **kwargs):
            self.stack.append([time.process_time(), 0.0])
            try:
                return fn(*args, **kwargs)
            finally:
                t0, inner = self.stack.pop()
                spent = time.process_time() - t0
                self.totals[label] = self.totals.get(label, 0.0) + spent - inner
                if self.stack:
                    self.stack[-1][1] += spent
        return timed

    @contextmanager
    def installed(self, phases):
        """Every function of ``phases`` wrapped where it is defined and where kincal modules imported it."""
        undo, missing = [], []
        for label, target in phases:
            try:
                owner, name, original = _resolve(target)
            except (ImportError, AttributeError, KeyError):
                missing.append(target)
                continue
            raw = original.__func__ if isinstance(original, (classmethod, staticmethod)) else original
            wrapped = self.wrap(label, raw)
            if isinstance(original, (classmethod, staticmethod)):
                wrapped = type(original)(wrapped)
            places = [(owner, name)] + [(m, k) for mod, m in list(sys.modules.items()) if mod.startswith("kincal")
                                        for k, v in list(vars(m).items()) if v is raw and m is not owner]
            for place, key in places:
                undo.append((place, key, place.__dict__[key] if isinstance(place, type) else getattr(place, key)))
                setattr(place, key, wrapped if place is owner else self.wrap(label, raw))
        try:
            yield missing
        finally:
            for place, key, value in reversed(undo):
                setattr(place, key, value)


def phases(nominal, ds, calls: int):
    """(rows [(phase, ms per call)], total ms per call, unlisted targets) of ``calls`` kincal calls."""
    kincal_fit(nominal, ds)  # warm-up
    timer = PhaseTimer()
    with timer.installed(PHASES) as missing:
        c0 = time.process_time()
        for _ in range(calls):
            kincal_fit(nominal, ds)
        total = time.process_time() - c0
    listed = sum(timer.totals.values())
    rows = sorted(((k, v / calls * 1e3) for k, v in timer.totals.items()), key=lambda kv: -kv[1])
    return rows + [("other (calibrate's own code and everything unlisted)", (total - listed) / calls * 1e3)], \
        total / calls * 1e3, missing


# ------------------------------------------------------------------------------------------------- report


def markdown(head, rows) -> str:
    rows = [tuple(head)] + [tuple(r) for r in rows]
    widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
    fmt = lambda r: "| " + " | ".join(c.ljust(w) for c, w in zip(r, widths)) + " |"  # noqa: E731
    return "\n".join([fmt(rows[0]), "|" + "|".join("-" * (w + 2) for w in widths) + "|"] + [fmt(r) for r in rows[1:]])


def ms(s: float) -> str:
    return f"{s * 1e3:.2f} ms" if s < 1 else f"{s:.2f} s"


def speed_table(rows, fig) -> str:
    head = ["N", "kincal CPU", "FIGAROH structural", "FIGAROH excitation", "FIGAROH / kincal", "minimal CPU",
            "kincal / minimal", "kincal wall", "minimal wall", "kincal CPU, caches emptied", "kincal CPU, report read"]
    out = []
    for n, r in rows.items():
        k, m = r["kincal"][0], r["minimal"][0]
        f = [fig.get((n, meth)) for meth in ("structural", "excitation")]
        ratio = " / ".join(f"{x[0] / k:.0f}x" for x in f if x) or "-"
        out.append([str(n), ms(k), *(ms(x[0]) if x else "-" for x in f), ratio, ms(m), f"{k / m:.2f}x",
                    ms(r["kincal"][1]), ms(r["minimal"][1]), ms(r["kincal_cold"]),
                    ms(r["kincal_read"]) if "kincal_read" in r else "-"])
    return markdown(head, out)


def overhead_line(rows) -> str:
    """kincal's fixed cost per call: its CPU time above the minimal solver's at the smallest N (the issue's
    measure, goal under 3 ms at N = 50), and both solvers' intercepts of a straight-line fit over N."""
    sizes = sorted(rows)
    k = np.array([rows[n]["kincal"][0] for n in sizes])
    m = np.array([rows[n]["minimal"][0] for n in sizes])
    out = f"fixed overhead per call at N = {sizes[0]} (kincal - minimal CPU): {(k[0] - m[0]) * 1e3:.1f} ms"
    if len(sizes) > 1:
        fit = lambda t: np.polyfit(sizes, t, 1)[1] * 1e3  # noqa: E731
        out += f"; intercepts of a straight-line fit over N: kincal {fit(k):.1f} ms, minimal {fit(m):.1f} ms"
    return out


def accuracy_table(rows, fig) -> str:
    head = ["N", "kincal val RMS mm", "minimal val RMS mm", "FIGAROH structural", "FIGAROH excitation", "kincal",
            "minimal"]
    out = [[str(n), f"{r['kincal_rms']:.5f}", f"{r['minimal_rms']:.5f}",
            *(f"{fig[(n, m)][1]:.5f}" if (n, m) in fig else "-" for m in ("structural", "excitation")),
            r["kincal_it"], r["minimal_it"]] for n, r in rows.items()]
    return markdown(head, out)


def phase_table(n, rows, total, missing) -> str:
    listed = markdown(["phase", "ms per call", "share"], [[k, f"{v:.2f}", f"{v / total:.0%}"] for k, v in rows])
    note = f"\n(not found, so not timed: {', '.join(missing)})" if missing else ""
    return f"kincal per call at N = {n}, by phase (CPU, {total:.1f} ms per call with the timers):\n{listed}{note}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[50, 200, 1000, 5000])
    ap.add_argument("--repeat", type=int, default=5, help="median of this many calls (kincal, minimal)")
    ap.add_argument("--figaroh-repeat", type=int, default=1)
    ap.add_argument("--figaroh-python", default=FIGAROH_PYTHON)
    ap.add_argument("--no-figaroh", action="store_true")
    ap.add_argument("--phases", type=int, nargs="*", default=[50], help="sizes of the phase tables")
    ap.add_argument("--phase-calls", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--figaroh-worker", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.figaroh_worker:
        return figaroh_worker(args.figaroh_worker, args.sizes, args.figaroh_repeat)
    data = make_data(args.seed, sorted(set(args.sizes) | set(args.phases)))
    nominal, sets, q_val, y_val = data
    with threadpool_limits(limits=1, user_api="blas"):  # main process only: it has kincal's dependencies
        rows = measure(nominal, {n: sets[n] for n in args.sizes}, q_val, y_val, args.repeat)
        tables = [phase_table(n, *phases(nominal, sets[n], args.phase_calls)) for n in args.phases]
    fig, note = ({}, "FIGAROH skipped: --no-figaroh") if args.no_figaroh else \
        figaroh(data, args.sizes, args.figaroh_repeat, args.figaroh_python)
    print(f"UR10 'fine', unknown tracker frame and one marker, sigma {SIGMA_M * 1e3:.2f} mm; BLAS on one thread; "
          f"CPU medians of {args.repeat} (FIGAROH: {args.figaroh_repeat}); load average {os.getloadavg()[0]:.1f}")
    print(note)
    print(speed_table(rows, fig))
    print(overhead_line(rows))
    print(f"\nvalidation on {N_VALIDATION} fresh configurations (marker in the tracker frame, noise-free truth):")
    print(accuracy_table(rows, fig))
    for table in tables:
        print("\n" + table)


if __name__ == "__main__":
    main()
