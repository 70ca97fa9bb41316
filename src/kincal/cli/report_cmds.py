"""``kincal report RESULT_DIR`` (one self-contained HTML file) and ``kincal plot RESULT_DIR`` (PNG plots) for a
calibration already written: the result is recomputed from the job and inputs its result.yaml records."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from kincal.cli.calibrate_cmds import _console
from kincal.io.atomic import output_directory, output_file
from kincal.report import write_plots
from kincal.report.html import report_html
from kincal.simulate import workspace_sample
from kincal.workflow.outputs import require_plots
from kincal.workflow.recompute import recompute

WORKSPACE = 300


@click.command("report")
@click.argument("result_dir", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=None,
              help="HTML file to write (default: RESULT_DIR/report.html).")
@click.option("--workspace", type=click.IntRange(10, 100_000), default=WORKSPACE, show_default=True,
              help="Random configurations of each arm for the predicted accuracy map.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--overwrite", is_flag=True, help="Replace an existing report.")
def report_cmd(result_dir: Path, output, workspace: int, seed: int, overwrite: bool) -> None:
    """Write one self-contained HTML report of the calibration in RESULT_DIR: verdict, what cannot be
    identified and what to measure next, estimates, residuals, validation, spectrum, accuracy map, provenance."""
    require_plots("the report's plots", "")
    out = output or result_dir / "report.html"
    result, prov = recompute(result_dir)
    rng = np.random.default_rng(seed)
    sample = {a: workspace_sample(result.robot, a, workspace, rng) for a in result.state.arms}
    text = report_html(result, title=f"kincal calibration: {Path(prov['job']).name}", workspace=sample,
                       provenance=prov)
    with output_file(out, overwrite=overwrite) as tmp:
        tmp.write_text(text, encoding="utf-8")
    _console().print(f"wrote {out}")


@click.command("plot")
@click.argument("result_dir", type=click.Path(path_type=Path))
@click.option("--overwrite", is_flag=True, help="Replace existing plots.")
def plot_cmd(result_dir: Path, overwrite: bool) -> None:
    """Write the PNG plots of the calibration in RESULT_DIR into RESULT_DIR/plots."""
    require_plots("plots", "")
    result, _ = recompute(result_dir)
    with output_directory(result_dir / "plots", overwrite=overwrite) as stage:
        files = write_plots(result, stage.path)
    _console().print(f"wrote {len(files)} plots into {result_dir / 'plots'}")


def register(group: click.Group) -> None:
    group.add_command(report_cmd)
    group.add_command(plot_cmd)
