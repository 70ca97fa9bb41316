"""``kincal simulate`` (scenario -> data set, truth, validation) and ``kincal convert-log`` (motor log -> joints)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import click
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from kincal.cli.console import CountColumn, make_console
from kincal.errors import DataFormatError
from kincal.io.datasets import load_scenario
from kincal.io.logs import EXTCTRL_PERIOD_S, convert_log as convert, write_joint_csv
from kincal.io.models import load_robot
from kincal.kinematics.model import PRISMATIC
from kincal.simulate import joint_spread
from kincal.simulate.generators import dataset_spread
from kincal.simulate.scenario import build_scenario, run
from kincal.workflow.outputs import SIMULATION_ENTRIES, write_simulation_output


def register(group: click.Group) -> None:
    group.add_command(simulate)
    group.add_command(convert_log)


@click.command()
@click.argument("scenario")
@click.option("-o", "--output", "output", required=True, type=click.Path(path_type=Path),
              help="Directory for data.yaml/data.csv, truth/ and validation/.")
@click.option("--seed", type=int, default=None, help="Override the scenario's seed.")
@click.option("--overwrite", is_flag=True, help="Replace files already in the output directory.")
@click.option("--quiet", is_flag=True, help="No progress bar or summary.")
def simulate(scenario: str, output: Path, seed: int | None, overwrite: bool, quiet: bool) -> None:
    """Simulate the experiment of SCENARIO.yaml (examples: kincal/scenarios/*.yaml)."""
    sc = build_scenario(load_scenario(scenario))
    if output.exists() and not output.is_dir():  # said before simulating, not after
        raise DataFormatError(f"{output}: exists and is not a directory; expected an output directory")
    existing = [str(output / n) for n in SIMULATION_ENTRIES if (output / n).exists()]
    if existing and not overwrite:
        raise DataFormatError(f"{', '.join(existing)}: exists; refusing to overwrite it (pass --overwrite)")
    if seed is not None:
        sc = replace(sc, seed=seed)
    console = Console(stderr=True, quiet=quiet)
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), CountColumn(),
                  TimeElapsedColumn(), console=console, transient=True, disable=quiet) as bar:
        task = bar.add_task(f"{sc.name}: configurations", total=sc.options.get("n"))

        def progress(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        true, ds, truth, validation = run(sc, progress)
    paths = write_simulation_output(output, ds, truth, validation, sc.robot, model=sc.model, angle=sc.angle_unit,
                                    length=sc.length_unit, overwrite=overwrite)  # all or nothing
    if quiet:
        return
    out = make_console()
    out.print(f"[bold]{sc.name}[/]: {ds.kind}, {ds.size} samples, arms {', '.join(ds.arms)}")
    for key, p in paths.items():
        out.print(f"  {key}: {p}")
    stats = {k: v for k, v in truth.meta.items() if k != "generator" and v is not None}  # None: not counted
    if stats:
        out.print("  generator: " + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in stats.items()))
    # how much of each joint's range the data cover, whatever the kind: identifiability rests on it
    for arm, sp in _spreads(ds, sc.robot, truth).items():
        out.print(_spread_table(arm, sp, sc.robot[arm].joint_types))
        if sp.n_branches is not None:
            out.print(f"  self-motion branches visited: {sp.n_branches}")
        if sp.weak:
            out.print(f"  [yellow]hardly excited: {', '.join(sp.weak)}[/]")


def _spreads(ds, robot, truth) -> dict:
    """``dataset_spread`` of the data set's arms, preceded by their carriers' (a torso's joints, shared by the
    arms on it: their spread is what identifies them)."""
    spreads = dataset_spread(ds, robot, truth)
    carriers = dict.fromkeys(c for a in ds.arms for c in robot.lineage(a)[:-1] if c not in spreads and c in ds.q)
    return {**{c: joint_spread(ds.q[c], robot[c].joint_names, robot[c].lower, robot[c].upper) for c in carriers},
            **spreads}


def _spread_table(arm: str, sp, kinds) -> Table:
    """Joint spread in deg (mm for prismatic joints)."""
    unit = "deg, mm for prismatic joints" if PRISMATIC in kinds else "deg"
    t = Table(title=f"joint spread, arm {arm} ({unit})")
    for col in ("joint", "min", "max", "range", "of limits"):
        t.add_column(col, justify="left" if col == "joint" else "right")
    for i, name in enumerate(sp.names):
        k = 1e3 if kinds[i] == PRISMATIC else 180 / math.pi
        frac = "" if sp.fraction[i] != sp.fraction[i] else f"{100 * sp.fraction[i]:.0f}%"
        t.add_row(name + (" (weak)" if name in sp.weak else ""), f"{sp.low[i] * k:.2f}", f"{sp.high[i] * k:.2f}",
                  f"{sp.range[i] * k:.2f}", frac)
    return t


@click.command("convert-log")
@click.argument("log", type=click.Path(path_type=Path))
@click.option("-m", "--model", required=True, help="Built-in robot name or model file.")
@click.option("-a", "--arm", "arms", multiple=True, help="Arm(s) in the log, in column order (default: all).")
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path),
              help="CSV of joint readings (rad, model order).")
@click.option("--every", type=int, default=1, show_default=True, help="Keep every k-th sample.")
@click.option("--still-rad-s", type=float, default=None,
              help="Keep only samples where every joint moves slower than this (rad/s).")
@click.option("--window", type=int, default=25, show_default=True, help="Samples in the standstill window.")
@click.option("--per-stop", is_flag=True, help="With --still-rad-s: one sample (the mean) per stop.")
@click.option("--no-header", is_flag=True, help="The log has no header: all columns are channels.")
@click.option("--period-s", type=float, default=None,
              help="Sample period without a t column (default ExtCtrl 0.004032 s).")
@click.option("--overwrite", is_flag=True, help="Replace OUTPUT if it exists.")
def convert_log(log: Path, model: str, arms: tuple[str, ...], output: Path, every: int, still_rad_s: float | None,
                window: int, per_stop: bool, no_header: bool, period_s: float | None, overwrite: bool) -> None:
    """Convert a controller LOG in motor radians (controller joint order) to arm radians in model order."""
    if output.resolve() == log.resolve():
        raise DataFormatError(f"{output}: is the input log; choose another output file")
    robot = load_robot(model)
    arms = tuple(arms) or tuple(robot.arms)
    for a in arms:
        robot[a]
    t, q = convert(log, robot, arms, every=every, still_rad_s=still_rad_s, window=window, per_stop=per_stop,
                   header=not no_header, period_s=EXTCTRL_PERIOD_S if period_s is None else period_s, model=model)
    write_joint_csv(output, t, q, robot, overwrite=overwrite)
    click.echo(f"{log} -> {output}: {len(t)} samples, arms {', '.join(arms)}")
