"""``kincal robots`` and ``kincal scenarios``: the built-in models and scenarios, one line each."""

from __future__ import annotations

import re

import click

from kincal.io.datasets import BUILTIN_SCENARIOS
from kincal.io.models import BUILTIN_ROBOTS, builtin_names, load_builtin


# The end of the first sentence: a full stop (not after Sec., eq., Fig., e.g., i.e.) before a capital, at the
# end of a comment line or of the text, or a colon at the end of a comment line (a table follows).
_SENTENCE_END = re.compile(r"(?<!\bSec)(?<!\beq)(?<!\bFig)(?<!\be\.g)(?<!\bi\.e)\.(?=\s+[A-Z]|\n|\s*$)|:(?=\n|$)")


def first_comment(path) -> str:
    """The first sentence of the file's leading comment: its description."""
    words = []
    with path.open("r", encoding="utf-8") as fh:
        for line in fh:
            if not line.startswith("#") or not line.lstrip("#").strip():
                break
            words.append(line.lstrip("#").strip())
    text = "\n".join(words)
    end = _SENTENCE_END.search(text)
    return (text[: end.start() + 1] if end else text).replace("\n", " ")


@click.command("robots")
def robots_cmd() -> None:
    """List the built-in robots (model files shipped with kincal)."""
    for name in builtin_names():  # plain lines (no wrapping): one per robot, for people and for grep
        robot = load_builtin(name)
        arms = ", ".join(f"{a} ({robot[a].dof} joints)" for a in robot.arms)
        click.echo(f"{name:<12} {arms:<33} {first_comment(BUILTIN_ROBOTS / f'{name}.yaml')}")


@click.command("scenarios")
def scenarios_cmd() -> None:
    """List the built-in simulation scenarios (for kincal simulate, analyze and design)."""
    for path in sorted(BUILTIN_SCENARIOS.glob("*.yaml")):
        click.echo(f"{path.stem:<26} {first_comment(path)}")


def register(group: click.Group) -> None:
    group.add_command(robots_cmd)
    group.add_command(scenarios_cmd)
