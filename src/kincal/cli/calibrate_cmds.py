"""``kincal calibrate JOB.yaml -o OUT`` and ``kincal demo``: run a calibration, print a summary, write results."""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from kincal.cli.console import make_console
from kincal.errors import DataFormatError
from kincal.estimation import validation_stats
from kincal.io.datasets import load_scenario
from kincal.io.jobs import load_job
from kincal.io.results import cross_validation_dict, data_warnings, prediction_rows, result_to_dict, stage_rows
from kincal.simulate.perturb import perturbation
from kincal.simulate.scenario import build_scenario, run
from kincal.workflow import run_job
from kincal.workflow.outputs import DEMO_ENTRIES, require_plots, write_calibration, write_demo_input
from kincal.workflow.provenance import provenance

DEG = 180.0 / math.pi
DEMO_SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "frida_dual_bracket.yaml"


def _console() -> Console:
    return make_console(highlight=False, markup=False)  # tables split, never cut, to fit (kincal.cli.console)


def _num(x, scale=1.0, digits=4) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x * scale:.{digits}g}"


def _shown(e) -> tuple[str, float, float]:
    """(unit, value, std) in display units: deg and mm; compliances in their SI units (rad/Nm, m/N)."""
    if e.unit not in ("rad", "m"):
        return e.unit, e.value, e.std
    k = DEG if e.unit == "rad" else 1e3
    return ("deg" if e.unit == "rad" else "mm"), e.value * k, e.std * k


# Outlying rows printed on the console at most; result.yaml lists them all.
MAX_OUTLIERS_SHOWN = 20


def _print_outliers(console: Console, outliers, what: str = "") -> None:
    """The rows left out as outliers, one line each (at most ``MAX_OUTLIERS_SHOWN``, then how many more)."""
    if not outliers:
        return
    console.print(f"{len(outliers)} {what}configuration(s) left out as outliers (standardized residual in sigmas):")
    for o in outliers[:MAX_OUTLIERS_SHOWN]:
        where = f"{o.file}: line {o.line}" if o.line is not None else f"sample {o.sample}"
        console.print(f"  {o.experiment}: {where}: {o.standardized:.3g}", markup=False, highlight=False)
    if len(outliers) > MAX_OUTLIERS_SHOWN:
        console.print(f"  and {len(outliers) - MAX_OUTLIERS_SHOWN} more (all in result.yaml)")


def _verdict(result) -> str:
    """Why a converged result is not trusted, in a few words for the status line ("" when it is trusted)."""
    if result.status != "converged" or result.trusted:
        return ""
    if not result.physical:
        names = ", ".join(c.name for c in result.negative_compliances if c.significant)
        return f" (NOT TRUSTED: compliance below 0 beyond the noise: {names})"
    return (" (NOT TRUSTED: low redundancy and no validation data)" if not result.predictions
            else " (NOT TRUSTED at the validation configurations)")


