"""``kincal analyze JOB.yaml | SCENARIO.yaml``: what an experiment identifies, how well, and what errors in held
parameters do, before (or without) calibrating."""

from __future__ import annotations

import json
import math
import re

import click
from rich.table import Table

from kincal.analysis.observability import MEANINGS
from kincal.cli.calibrate_cmds import DEG, _console, _num, _shown
from kincal.errors import DataFormatError
from kincal.io.datasets import load_scenario, scenario_path
from kincal.io.yamlfile import read_yaml
from kincal.workflow.analyze import WORKSPACE_SAMPLES, Analysis, analyze
from kincal.workflow.plan import load_plan_job, scenario_dataset

_ERROR = re.compile(r"^\s*([^=\s]+)\s*=\s*([-+0-9.eE]+)\s*(mm|m|deg|rad)\s*$")
_UNITS = {"mm": 1e-3, "m": 1.0, "deg": math.pi / 180, "rad": 1.0}
# Largest estimate changes listed per held parameter.
SHOWN_SHIFTS = 3


def _errors(values: tuple[str, ...]) -> dict[str, float]:
    out = {}
    for v in values:
        m = _ERROR.match(v)
        if not m:
            raise DataFormatError(f"--error {v!r}: expected NAME=VALUE with a unit mm, m, deg or rad "
                                  "(e.g. clamp.v_x=10mm)")
        out[m.group(1)] = float(m.group(2)) * _UNITS[m.group(3)]
    return out


def _inputs(source: str, free: str | None):
    """(robot, datasets, calibrate arguments) of a job file, or of a scenario (a file or a built-in name)
    simulated on the nominal robot."""
    path = scenario_path(source)
    top = read_yaml(path, "job or scenario file")
    if isinstance(top, dict) and top.get("format") == "kincal-scenario":
        robot, ds = scenario_dataset(load_scenario(path))
        return robot, [ds], {"free": free or "offsets"}
    job = load_plan_job(path)
    return job.robot, list(job.datasets), {"free": free or job.free, "fixed": job.fixed, "priors": job.priors,
                                           "noise": job.noise, "constraints": job.constraints}


@click.command("analyze")
@click.argument("source")
@click.option("--free", default=None, help="What to calibrate (a level or comma-separated names); "
              "default: the job's, or 'offsets' for a scenario.")
@click.option("--held", multiple=True, help="Held (fixed) parameter, name or glob, whose errors to propagate; "
              "repeat; default: every known experiment frame.")
@click.option("--error", "errors", multiple=True, help="An error of a held parameter, NAME=VALUE with unit "
              "(clamp.v_x=10mm, clamp.w_y=0.1rad); repeat.")
@click.option("--workspace", default=WORKSPACE_SAMPLES, show_default=True, type=click.IntRange(2, None),
              help="Random configurations within the joint limits over which the tool accuracy is predicted.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of the workspace sample.")
@click.option("--json", "as_json", is_flag=True, help="Print the analysis as JSON instead of tables.")
def analyze_cmd(source: str, free, held, errors, workspace: int, seed: int, as_json: bool) -> None:
    """Analyse the experiment of JOB.yaml (its data) or of a scenario (SCENARIO.yaml or a built-in name such as
    frida_clamp_one: its configurations on the nominal robot): rank and what cannot be identified, observability indices, predicted standard
    deviations, predicted tool accuracy over the workspace, and the effect of errors in held parameters."""
    robot, datasets, args = _inputs(source, free)
    if isinstance(args["free"], str) and "," in args["free"]:
        args["free"] = tuple(s.strip() for s in args["free"].split(","))
    an = analyze(robot, datasets, held=list(held) or None, errors=_errors(errors), workspace=workspace, seed=seed,
                 **args)
    if as_json:
        click.echo(json.dumps(analysis_dict(an), indent=2))
        return
    _print(an)


