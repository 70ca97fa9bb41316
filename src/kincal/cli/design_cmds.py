"""``kincal design``: choose the configurations to measure (a scenario's experiment), or the next ones to add
to an existing calibration (``--next K JOB.yaml``)."""

from __future__ import annotations

import math
from datetime import datetime, timezone
from pathlib import Path

import click
import numpy as np

from kincal import __version__
from kincal.analysis.design import CRITERIA
from kincal.cli.calibrate_cmds import _console
from kincal.errors import DataFormatError
from kincal.io.datasets import load_scenario, scenario_path
from kincal.io.planjobs import is_planned, planned_source, scenario_file
from kincal.io.models import load_robot
from kincal.io.targets import write_targets
from kincal.io.yamlfile import read_yaml
from kincal.simulate.scenario import build_scenario
from kincal.workflow.augment import next_configurations
from kincal.workflow import run_job
from kincal.workflow.design import Candidates, choose, design
from kincal.workflow.plan import load_plan_job


def _floats(text: str | None, n: int, option: str) -> np.ndarray | None:
    if text is None:
        return None
    try:
        v = np.array([float(x) for x in text.split(",")])
    except ValueError:
        v = np.zeros(0)
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise DataFormatError(f"{option} {text!r}: expected {n} comma-separated numbers")
    return v


def _limits(box: str | None, cone: float | None) -> Candidates:
    b = _floats(box, 6, "--box")
    if b is not None and not np.all(b[:3] < b[3:]):
        raise DataFormatError(f"--box {box!r}: expected xmin,ymin,zmin,xmax,ymax,zmax (m) with each min below its max")
    if cone is not None and not 0 < cone <= 180:
        raise DataFormatError(f"--cone {cone}: expected a half-angle in degrees in (0, 180]")
    return Candidates(None if b is None else (b[:3], b[3:]), None if cone is None else math.radians(cone))


@click.command("design")
@click.argument("source")
@click.option("-n", "count", type=click.IntRange(1, None), default=None, help="Configurations to choose.")
@click.option("--next", "next_count", type=click.IntRange(1, None), default=None,
              help="Choose this many configurations to add to the calibration of SOURCE (a job file).")
@click.option("--result", type=click.Path(path_type=Path), default=None,
              help="With --next: a calibrate output folder of the job (its model.yaml); default: calibrate the job.")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True, help="Output folder (new).")
@click.option("--free", default=None, help="What the calibration will free (default: the job's, or 'offsets').")
@click.option("--criterion", type=click.Choice(CRITERIA), default="D", show_default=True,
              help="D, A, E, O1-O5, or I / G: mean / max predicted tool error over the workspace.")
@click.option("--pool", type=click.IntRange(1, None), default=2000, show_default=True, help="Candidates to draw (a job whose data set gives the configurations: ignored).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--box", default=None, help="Tracker experiments: tool position box xmin,ymin,zmin,xmax,ymax,zmax (m).")
@click.option("--cone", type=float, default=None, help="Tracker experiments: line-of-sight half-angle (deg).")
@click.option("--overwrite", is_flag=True, help="Replace a previous design in the output folder.")
def design_cmd(source, count, next_count, result, output, free, criterion, pool, seed, box, cone, overwrite) -> None:
    """Choose configurations to measure for the experiment of SOURCE (a scenario file or built-in name, or a job
    with one data set: a scenario it names, or its configurations as the candidates), or with --next the ones
    that most improve the calibration of a job. Writes joint targets in model order and in
    controller order (motor units) and design.yaml."""
    if (count is None) == (next_count is None):
        raise DataFormatError("give either -n K (a new experiment: a scenario, or a job with one data set) or --next K "
                              "(a job to extend)")
    console = _console()
    if next_count is not None:
        robot, q, summary = _next(source, next_count, result, free, pool, seed, console)
    else:
        robot, q, summary = _design(source, count, free, criterion, pool, seed, _limits(box, cone), console)
    paths = write_targets(output, robot, q, summary, overwrite=overwrite)
    console.print(f"wrote {', '.join(str(p) for p in paths.values())}")


