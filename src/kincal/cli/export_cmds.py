"""``kincal import URDF -o MODEL.yaml`` and ``kincal export MODEL.yaml --to FORMAT -o OUT``."""

from __future__ import annotations

from pathlib import Path

import click

from kincal.cli.calibrate_cmds import _console
from kincal.errors import DataFormatError
from kincal.io.export import FORMATS, export_text, import_urdf, write_text
from kincal.io.ur_ros import ur_ros_text
from kincal.io.models import dump_robot, load_robot, select_arm


@click.command("import")
@click.argument("urdf", type=click.Path(path_type=Path))
@click.option("--base-link", required=True, help="First link of the chain (the arm's base).")
@click.option("--tip-link", required=True, help="Last link of the chain (the flange).")
@click.option("--arm", default="arm", show_default=True, help="Name of the arm in the model.")
@click.option("--name", default=None, help="Robot name (default: the file's stem).")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True)
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
def import_cmd(urdf: Path, base_link: str, tip_link: str, arm: str, name, output: Path, overwrite: bool) -> None:
    """Read the chain BASE_LINK -> TIP_LINK of URDF into a kincal model file; the URDF is recorded so that
    `kincal export --to urdf` can write a calibration back into it."""
    robot = import_urdf(urdf, base_link, tip_link, arm=arm, name=name)
    write_text(output, dump_robot(robot), overwrite)
    _console().print(f"wrote {output}: arm '{arm}' with {robot[arm].dof} joints ({', '.join(robot[arm].joint_names)})")


@click.command("export")
@click.argument("model", type=click.Path(path_type=Path))
@click.option("--to", "fmt", type=click.Choice(FORMATS), required=True,
              help="urdf (patched into the imported URDF, or new), dh / mdh (table), controller (offsets per "
                   "channel in motor units), json, ur-ros (the Universal Robots ROS driver's kinematics file).")
@click.option("--ur-hash", default=None, help="ur-ros: the robot's calibration checksum (the hash line "
              "ur_calibration writes for it), which the driver checks at start-up.")
@click.option("--arm", default=None, help="Arm to export (default: the only one).")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True)
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
def export_cmd(model: Path, fmt: str, ur_hash, arm, output: Path, overwrite: bool) -> None:
    """Write MODEL (a model file or built-in name, e.g. a calibration's model.yaml) in another format."""
    robot = load_robot(model)
    if arm is None and fmt != "json":
        select_arm(robot)  # one arm, or an error naming them
    name = arm or next(iter(robot.arms))
    if name not in robot.arms:
        raise DataFormatError(f"--arm {name!r}: the model's arms are {', '.join(robot.arms)}")
    notes = []
    if fmt == "ur-ros":
        text, notes = ur_ros_text(robot[name], str(model), ur_hash)
    else:
        text = export_text(robot, name, fmt, Path(model) if Path(model).is_file() else None)
    write_text(output, text, overwrite)
    console = _console()
    console.print(f"wrote {output} ({fmt}, arm '{name}')")
    for note in notes:
        console.print(f"note: {note}", highlight=False)


def register(group: click.Group) -> None:
    group.add_command(import_cmd)
    group.add_command(export_cmd)
