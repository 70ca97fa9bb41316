"""``kincal compensate CALIBRATED PROGRAM.csv --nominal MODEL -o OUT.csv``: the joint values the calibrated robot
needs to reach what a program written for the nominal model intends (docs/deploy.md)."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from kincal.cli.calibrate_cmds import _console
from kincal.io.models import load_robot
from kincal.io.programs import read_program, write_program
from kincal.workflow.compensate import compensate_joints, compensate_poses

# Rows that could not be compensated printed at most; the output file marks them all.
SHOWN = 20
FAILED_EXIT = 1


@click.command("compensate")
@click.argument("calibrated")
@click.argument("program", type=click.Path(path_type=Path))
@click.option("--nominal", required=True, help="The model the program was written for (built-in name or file).")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True, help="Compensated program (CSV).")
@click.option("--angle", type=click.Choice(["rad", "deg"]), default="rad", show_default=True,
              help="Unit of the joint columns (motor columns are always motor rad).")
@click.option("--length", type=click.Choice(["m", "mm"]), default="m", show_default=True,
              help="Unit of pose positions and prismatic joints.")
@click.option("--wrench", "wrench", default=None, metavar="FX,FY,FZ,TX,TY,TZ",
              help="Tool load of every solved arm (N, N m; tool frame, applied to the tool), for rows without "
                   "<arm>.wrench.* columns.")
@click.option("--payload", type=float, default=None, metavar="KG",
              help="Payload mass on every solved arm (the model's gravity loads it), instead of the model's.")
@click.option("--payload-com", default="0,0,0", show_default=True, metavar="X,Y,Z",
              help="The payload's centre of mass in the tool frame (m).")
@click.option("--rigid", is_flag=True, help="Ignore the calibrated model's compliance (no sag under loads).")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
def compensate_cmd(calibrated, program: Path, nominal, output: Path, angle, length, wrench, payload, payload_com,
                   rigid, overwrite) -> None:
    """Compensate PROGRAM.csv (joint targets in model or controller order, or Cartesian tool poses with their
    nominal joint values) for the CALIBRATED model. On a tree-structured robot the carriers' readings (a torso's)
    are held as given and the arms on them solved. A compliant calibrated model is compensated deflected by its
    loads (tool wrenches, payload, the weights of its mass model) unless --rigid. Exit 1 when some rows could
    not be compensated (they are named here and marked in the output)."""
    cal, nom = load_robot(calibrated), load_robot(nominal)
    prog = read_program(program, nom, angle, length)
    solved = prog.poses if prog.form == "poses" else [a for a in prog.q if not _carries(nom, a, prog.q)]
    loads = {"wrench": _wrenches(prog, solved, wrench), "rigid": rigid,
             "payload": None if payload is None else {a: (payload, _floats(payload_com, 3, "--payload-com"))
                                                      for a in solved}}
    if prog.form == "poses":
        comp = compensate_poses(cal, prog.poses, prog.q, nominal=nom, **loads)
    else:
        comp = compensate_joints(nom, cal, prog.q, **loads)
    write_program(output, prog, cal, comp, overwrite=overwrite)
    console = _console()
    failed = comp.failed()
    rows = len(prog.lines)
    console.print(f"wrote {output}: {rows} rows, {rows * len(comp.q) - len(failed)} arm targets compensated, "
                  f"{len(failed)} not")
    for arm in comp.held:
        console.print(f"  arm '{arm}' carries {', '.join(a for a in comp.q if arm in cal.lineage(a))}: its readings "
                      "are held as the program gives them (the carried arms are solved through it)")
    for arm, i, status in failed[:SHOWN]:
        console.print(f"  {program}: line {prog.lines[i]}, arm '{arm}': {status} (remaining "
                      f"{comp.position_error[arm][i] * 1e3:.3g} mm)")
    if len(failed) > SHOWN:
        console.print(f"  and {len(failed) - SHOWN} more (marked in {output})")
    if failed:
        raise SystemExit(FAILED_EXIT)


def _carries(robot, arm: str, arms) -> bool:
    return any(arm in robot.lineage(b)[:-1] for b in arms)


def _floats(text: str, n: int, option: str) -> np.ndarray:
    try:
        values = np.array([float(x) for x in text.split(",")])
    except ValueError:
        values = np.array([])
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise click.BadParameter(f"expected {n} comma-separated numbers, found '{text}'", param_hint=option)
    return values


def _wrenches(prog, solved, wrench: str | None) -> dict:
    """Per solved arm its tool loads: its program columns, else ``--wrench``; arms with neither carry none."""
    constant = None if wrench is None else _floats(wrench, 6, "--wrench")
    out = {a: prog.wrench.get(a, constant) for a in solved}
    return {a: w for a, w in out.items() if w is not None}


def register(group: click.Group) -> None:
    group.add_command(compensate_cmd)
