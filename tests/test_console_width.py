"""Console output at 80 columns (issue #12, console polish): the main commands run through CliRunner with
COLUMNS=80; no number is cut with an ellipsis, no Python repr ({...}, array(...), np.float64(...), None)
appears, angles are in degrees, lines fit, and a progress count never shows a "None" total."""

from __future__ import annotations

import os
import re

import numpy as np
import pytest
from click.testing import CliRunner
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from kincal import robots
from kincal.cli import cli
from kincal.cli.console import CountColumn, FittingConsole

JOB = """format: kincal-job
version: 1
model: ur10
data: [sim/data.yaml]
validation: [sim/validation/arm.yaml]
free: kinematic
"""
REPRS = ("{", "}", "array(", "np.float64(", "None", "…")
WIDE_BY_DESIGN = {"robots", "scenarios"}  # one plain line per entry, for grep (tests/test_cli_misc.py)


def _check(args, out: str) -> None:
    for token in REPRS:
        assert token not in out, f"{' '.join(args)}: {token!r} in\n{out}"
    assert not re.search(r"\d…|…\d", out), f"{' '.join(args)}: a number cut in\n{out}"  # rich's cut mark
    for line in out.splitlines():
        if args[0] not in WIDE_BY_DESIGN:
            assert len(line) <= 80, f"{' '.join(args)}: line of {len(line)} columns: {line!r}"
    # angles in degrees; data warnings quote a file's values in the file's own unit, and the gauge's metric
    # is stated in SI ("1 m counting as 1 rad")
    text = re.sub(r"warning: .*?of model '[^']*'", "", " ".join(out.split()))
    text = text.replace("1 m counting as 1 rad", "")
    assert not re.search(r"\d\s*rad\b", text), f"{' '.join(args)}: an angle in rad in\n{out}"


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """One simulated UR10 data set, its calibration, and a short program, shared by the commands below."""
    d = tmp_path_factory.mktemp("w80")
    runner, before = CliRunner(env={"COLUMNS": "80"}), os.getcwd()
    os.chdir(d)
    try:
        assert runner.invoke(cli, ["simulate", "ur10_tracker_markers", "-o", "sim", "--quiet"]).exit_code == 0
        open("job.yaml", "w").write(JOB)
        assert runner.invoke(cli, ["calibrate", "job.yaml", "-o", "res", "--quiet"]).exit_code in (0, 5)
        arm = robots.load("ur10")["arm"]
        q = np.random.default_rng(0).uniform(-1.5, 1.5, (5, 6))
        rows = [",".join(f"arm.{n}" for n in arm.joint_names)] + [",".join(f"{x:.6f}" for x in r) for r in q]
        open("program.csv", "w").write("\n".join(rows) + "\n")
    finally:
        os.chdir(before)
    return d


COMMANDS = [
    ["robots"], ["scenarios"], ["--help"], ["model", "--help"], ["model", "show", "ur10"], ["model", "show", "frida"],
    ["fk", "ur10", "--q-deg", "0 -90 90 0 90 0"], ["fk", "frida", "--arm", "right", "--q-deg", "0 0 0 0 0 0 0"],
    ["simulate", "ur10_tracker_markers", "-o", "sim2"], ["calibrate", "job.yaml", "-o", "res2"],
    ["demo", "-o", "demo", "-n", "30"], ["export", "res/model.yaml", "--to", "ur-ros", "-o", "ur.yaml"],
    ["export", "res/model.yaml", "--to", "controller", "-o", "c.yaml"], ["export", "ur10", "--to", "dh", "-o", "dh.yaml"],
    ["import", "dh.yaml", "-o", "from_dh.yaml"],
    ["compensate", "res/model.yaml", "program.csv", "--nominal", "ur10", "-o", "comp.csv"],
    ["report", "res"], ["analyze", "ur10_tracker_markers"],
    ["design", "ur10_tracker_markers", "-n", "10", "--pool", "200", "-o", "des"],
]


@pytest.mark.parametrize("args", COMMANDS, ids=[" ".join(a[:2]) for a in COMMANDS])
def test_command_output_at_80_columns(args, workdir, monkeypatch):
    monkeypatch.chdir(workdir)
    res = CliRunner(env={"COLUMNS": "80"}).invoke(cli, args)
    assert res.exit_code in (0, 1, 5), f"{args}: exit {res.exit_code}\n{res.output}\n{res.exception!r}"
    assert res.output.strip()
    _check(args, res.output)


def test_a_table_too_wide_is_split_not_cut():
    console = FittingConsole(width=80, record=True, file=open("/dev/null", "w"))
    t = Table(title="twelve numeric columns (unit)")
    t.add_column("name")
    for k in range(11):
        t.add_column(f"column {k} before", justify="right")
    t.add_row("right.shoulder_lift.offset", *[f"{0.000123456 * (k + 1):.6g}" for k in range(11)])
    console.print(t)
    text = console.export_text()
    assert "…" not in text and max(len(ln) for ln in text.splitlines()) <= 80
    assert text.count("right.shoulder_lift.offset") >= 2 and "(continued)" in text
    for k in range(11):
        assert f"{0.000123456 * (k + 1):.6g}" in text  # every number whole


def test_progress_count_without_a_known_total_never_says_none():
    console = Console(width=80, record=True, file=open("/dev/null", "w"), force_terminal=True)
    with Progress(CountColumn(), console=console, auto_refresh=False) as bar:
        task = bar.add_task("x", total=None)
        bar.update(task, completed=3)
        bar.refresh()
        bar.update(task, total=10, completed=5)
        bar.refresh()
    text = console.export_text()
    assert "None" not in text and "3" in text and "5/10" in text