def _design(source, K, free, criterion, pool, seed, limits, console):
    robot, kind, options, given, job_free, noise = _experiment_source(source)
    free = free or job_free
    if given is None:
        d = design(robot, kind, options, K, free=free, pool=pool, criterion=criterion, noise=noise, seed=seed,
                   limits=limits)
    else:
        if limits != Candidates():
            raise DataFormatError("--box and --cone filter the candidates kincal draws; this job's data set gives "
                                  "the candidates (name a scenario in the job to draw them)")
        console.print(f"choosing from the {given.size} configurations of data set '{given.name}'")
        d = choose(robot, given, K, free=free, criterion=criterion, noise=noise, seed=seed)
        if d.outside:
            console.print(f"left out {d.outside} configurations outside the joint limits")
    console.print(f"chose {K} of {d.pool} candidates by {criterion}: criterion {d.selection.value:.6g} against "
                  f"{d.random:.6g} for the median of 20 random designs; rank {d.rank} of {d.free}")
    console.print(f"predicted tool position std over the workspace: {d.tool_rms * 1e3:.4g} mm RMS "
                  f"(max {d.tool_max * 1e3:.4g}); random designs of {K}: {d.random_tool_rms * 1e3:.4g} mm RMS")
    if robot.mounts:
        console.print(f"tree: {', '.join(f'{a} on {c}' for a, c in robot.mounts.items())}; the targets set every "
                      "joint of the composite chains, the carriers' once", highlight=False)
    if d.unidentifiable:
        console.print(f"not identifiable from this experiment: {', '.join(d.unidentifiable)}", highlight=False)
    summary = _common(source, criterion, free, pool if given is None else d.pool, seed) | {
        "experiment": kind, "configurations": K, "candidates": d.pool, "rank": d.rank, "free_parameters": d.free,
        "criterion_value": d.selection.value, "criterion_random_median": d.random,
        "exchanges": d.selection.exchanges, "tool_position_std_rms_m": d.tool_rms,
        "tool_position_std_max_m": d.tool_max, "tool_position_std_rms_random_m": d.random_tool_rms,
        "not_identifiable": list(d.unidentifiable)} | ({"mounts": dict(robot.mounts)} if robot.mounts else {})
    return robot, dict(d.dataset.q), summary


def _experiment_source(source):
    """(robot, kind, generator options, candidates given or None, free, noise) of a scenario, or of a job with
    one data set: a job entry naming a scenario draws candidates like the scenario; any other data set (measured,
    or a configurations file) is itself the pool."""
    path = scenario_path(source)
    top = read_yaml(path, "job or scenario file")
    if isinstance(top, dict) and top.get("format") == "kincal-scenario":
        sc = build_scenario(load_scenario(path))
        return sc.robot, sc.kind, sc.options, None, "offsets", sc.noise
    job = load_plan_job(path)
    if len(job.datasets) != 1:
        raise DataFormatError(f"{path}: design -n chooses configurations for one experiment; the job has "
                              f"{len(job.datasets)} data sets (keep one, or use --next to extend them)")
    (ds,) = job.datasets
    entry = top["data"][0]
    if is_planned(entry) and planned_source(entry) == "scenario":
        sc = build_scenario(load_scenario(scenario_file(f"{path}: data[0]", path, entry["scenario"])))
        return job.robot, sc.kind, sc.options, None, job.free, job.noise[ds.name]
    return job.robot, ds.kind, {}, ds, job.free, job.noise[ds.name]


def _next(source, K, result, free, pool, seed, console):
    top = read_yaml(Path(source), "job file")
    if not isinstance(top, dict) or top.get("format") != "kincal-job":
        raise DataFormatError(f"{source}: --next needs a job file (format: kincal-job)")
    job = load_plan_job(source)
    if result is None:  # the information counts at the calibrated model: calibrate first
        console.print("calibrating the job first (give --result DIR to use an existing calibration)")
        robot = run_job(job).robot
    else:
        robot = load_robot(result / "model.yaml")
    free = free or job.free
    a = next_configurations(robot, list(job.datasets), K, free=free, noise=job.noise, pool=pool, seed=seed)
    console.print(f"chose {K} configurations of '{a.base}': rank {a.rank_before} -> {a.rank_after}")
    for name in a.gained:
        console.print(f"  now identifiable: {name}")
    for name, words in a.structural:
        console.print(f"  cannot become identifiable with more '{a.base}' data: {words}")
    summary = _common(source, "D", free, pool, seed) | {
        "extends": a.base, "configurations": K, "rank_before": a.rank_before, "rank_after": a.rank_after,
        "now_identifiable": list(a.gained), "reachable_with_the_pool": list(a.reachable),
        "structurally_unidentifiable": [{"parameter": n, "why": w} for n, w in a.structural]}
    return robot, dict(a.dataset.q), summary


def _common(source, criterion, free, pool, seed) -> dict:
    return {"format": "kincal-design", "version": 1, "kincal": __version__,
            "date": datetime.now(timezone.utc).isoformat(timespec="seconds"), "source": str(source),
            "criterion": criterion, "free": free if isinstance(free, str) else list(free), "pool": pool,
            "seed": seed, "units": {"targets.csv": "rad (m for prismatic joints)",
                                    "controller.csv": "motor rad (q x gear ratio), controller channel order"}}


def register(group: click.Group) -> None:
    group.add_command(design_cmd)
