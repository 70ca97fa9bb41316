"""The ``kincal`` command. Each sub-command lives in its own module and registers itself here."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import warnings

import click
from threadpoolctl import threadpool_limits

from kincal import __version__
from kincal.cli import (analyze_cmds, calibrate_cmds, compensate_cmds, design_cmds, export_cmds, list_cmds, model_cmds,
                        pose_cmds, report_cmds, simulate_cmds, study_cmds)
from kincal.errors import KincalError, KincalWarning


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="kincal")
@click.pass_context
def cli(ctx: click.Context) -> None:
    """kincal: kinematic calibration of robot arms."""
    ctx.with_resource(blas_threads())  # every command, however it is invoked (console, tests' CliRunner)


for _module in (model_cmds, list_cmds, simulate_cmds, calibrate_cmds, analyze_cmds, design_cmds, export_cmds,
                report_cmds, compensate_cmds, pose_cmds, study_cmds):  # each defines ``register(group)``
    _module.register(cli)

# One whole phrase per command in ``kincal --help`` (click would cut the docstring's first line mid-phrase).
SHORT_HELP = {
    "batch": "Calibrate many jobs (a fleet) in parallel; one summary.",
    "analyze": "Before measuring: what an experiment identifies, how well.",
    "calibrate": "Calibrate as a job file describes; write model and result.",
    "compensate": "Joint targets the calibrated robot needs for a program.",
    "convert-log": "Controller motor log -> joint readings at standstills.",
    "demo": "Calibrate Frida's clamped arms from built-in data.",
    "design": "Choose the configurations to measure (or to add).",
    "export": "Model as URDF, DH, controller offsets, JSON or UR ROS file.",
    "fk": "Tool pose for one joint configuration.",
    "import": "Read a URDF chain or a DH table into a kincal model file.",
    "markers-to-pose": "Markers data set -> fitted poses with their covariance.",
    "model": "Inspect robot models (built-in names or files).",
    "plot": "PNG plots of a calibration already written.",
    "report": "One self-contained HTML report of a calibration.",
    "robots": "List the built-in robots.",
    "scenarios": "List the built-in simulation scenarios.",
    "simulate": "Simulate a scenario: data set, truth, validation.",
    "studies": "List the built-in Monte Carlo studies.",
    "study": "Monte Carlo study of calibration variants (on Dask).",
}
for _name, _text in SHORT_HELP.items():
    if _name in cli.commands:
        cli.commands[_name].short_help = _text


# Environment variables by which a user chooses BLAS threads; without them the CLI uses one (see blas_threads).
BLAS_VARIABLES = ("KINCAL_BLAS_THREADS", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def blas_threads():
    """A context limiting BLAS to ``KINCAL_BLAS_THREADS`` threads (default 1) unless the user set a BLAS thread
    variable: kincal's matrices are small and many, and BLAS threads spinning against each other (or against
    other processes on a small machine) made the CLI 2-3.5x slower."""
    chosen = {v: os.environ[v] for v in BLAS_VARIABLES if os.environ.get(v)}
    if chosen and "KINCAL_BLAS_THREADS" not in chosen:
        return contextlib.nullcontext()
    try:
        limit = max(1, int(chosen.get("KINCAL_BLAS_THREADS", 1)))
    except ValueError:
        limit = 1
    return threadpool_limits(limits=limit, user_api="blas")


def _terminated(signum, frame):
    """SIGTERM unwinds like an error (exit 143), so the output being written is removed (kincal.io.atomic)."""
    raise SystemExit(128 + signum)


def main(argv=None) -> int:
    """Console entry point: kincal errors become one clear line and exit code 2, never a traceback."""
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _terminated) if in_main else None
    try:
        return _run(argv)
    finally:
        if in_main:
            signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


def _run(argv) -> int:
    with warnings.catch_warnings():  # kincal's warnings as one line each on stderr, like its errors
        show = warnings.showwarning
        warnings.showwarning = lambda msg, category, *args: (
            click.echo(f"kincal: warning: {msg}", err=True) if issubclass(category, KincalWarning)
            else show(msg, category, *args))
        return _command(argv)


def _command(argv) -> int:
    try:
        cli.main(args=argv, prog_name="kincal", standalone_mode=False)
    except KincalError as exc:
        click.echo(f"kincal: error: {exc}", err=True)
        return 2
    except OSError as exc:  # a path the system refuses (permissions, a file where a folder is needed)
        where = f"{exc.filename}: " if exc.filename else ""
        click.echo(f"kincal: error: {where}{exc.strerror or exc}", err=True)
        return 2
    except click.exceptions.Abort:
        click.echo("kincal: aborted", err=True)
        return 130
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code
    except SystemExit as exc:  # a command's own exit status (calibrate_cmds.EXIT_CODES), as a return value
        return exc.code if isinstance(exc.code, int) else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
