"""``kincal import URDF_OR_DH -o MODEL.yaml`` and ``kincal export MODEL.yaml --to FORMAT -o OUT``."""

from __future__ import annotations

from pathlib import Path

import click

from kincal.cli.calibrate_cmds import _console
from kincal.errors import DataFormatError
from kincal.io.dh_table import read_dh_table
from kincal.io.export import FORMATS, export_text, export_tree, import_urdf, write_text
from kincal.io.ur_ros import ur_ros_text
from kincal.io.models import dump_robot, load_robot, select_arm
from kincal.kinematics import Robot

DH_SUFFIXES = (".yaml", ".yml")


@click.command("import")
@click.argument("source", type=click.Path(path_type=Path))
@click.option("--base-link", default=None, help="URDF: first link of the chain (the arm's base).")
@click.option("--tip-link", default=None, help="URDF: last link of the chain (the flange).")
@click.option("--arm", default=None, help="Name of the arm in the model (default: the DH file's, or arm).")
@click.option("--name", default=None, help="Robot name (default: the file's stem).")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True)
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
def import_cmd(source: Path, base_link, tip_link, arm, name, output: Path, overwrite: bool) -> None:
    """Read SOURCE into a kincal model file: a URDF (the chain BASE_LINK -> TIP_LINK; the URDF is recorded so
    that `kincal export --to urdf` can write a calibration back into it) or a DH table file (.yaml, the format
    `kincal export --to dh|mdh` writes: docs/deploy.md)."""
    if source.suffix.lower() in DH_SUFFIXES:
        if base_link or tip_link:
            raise DataFormatError(f"{source}: a DH table has no links; --base-link and --tip-link are for URDFs")
        robot = read_dh_table(source, name)
        if arm is not None:
            robot = Robot(robot.name, {arm: robot[next(iter(robot.arms))].replace(name=arm)})
    else:
        if not base_link or not tip_link:
            raise DataFormatError(f"{source}: a URDF needs --base-link and --tip-link (the chain to import); "
                                  "DH tables are read from .yaml files")
        robot = import_urdf(source, base_link, tip_link, arm=arm or "arm", name=name)
    write_text(output, dump_robot(robot), overwrite)
    arm = next(iter(robot.arms))
    _console().print(f"wrote {output}: arm '{arm}' with {robot[arm].dof} joints ({', '.join(robot[arm].joint_names)})",
                     highlight=False)


@click.command("export")
@click.argument("model", type=click.Path(path_type=Path))
@click.option("--to", "fmt", type=click.Choice(FORMATS), required=True,
              help="urdf (patched into the imported URDF, or new), dh / mdh (table), controller (offsets per "
                   "channel in motor units), json, ur-ros (the Universal Robots ROS driver's kinematics file).")
@click.option("--ur-hash", default=None, help="ur-ros: the robot's calibration checksum (the hash line "
              "ur_calibration writes for it), which the driver checks at start-up.")
@click.option("--arm", default=None, help="Arm to export (default: the only one; a tree-structured robot: every "
              "arm in one file, urdf or controller; a mounted arm: its chain with its carriers).")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True)
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
def export_cmd(model: Path, fmt: str, ur_hash, arm, output: Path, overwrite: bool) -> None:
    """Write MODEL (a model file or built-in name, e.g. a calibration's model.yaml) in another format."""
    robot = load_robot(model)
    if arm is None and robot.mounts and fmt != "json":  # a tree: every arm in one file
        text, notes = export_tree(robot, fmt)
        write_text(output, text, overwrite)
        _console().print(f"wrote {output} ({fmt}, the tree: {_tree_words(robot)})", highlight=False)
        for note in notes:
            _console().print(f"note: {note}", highlight=False)
        return
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


def _tree_words(robot: Robot) -> str:
    return ", ".join(f"{a} on {robot.mounts[a]}" if a in robot.mounts else a for a in robot.arms)


def register(group: click.Group) -> None:
    group.add_command(import_cmd)
    group.add_command(export_cmd)
