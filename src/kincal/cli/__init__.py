"""The ``kincal`` command. Each sub-command lives in its own module and registers itself here."""

from __future__ import annotations

import signal
import sys
import threading

import click

from kincal import __version__
from kincal.cli import calibrate_cmds, model_cmds, simulate_cmds
from kincal.errors import KincalError


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="kincal")
def cli() -> None:
    """kincal: kinematic calibration of robot arms."""


for _module in (model_cmds, simulate_cmds, calibrate_cmds):  # each defines ``register(group)``
    _module.register(cli)


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
