"""``kincal markers-to-pose``: a ``markers`` data set -> the ``pose`` data set fitted to it, with its covariance."""

from __future__ import annotations

from pathlib import Path

import click

from kincal.experiments.pose import WEIGHTS, weighted
from kincal.experiments.pose_from_markers import markers_to_pose
from kincal.io import units
from kincal.io.atomic import output_directory
from kincal.io.datasets import load_dataset, write_dataset
from kincal.io.models import load_robot

ENTRIES = ("pose.yaml", "pose.csv")


def register(group: click.Group) -> None:
    group.add_command(markers_to_pose_cmd)


@click.command("markers-to-pose")
@click.argument("manifest", type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path),
              help="Directory for pose.yaml and pose.csv.")
@click.option("--sigma-mm", type=float, default=None,
              help="Marker noise (mm; default: the data set's stated position noise).")
@click.option("--weights", type=click.Choice(WEIGHTS), default="full", show_default=True,
              help="full: the fit's covariance (cov.* columns); diagonal: its diagonal; equal: none, "
                   "noise 1 m = 1 rad (the paper's unweighted approach 1).")
@click.option("--length", default="m", show_default=True, help="Length unit of the output (m or mm).")
@click.option("--angle", default="rad", show_default=True, help="Angle unit of the output (rad or deg).")
@click.option("--overwrite", is_flag=True, help="Replace pose.yaml and pose.csv in the output directory.")
def markers_to_pose_cmd(manifest: Path, output: Path, sigma_mm: float | None, weights: str, length: str, angle: str,
                        overwrite: bool) -> None:
    """Fit the known marker layout to every row of the markers data set MANIFEST: a pose data set with each
    pose's 6x6 covariance (docs/calibration.md "Pose data with a full covariance")."""
    sigma = None if sigma_mm is None else sigma_mm * units.LENGTH["mm"]
    for q, u in (("length", length), ("angle", angle)):
        units.factor(q, u, f"--{q}")
    ds = load_dataset(manifest)
    pose = markers_to_pose(ds, sigma=sigma)
    if weights != "full":
        pose = weighted(pose, weights, sigma)
    robot = load_robot(ds.robot)
    with output_directory(output, names=ENTRIES, overwrite=overwrite, last="pose.yaml", inside_ok=False) as stage:
        path = write_dataset(pose, stage.path / "pose.yaml", robot, angle=angle, length=length)
    click.echo(f"{manifest} -> {stage.final(path)}: {pose.size} poses, weights {weights}")