def print_summary(console: Console, result, title: str) -> None:
    ana = result.identifiability
    verdict = _verdict(result)
    console.print(f"{title}: {result.status}{verdict} after {result.iterations} outer iterations "
                  f"({result.evaluations} evaluations); rank {ana.rank} of {len(ana.names)} free parameters; "
                  f"residual variance factor {_num(result.sigma2)}")
    t = Table(title="residuals per experiment (position mm, orientation deg)")
    for c in ("experiment", "kind", "samples", "pos RMS before", "pos RMS after", "rot RMS before", "rot RMS after"):
        t.add_column(c, justify="right" if c not in ("experiment", "kind") else "left")
    for b, a in zip(result.before, result.after):
        t.add_row(b.experiment, b.kind, str(b.samples), _num(b.position_rms, 1e3),
                  _num(a.position_rms, 1e3), _num(b.orientation_rms, DEG), _num(a.orientation_rms, DEG))
    console.print(t)
    if result.stages:  # a staged solve: each stage from the previous one's estimates (docs/calibration.md)
        t = Table(title="stages (position mm, orientation deg; the result is the last stage's)")
        for c in ("stage", "free", "fixed", "params", "rank", "chi2", "var factor", "pos RMS", "rot RMS", "status"):
            t.add_column(c)
        for r in stage_rows(result):
            t.add_row(r["name"], r["free"] if isinstance(r["free"], str) else ", ".join(r["free"]),
                      ", ".join(r["fixed"]), str(r["free_parameters"]), str(r["rank"]), _num(r["chi2"]),
                      _num(r["residual_variance_factor"]), _num(r["position_mm_rms"]), _num(r["orientation_deg_rms"]),
                      r["status"])
        console.print(t)
    _print_outliers(console, result.outliers)
    for w in data_warnings(result):
        console.print(f"warning: {w}", markup=False, highlight=False)
    if result.validation:
        t = Table(title="validation on held-out configurations (position mm, orientation deg)")
        for c in ("set", "samples", "pos RMS before", "pos RMS after", "pos max before", "pos max after",
                  "rot RMS before", "rot RMS after"):
            t.add_column(c, justify="left" if c == "set" else "right")
        for v in result.validation:
            t.add_row(v.experiment, str(v.samples), _num(v.before.position_rms, 1e3),
                      _num(v.after.position_rms, 1e3), _num(v.before.position_max, 1e3),
                      _num(v.after.position_max, 1e3), _num(v.before.orientation_rms, DEG),
                      _num(v.after.orientation_rms, DEG))
        console.print(t)
    _print_outliers(console, result.validation_outliers, "validation ")
    _print_predictions(console, prediction_rows(result))
    _print_cross_validation(console, cross_validation_dict(result.cross_validation))
    _print_estimates(console, result)
    for m in result.messages:
        console.print(f"- {m}")
    for a, b, r in result.correlated[:10]:
        console.print(f"- strongly correlated: {a} and {b} (rho = {r:+.3f})")


HELD_STD = 1e-9  # m or rad: a determined change whose std is below this is held at nominal by the gauge


def _print_estimates(console: Console, result) -> None:
    """The estimates, their change from nominal split into what the data determine (in the result's gauge, with
    its standard deviation) and a gauge move (changes no residual), then the derived quantities."""
    g = result.gauge
    gauge = g.name if g is not None else "none"
    t = Table(title=f"estimates (offsets and compliances absolute; twist/pose coordinates as change from nominal); "
                    f"change = determined + gauge move, determined in the gauge '{gauge}' (see below)")
    for c in ("parameter", "value", "std", "determined", "determined std", "gauge move", "unit"):
        t.add_column(c, justify="left" if c == "parameter" else "right")
    for e in result.estimates:
        unit, v, s = _shown(e)
        k = 1.0 if unit == e.unit else (DEG if e.unit == "rad" else 1e3)
        det, det_std, move = g.split(e.name) if g is not None else (math.nan,) * 3
        held = e.unit in ("m", "rad") and det_std < HELD_STD  # kept at nominal by the gauge: change is round-off
        t.add_row(e.name, _num(v, digits=6), _num(s, digits=3) if e.identifiable else "unidentifiable",
                  "0" if held else _num(det, k, 6), "held at nominal" if held else _num(det_std, k, 3),
                  _num(move, k, 4), unit)
    console.print(t)
    if g is not None:
        console.print(f"gauge: {g.description}")
    if not result.derived:
        return
    t = Table(title="derived quantities at the nominal zero (identifiable: the same value and std in every gauge)")
    for c in ("quantity", "value", "nominal", "change", "std", "identifiable", "unit"):
        t.add_column(c, justify="left" if c == "quantity" else "right")
    for d in result.derived:
        k, unit = (DEG, "deg") if d.unit == "rad" else (1e3, "mm") if d.unit == "m" else (1.0, d.unit)
        t.add_row(d.name, _num(d.value, k, 6), _num(d.nominal, k, 6), _num(d.value - d.nominal, k, 4),
                  _num(d.std, k, 3), "yes" if d.identifiable else "no (gauge)", unit)
    console.print(t)


