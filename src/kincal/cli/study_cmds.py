"""``kincal study`` (Monte Carlo studies of a calibration) and ``kincal batch`` (many jobs at once), both on the
Dask back end (``kincal.workflow.parallel``)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import click
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from kincal.cli.console import make_console
from kincal.io.studies import study_names
from kincal.workflow import batch as batch_flow
from kincal.workflow import study as study_flow
from kincal.workflow.outputs import require_plots

_WORKERS = click.option("--workers", type=click.IntRange(min=0), default=None,
                        help="Local Dask worker processes (default: one per core; 0: run in this process).")
_SCHEDULER = click.option("--scheduler", default=None, metavar="ADDRESS",
                          help="Use the existing Dask cluster at ADDRESS (tcp://host:8786) instead of a local one.")


def register(group: click.Group) -> None:
    group.add_command(study)
    group.add_command(batch)
    group.add_command(studies)


def _bar(console: Console, quiet: bool) -> Progress:
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                    TimeElapsedColumn(), console=console, transient=True, disable=quiet)


@click.command()
@click.argument("study_file", metavar="STUDY")
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path),
              help="Directory for study.csv, validation.csv and repeats.csv.")
@_WORKERS
@_SCHEDULER
@click.option("--repeats", type=click.IntRange(min=2), default=None, help="Override the study's repeats.")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Override the study's seed.")
@click.option("--plots", is_flag=True, help='Also write PNG plots to OUTPUT/plots (needs "kincal[plot]").')
@click.option("--overwrite", is_flag=True, help="Replace the tables already in the output directory.")
@click.option("--quiet", is_flag=True, help="No progress bar or table.")
def study(study_file: str, output: Path, workers, scheduler, repeats, seed, plots: bool, overwrite: bool,
          quiet: bool) -> None:
    """Monte Carlo study of STUDY.yaml (or a built-in study: kincal studies): per variant and parameter the bias,
    std, RMS, reported/empirical std and the validation error."""
    if plots:
        require_plots()
    s = study_flow.load(study_file)
    s = replace(s, repeats=repeats or s.repeats, seed=s.seed if seed is None else seed)
    console = Console(stderr=True, quiet=quiet)
    with _bar(console, quiet) as bar:
        task = bar.add_task(f"{s.name}: repeats", total=s.repeats)
        result = study_flow.run_study(s, workers=workers, scheduler=scheduler,
                                      progress=lambda done, total: bar.update(task, completed=done))
    paths = study_flow.write_study(result, output, overwrite=overwrite, plots=plots)
    if quiet:
        return
    out = make_console()
    shown = [{k: v for k, v in r.items() if k not in ("truth", "repeats")} for r in study_flow.table(result)]
    out.print(_table(f"{s.name}: {s.repeats} repeats, seed {s.seed}", shown))
    out.print(_table("validation RMS position error", [{k: v for k, v in r.items() if k != "first_failure"}
                                                        for r in study_flow.validation_table(result)]))
    for r in study_flow.validation_table(result):
        if r["first_failure"]:
            out.print(f"[yellow]{r['variant']}: {r['failed']} repeat(s) failed; first: {r['first_failure']}[/]")
    for p in paths:
        out.print(f"  {p}")


@click.command()
@click.argument("jobs", nargs=-1, required=True, metavar="JOB...")
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path),
              help="Directory for summary.csv and one folder per job.")
@_WORKERS
@_SCHEDULER
@click.option("--overwrite", is_flag=True, help="Replace what is already in the output directory.")
@click.option("--quiet", is_flag=True, help="No progress bar or table.")
def batch(jobs, output: Path, workers, scheduler, overwrite: bool, quiet: bool) -> None:
    """Calibrate many JOB files (a fleet) in parallel: each job's outputs in its own folder, one summary table.
    A failing job is a row of the table, not the end of the batch."""
    console = Console(stderr=True, quiet=quiet)
    with _bar(console, quiet) as bar:
        task = bar.add_task("jobs", total=len(jobs))
        rows = batch_flow.run_batch([Path(j) for j in jobs], output, workers=workers, scheduler=scheduler,
                                    overwrite=overwrite, progress=lambda done, total: bar.update(task, completed=done))
    if not quiet:
        shown = [{"job": Path(r["folder"]).name, **{k: v for k, v in r.items() if k not in ("job", "folder")}}
                 for r in rows]
        make_console().print(_table(f"{len(rows)} jobs -> {output}", shown))
    if any(r["status"] == batch_flow.FAILED for r in rows):
        raise SystemExit(1)


@click.command()
def studies() -> None:
    """List the built-in studies."""
    for name in study_names():
        click.echo(name)


def _table(title: str, rows: list[dict]) -> Table:
    t = Table(title=title)
    for key in (rows[0] if rows else {}):
        left = key in ("variant", "quantity", "job", "status", "message")
        t.add_column(key.replace("_", " "), no_wrap=key != "message", justify="left" if left else "right")
    for r in rows:
        t.add_row(*[f"{v:.3g}" if isinstance(v, float) else str(v) for v in r.values()])
    return t