def analysis_dict(an: Analysis) -> dict:
    """The analysis as plain data (SI units: m, rad)."""
    p = an.plan
    ana = p.identifiability
    out = {"rank": ana.rank, "free": len(ana.names), "configurations": p.observability.configurations,
           "unidentifiable": [d.words for d in ana.directions], "messages": list(ana.messages),
           "observability": p.observability.as_dict(),
           "estimates": [{"name": e.name, "unit": e.unit, "nominal": e.nominal,
                          "std": e.std if e.identifiable else None, "identifiable": e.identifiable}
                         for e in p.estimates],
           "workspace": {arm: {"samples": pr.samples, "position_std_rms_m": pr.stats()["position_std_rms"],
                               "position_std_max_m": pr.stats()["position_std_max"],
                               "orientation_std_rms_rad": pr.stats()["orientation_std_rms"],
                               "trusted": pr.trusted, "messages": list(pr.messages)}
                         for arm, pr in an.predictions.items()},
           "held": {name: {arm: vars(t) for arm, t in per.items()} for name, per in an.held_tool.items()}}
    if an.shift is not None:
        out["errors"] = {"given": dict(an.errors),
                         "shift": {e.name: float(s) for e, s in zip(p.estimates, an.shift)},
                         "tool": {arm: vars(t) for arm, t in an.error_tool.items()}}
    return out


def _print(an: Analysis) -> None:
    console = _console()
    p = an.plan
    ana = p.identifiability
    console.print(f"rank {ana.rank} of {len(ana.names)} free parameters from {p.observability.configurations} "
                  f"configurations")
    for m in ana.messages:
        console.print(f"  {m}")
    t = Table(title="observability indices (whitened Jacobian, unit columns, identifiable part)")
    for c in ("index", "value", "meaning"):
        t.add_column(c)
    for k, v in p.observability.as_dict().items():
        t.add_row(k, f"{v:.4g}", MEANINGS[k])
    console.print(t)
    t = Table(title="predicted standard deviations at the stated noise (mm, deg)")
    for c in ("parameter", "unit", "std"):
        t.add_column(c, justify="left" if c == "parameter" else "right")
    for e in p.estimates:
        unit, _, std = _shown(e)
        t.add_row(e.name, unit, _num(std) if e.identifiable else "not identifiable")
    console.print(t)
    for arm, pr in an.predictions.items():
        st = pr.stats()
        console.print(f"arm '{arm}' over {pr.samples} workspace configurations: predicted tool position std "
                      f"{_num(st['position_std_rms'], 1e3)} mm RMS (max {_num(st['position_std_max'], 1e3)}), "
                      f"orientation {_num(st['orientation_std_rms'], DEG)} deg RMS; "
                      f"{'trusted' if pr.trusted else 'not trusted'}")
        for m in pr.messages[2:]:
            console.print(f"  {m}")
    _print_held(console, an)


def _print_held(console, an: Analysis) -> None:
    p = an.plan
    if p.sensitivity is None:
        return
    t = Table(title="effect of a held parameter's error, per unit (mm per mm or mm per mrad; tool change RMS "
                    "over the workspace)")
    for c in ("held", "largest estimate changes", *(f"tool {a} mm" for a in an.predictions)):
        t.add_column(c)
    S = p.sensitivity
    for j, name in enumerate(S.held):
        col = S.matrix[:, j]
        top = ", ".join(f"{S.free[i]} {col[i]:+.3g}" for i in abs(col).argsort()[::-1][:SHOWN_SHIFTS])
        t.add_row(name, top, *(_num(an.held_tool[name][a].position_rms, 1.0) for a in an.predictions))
    console.print(t)
    if an.shift is not None:
        for arm, eff in an.error_tool.items():
            console.print(f"with the given errors the calibrated tool of arm '{arm}' moves by "
                          f"{_num(eff.position_rms, 1e3)} mm RMS (max {_num(eff.position_max, 1e3)}) and "
                          f"{_num(eff.orientation_rms, DEG)} deg RMS over the workspace")


def register(group: click.Group) -> None:
    group.add_command(analyze_cmd)