def _print_predictions(console: Console, rows) -> None:
    """Predicted standard deviations next to the actual validation errors, and whether anything the data cannot
    determine moves the tool there: the model is to be trusted only where the two agree and nothing moves."""
    if not rows:
        return
    t = Table(title="predicted vs actual on held-out configurations (position mm, orientation deg; undetermined: "
                    "tool mm per mm-or-mrad along directions the data cannot or barely determine)")
    for c in ("set", "arm", "pos RMS actual", "pos RMS predicted", "pos std", "pos max actual", "pos std max",
              "rot RMS actual", "rot RMS predicted", "rot std", "undetermined", "trust"):
        t.add_column(c, justify="left" if c in ("set", "arm") else "right")
    for r in rows:
        undetermined = max(r["unidentifiable_position_mm_per_unit_max"] or 0.0, r["weak_position_mm_per_unit_max"] or 0.0)
        t.add_row(r["set"], r["arm"], _num(r.get("position_mm_rms_actual")), _num(r["position_mm_rms_predicted"]),
                  _num(r["position_mm_std_rms"]), _num(r.get("position_mm_max_actual")),
                  _num(r["position_mm_std_max"]), _num(r.get("orientation_deg_rms_actual")),
                  _num(r["orientation_deg_rms_predicted"]), _num(r["orientation_deg_std_rms"]),
                  _num(undetermined, digits=3), "yes" if r["trusted"] else "NO")
    console.print(t)
    for r in rows:
        for m in r["messages"]:
            console.print(f"- {r['set']} ({r['arm']}): {m}")


def _print_cross_validation(console: Console, cv) -> None:
    """Held-out RMS per fold and overall against the RMS predicted from each fold's training fit."""
    if cv is None:
        return
    t = Table(title=f"{cv['folds']}-fold cross-validation by configuration (held-out, frames from the training "
                    "folds; position mm, orientation deg; outlying held-out rows left out, with them in brackets)")
    for c in ("fold", "status", "var factor", "pos RMS actual", "pos RMS predicted", "rot RMS actual",
              "rot RMS predicted"):
        t.add_column(c, justify="left" if c in ("fold", "status") else "right")
    rows = [(str(f["fold"] + 1), f["status"], _num(f["residual_variance_factor"]), f) for f in cv["per_fold"]]
    for label, status, vf, f in rows + [("all", "", "", cv["overall"])]:
        cells = []
        for q, unit in (("position", "mm"), ("orientation", "deg")):
            actual, with_out = f.get(f"{q}_{unit}_rms_actual"), f.get(f"{q}_{unit}_rms_actual_with_outliers")
            shown = _num(actual) + (f" ({_num(with_out)})" if f.get(f"{q}_outlying_rows") else "")
            cells += [shown if actual is not None else "-", _num(f.get(f"{q}_{unit}_rms_predicted"))]
        t.add_row(label, status, vf, *cells)
    console.print(t)
    console.print(f"- cross-validated model error carried into the predictions: "
                  f"{_num(cv['model_error_position_mm'])} mm, {_num(cv['model_error_orientation_deg'])} deg")


def _progress(console: Console, quiet: bool):
    if quiet:
        return None
    return lambda it, cost: console.print(f"  outer iteration {it}: whitened cost {cost:.6g}", style="dim")


@click.command("calibrate")
@click.argument("job", type=click.Path(path_type=Path))
@click.option("-o", "--output", "out", required=True, type=click.Path(path_type=Path),
              help="Directory for model.yaml and result.yaml (existing files are never replaced).")
@click.option("--quiet", is_flag=True, help="Print nothing but errors.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON on stdout.")
@click.option("--plots", is_flag=True, help='Also write PNG plots to OUT/plots (needs "kincal[plot]").')
@click.option("--cv", type=click.IntRange(2, 1000), default=None, metavar="K",
              help="K-fold cross-validation by configuration (overrides the job's solver.cv); its model error "
                   "goes into the predictions (docs/calibration.md).")
@click.option("--confine", is_flag=True, help="Refuse file references outside the job's folder (docs/formats.md).")
@click.option("--overwrite", is_flag=True, help="Replace a previous result in OUT (only once the new one is whole).")
def calibrate_cmd(job: Path, out: Path, quiet: bool, as_json: bool, plots: bool, cv: int | None,
                  confine: bool, overwrite: bool) -> None:
    """Calibrate as described by JOB.yaml (docs/job-format.md) and write the results to OUT.

    Exit codes: 0 converged, 1 not converged, 2 bad input, 3 degenerate, 4 misfit, 5 converged but not
    trusted (at the validation configurations, or a compliance below 0 beyond the noise; docs/calibration.md)."""
    console = _console()
    if not overwrite:
        _refuse_existing(out, ("model.yaml", "result.yaml") + (("plots",) if plots else ()))
    if plots:
        require_plots()
    j = load_job(job, confine=confine)
    if cv is not None:
        if j.method == "thesis":
            raise DataFormatError(f"{job}: --cv needs kincal's solver (solver.method 'kincal'), not 'thesis'")
        j = replace(j, options={**j.options, "cv": cv})
    if not (quiet or as_json):
        console.print(f"calibrating '{j.name}': {len(j.datasets)} data set(s), "
                      f"{f'{len(j.stages)} stages' if j.stages else f'free: {j.free}'}, method: {j.method}")
    result = run_job(j, _progress(console, quiet or as_json))
    if j.method == "thesis":
        _write_thesis(result, j, out, console, quiet or as_json, as_json, overwrite)
        _exit("converged" if result.converged else "not converged")
        return
    paths = write_calibration(result, out, plots=plots, provenance=provenance(j),
                              overwrite=overwrite)  # all or nothing (docs/formats.md "Outputs")
    figures = paths["plots"]
    if as_json:
        click.echo(json.dumps(result_to_dict(result)))
    elif not quiet:
        print_summary(console, result, j.name)
        console.print(f"wrote {paths['model']} and {paths['result']}"
                      + (f", plots: {', '.join(str(f) for f in figures)}" if figures else ""))
    _exit(result.status, result.trusted)


# ``kincal calibrate`` and ``kincal demo`` exit with the status' code (docs/calibration.md "Statuses and exit
# codes"); 2 is kincal's one-line input error (``kincal.cli.main``), 130 an abort.
EXIT_CODES = {"converged": 0, "not converged": 1, "degenerate": 3, "misfit": 4}
# A converged result that is not trusted (``Result.trusted``): it fits, but directions its data cannot determine
# move the tool where it was validated, or a compliance came out below 0 beyond the noise (``Result.physical``).
UNTRUSTED_EXIT = 5


def _exit(status: str, trusted: bool = True) -> None:
    code = EXIT_CODES[status] or (0 if trusted else UNTRUSTED_EXIT)
    if code:
        raise SystemExit(code)


def _write_thesis(res, job, out: Path, console, quiet, as_json, overwrite: bool = False) -> None:
    """Write and print a thesis baseline's result, validated on the job's held-out sets like kincal's."""
    robot = res.calibrated(job.robot)
    if job.validation:
        res = replace(res, validation=validation_stats(job.robot, robot, job.validation))
    write_calibration(res, out, robot=robot, provenance=provenance(job), overwrite=overwrite)
    report = result_to_dict(res)
    if as_json:
        click.echo(json.dumps(report))
        return
    if quiet:
        return
    console.print(f"thesis baseline {res.method}: {'converged' if res.converged else 'stopped on the iteration budget'}"
                  f" after {res.iterations_label} iterations (thesis notation: run(accepted)); Eval_error "
                  f"{res.history[0][0] * 1e3:.4g} mm / {res.history[0][1] * DEG:.4g} deg -> "
                  f"{res.history[-1][0] * 1e3:.4g} mm / {res.history[-1][1] * DEG:.4g} deg")
    console.print("no identifiability analysis or standard deviations: the thesis' method has none")
    if res.validation:
        t = Table(title="validation on held-out configurations (position mm, orientation deg)")
        for c in ("set", "samples", "pos RMS before", "pos RMS after", "rot RMS before", "rot RMS after"):
            t.add_column(c, justify="left" if c == "set" else "right")
        for v in res.validation:
            t.add_row(v.experiment, str(v.samples), _num(v.before.position_rms, 1e3),
                      _num(v.after.position_rms, 1e3), _num(v.before.orientation_rms, DEG),
                      _num(v.after.orientation_rms, DEG))
        console.print(t)
    t = Table(title="estimates (deg for offsets and angles, mm for lengths)")
    for c in ("parameter", "value"):
        t.add_column(c, justify="left" if c == "parameter" else "right")
    for n, v in zip(res.parameter_names, res.estimate):
        scale = 1e3 if n.split(".")[-1].startswith("v_") else DEG
        t.add_row(n, _num(float(v), scale, 6))
    console.print(t)
    console.print(f"wrote {out / 'model.yaml'} and {out / 'result.yaml'}")


def _refuse_existing(out: Path, names) -> None:
    existing = [str(out / n) for n in names if (out / n).exists()]
    if existing:
        raise DataFormatError(f"{', '.join(existing)}: file exists; not overwritten (choose another output directory)")


@click.command("demo")
@click.option("-o", "--output", "out", default=None, type=click.Path(path_type=Path),
              help="Output directory (must not hold results). Default: the first free of ./kincal-demo-out, "
                   "./kincal-demo-out-2, ...")
@click.option("-n", "--samples", default=200, show_default=True, type=click.IntRange(20, 5000),
              help="Clamped configurations to simulate.")
@click.option("--quiet", is_flag=True, help="Print nothing but errors.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON on stdout.")
def demo_cmd(out: Path | None, samples: int, quiet: bool, as_json: bool) -> None:
    """Frida's arms clamped tool to tool (thesis Fig. 3.5): simulate, calibrate joint offsets, validate, write.

    Writes the simulated data (data.yaml, truth/, validation/), a job file (job.yaml) that re-runs the
    calibration with ``kincal calibrate``, and the results (model.yaml, result.yaml).
    """
    console = _console()
    say = (lambda msg: None) if (quiet or as_json) else (lambda msg: console.print(msg))
    out = _free_directory(Path("kincal-demo-out")) if out is None else out
    _refuse_existing(out, DEMO_ENTRIES + ("model.yaml", "result.yaml"))
    t0 = time.perf_counter()
    scenario = build_scenario(load_scenario(DEMO_SCENARIO))
    # thesis Table 4.5: nominal geometry, joint offsets of thesis size (up to 0.07 rad)
    scenario = replace(scenario, options={**scenario.options, "n": samples},
                       perturbation=perturbation("thesis", twist_m=0.0, twist_rad=0.0, home_m=0.0, home_rad=0.0))
    say(f"simulating {samples} configurations of Frida's clamped arms (true robot: joint offsets up to 4 deg) ...")
    true, ds, truth, validation = run(scenario)
    written = write_demo_input(out, ds, truth, validation, scenario.robot, model=scenario.model,
                               job_name="frida-dual-offsets", free="offsets")
    try:  # an interrupted or failed calibration takes the simulation with it: all or nothing
        say(f"calibrating joint offsets of both arms (job {out / 'job.yaml'}) ...")
        j = load_job(out / "job.yaml")
        result = run_job(j, _progress(console, quiet or as_json))
        paths = write_calibration(result, out, provenance=provenance(j))
    except BaseException:
        written.undo()
        raise
    if as_json:
        click.echo(json.dumps(result_to_dict(result)))
    else:
        if not quiet:
            print_summary(console, result, "demo")
            console.print(_recovery_table(result, true))
        say(f"wrote {paths['model']}, {paths['result']} and the simulated data in {out} "
            f"({time.perf_counter() - t0:.1f} s)")
    _exit(result.status, result.trusted)


def _free_directory(base: Path) -> Path:
    k = 1
    while (candidate := base if k == 1 else base.with_name(f"{base.name}-{k}")).exists():
        k += 1
    return candidate


def _recovery_table(result, true_robot) -> Table:
    """The demo knows the truth: estimated vs true joint offsets, and the error in reported standard deviations."""
    t = Table(title="recovery of the simulated truth (joint offsets, deg)")
    for c in ("parameter", "estimate", "true", "error", "error / std"):
        t.add_column(c, justify="left" if c == "parameter" else "right")
    for e in result.estimates:
        arm, joint, kind = e.name.split(".")
        if kind != "offset":
            continue
        truth = float(true_robot[arm].offsets[true_robot[arm].joint_names.index(joint)])
        err = e.value - truth
        t.add_row(e.name, _num(e.value, DEG, 6), _num(truth, DEG, 6), _num(err, DEG, 3),
                  _num(err / e.std if e.identifiable and e.std > 0 else float("nan"), digits=3))
    return t


def register(group: click.Group) -> None:
    group.add_command(calibrate_cmd)
    group.add_command(demo_cmd)
